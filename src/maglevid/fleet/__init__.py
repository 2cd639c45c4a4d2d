"""Fleets: diagnose thousands of recordings of many machines on a Dask cluster.

``maglevid.fleet.run_fleet(sources, store=...)`` (and ``maglevid fleet``)
diagnoses every recording of a folder, glob or manifest with
:func:`maglevid.diagnose.pipeline.diagnose`, on a local Dask cluster sized to
the machine or on an existing one, records each diagnosis in the history
store (idempotently: a second run adds nothing), and summarises the fleet:
which machines changed and why, which drift, which recordings could not be
diagnosed. Design and measurements: ``docs/fleet.md``.

Dask (``distributed``) is imported only when a run starts: it is in the
``fleet`` extra.
"""

from maglevid.fleet.jobs import FleetJob, ManifestError, collect_jobs, read_manifest
from maglevid.fleet.runner import Batch, default_n_workers, plan_batches, run_fleet
from maglevid.fleet.summary import FleetSummary, MachineSummary, machine_drifts
from maglevid.fleet.worker import OUTCOME_STATUSES, RecordingOutcome

__all__ = [
    "OUTCOME_STATUSES",
    "Batch",
    "FleetJob",
    "FleetSummary",
    "MachineSummary",
    "ManifestError",
    "RecordingOutcome",
    "collect_jobs",
    "default_n_workers",
    "machine_drifts",
    "plan_batches",
    "read_manifest",
    "run_fleet",
]
