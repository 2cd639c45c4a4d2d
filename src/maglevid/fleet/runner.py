"""Run a fleet's diagnoses on Dask: a local cluster by default, or an existing one.

The task graph (:func:`plan_batches`):

* recordings compared with a fixed baseline (``"nominal"`` or given
  parameters) are independent: batches of up to ``batch_size`` recordings of
  one machine, all submitted at once;
* recordings compared with ``baseline="history"`` depend on each other: each
  is compared with the machine's latest diagnosis *before* it, so a machine's
  recordings form a chain in recording-time order, cut into batches that run
  one after the other (the next is submitted when the previous has finished
  and written its diagnoses); different machines' chains run in parallel.

The client keeps the loop: ``distributed.as_completed`` over the batches,
progress per recording, and the tasks of chains as their predecessors finish.
Workers read the recordings and write to the store themselves (see
``docs/fleet.md`` for why and for the numbers). A worker that dies takes its
running batch with it; the scheduler reruns the batch on another worker (a
task may see ``distributed.scheduler.allowed-failures`` worker deaths, 3 by
default). A batch that still fails is split into single recordings and
resubmitted once, so that one recording that kills its worker every time
(a crash in a native library, memory) is isolated as ``"lost"`` while the
rest of its batch is diagnosed.
"""

from __future__ import annotations

import logging
import math
import os
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from maglevid.exceptions import DataError, MaglevidError
from maglevid.fleet.jobs import FleetJob, collect_jobs
from maglevid.fleet.summary import FleetSummary, machines_drifts, summarize_fleet
from maglevid.fleet.worker import (
    REPORT_VERDICTS,
    UNREADABLE_METHOD,
    BatchContext,
    RecordingOutcome,
    diagnose_batch,
    drop_kept,
    write_kept_report,
)
from maglevid.parallel import available_cores

__all__ = ["Batch", "MissingDependencyError", "default_n_workers", "plan_batches", "run_fleet"]


class MissingDependencyError(MaglevidError, ImportError):
    """An optional dependency (here Dask's ``distributed``) is not installed."""


logger = logging.getLogger(__name__)

#: Recordings per task when not given: enough tasks to keep every worker busy
#: to the end (8 per worker), at most this many recordings per task.
MAX_AUTO_BATCH = 8


def default_n_workers() -> int:
    """Cores this process may use (:func:`maglevid.parallel.available_cores`)."""
    return available_cores()


@dataclass(frozen=True)
class Batch:
    """One Dask task: jobs (indices into the run's job list) diagnosed in order.

    ``chain`` names the machine whose history chain the batch belongs to
    (``None`` for independent batches); ``position`` is its place in the chain.
    """

    jobs: tuple[int, ...]
    chain: str | None = None
    position: int = 0


def _time_key(job: FleetJob) -> tuple[float, str]:
    """Order of a machine's history chain: manifest time, else file modification time, path."""
    if job.recorded_at is not None:
        return job.recorded_at.timestamp(), job.recording
    try:
        return os.stat(job.recording).st_mtime, job.recording
    except OSError:
        return math.inf, job.recording


def plan_batches(
    jobs: Sequence[FleetJob], *, batch_size: int
) -> tuple[list[Batch], dict[str, list[Batch]]]:
    """The task graph: independent batches, and per-machine chains of batches.

    Parameters
    ----------
    jobs : sequence of FleetJob
    batch_size : int
        Most recordings per task (>= 1).

    Returns
    -------
    independent : list of Batch
        Batches of one machine's fixed-baseline recordings, in job order.
    chains : dict
        Machine -> its ``baseline="history"`` batches, in recording-time order
        (manifest ``recorded_at``, else the file's modification time; recordings
        whose time is only in their metadata should be named so that they sort
        in time, or given a ``recorded_at`` in the manifest).
    """
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise DataError(f"`batch_size` = {batch_size!r}; expected an integer >= 1")
    fixed: dict[str, list[int]] = {}
    history: dict[str, list[int]] = {}
    for i, job in enumerate(jobs):
        (history if job.baseline == "history" else fixed).setdefault(job.machine, []).append(i)
    independent = [
        Batch(tuple(idx[k : k + batch_size]))
        for idx in fixed.values()
        for k in range(0, len(idx), batch_size)
    ]
    chains: dict[str, list[Batch]] = {}
    for machine, idx in history.items():
        idx = sorted(idx, key=lambda i: _time_key(jobs[i]))
        chains[machine] = [
            Batch(tuple(idx[k : k + batch_size]), chain=machine, position=n)
            for n, k in enumerate(range(0, len(idx), batch_size))
        ]
    return independent, chains


def _auto_batch_size(n_jobs: int, n_workers: int) -> int:
    return max(1, min(MAX_AUTO_BATCH, n_jobs // (8 * max(1, n_workers))))


def _stored_keys(store: Any, machines: Iterable[str]) -> tuple[dict, dict, dict]:
    """What the store holds before the run, per machine: keys, records, records by key."""
    from maglevid.diagnose.history import NotFoundError

    known: dict[str, frozenset[tuple[str, str, str]]] = {}
    records: dict[str, list[Any]] = {}
    by_key: dict[tuple[str, str, str, str], Any] = {}
    for machine in machines:
        try:
            recs = store.diagnoses(machine)
        except NotFoundError:
            continue
        records[machine] = recs
        keys = set()
        for r in recs:
            if r.method == UNREADABLE_METHOD:
                continue
            k = (r.recording_hash, r.method, r.options_hash)
            keys.add(k)
            by_key[(machine, *k)] = r
        known[machine] = frozenset(keys)
    return known, records, by_key


def _fill_skipped(o: RecordingOutcome, job: FleetJob, by_key: Mapping) -> RecordingOutcome:
    """A skipped recording's outcome with the verdict the store holds for it."""
    from maglevid.diagnose.history import hash_options
    from maglevid.fleet.summary import _latest_from_record

    rec = by_key.get(
        (o.machine, o.recording_hash, o.method, hash_options(dict(job.method_options)))
    )
    if rec is None:
        return o
    latest = _latest_from_record(rec)
    return replace(
        o,
        verdict_code=rec.verdict_code,
        verdict=rec.verdict,
        reasons=tuple(latest["reasons"]),
        changes=tuple(latest["changes"]),
        cause=latest["cause"],
        recorded_at=latest["recorded_at"],
    )


def _lost(job: FleetJob, exc: BaseException) -> RecordingOutcome:
    return RecordingOutcome(
        machine=job.machine,
        recording=job.recording,
        status="lost",
        verdict=f"the worker diagnosing it died ({type(exc).__name__}: {exc})",
        error=f"{type(exc).__name__}: {exc}",
        source=job.source,
    )


def _shared_location(location: str) -> str:
    """The store as every worker must name it: an SQLite file by its absolute path.

    Workers may run in another folder; an in-memory SQLite store would be one
    private store per process, so it is refused.
    """
    from maglevid.diagnose.history import parse_target

    dialect, target = parse_target(location)
    if dialect != "sqlite":
        return location
    if target == ":memory:":
        raise DataError(
            f"store {location!r}: a fleet's workers must share the store; an in-memory "
            "SQLite store would be private to each process (give a file or a postgresql:// URL)"
        )
    return os.path.abspath(target)


def _check_store_reachable(location: str, client: Any, local: bool) -> None:
    """An SQLite store is a file on this host: workers elsewhere cannot write to it."""
    from maglevid.diagnose.history import parse_target

    dialect, _ = parse_target(location)
    if dialect != "sqlite" or local:
        return
    import socket

    here = socket.gethostname()
    hosts = set(client.run(socket.gethostname).values())
    others = sorted(hosts - {here})
    if others:
        raise DataError(
            f"the store {location!r} is an SQLite file on {here}, but workers run on "
            f"{', '.join(others)}: give a PostgreSQL store (--store postgresql://...) that "
            "every worker can reach (SQLite's locking does not work over network file systems)"
        )


def run_fleet(
    sources: Any,
    *,
    store: str | os.PathLike[str] | None = None,
    schema: str | None = None,
    scheduler: Any = None,
    n_workers: int | None = None,
    machine: str | None = None,
    baseline: Any = "nominal",
    method: str | None = None,
    tolerances: Any = None,
    method_options: Mapping[str, Any] | None = None,
    batch_size: int | None = None,
    retries: int = 2,
    reports: str | os.PathLike[str] | None = None,
    alpha: float = 0.01,
    progress: Callable[[Iterable[RecordingOutcome], int], Iterable[RecordingOutcome]]
    | None = None,
    diagnose_fn: Callable[..., Any] | None = None,
) -> FleetSummary:
    """Diagnose every recording of a fleet on Dask; record each in the history store.

    Parameters
    ----------
    sources : path, glob, manifest, or a sequence of them or of FleetJob
        What to diagnose (:func:`maglevid.fleet.jobs.collect_jobs`), or jobs.
    store : path or URL, optional
        History store: SQLite file (created if missing) or ``postgresql://`` URL.
        Default :func:`maglevid.diagnose.history.default_store_location`.
    schema : str, optional
        PostgreSQL schema of the store.
    scheduler : str or distributed.Client, optional
        ``"tcp://host:port"`` of a running Dask scheduler, or a connected
        client. Default: a local cluster of ``n_workers`` processes with one
        thread each, started for this run and closed after it.
    n_workers : int, optional
        Workers of the local cluster (default: the cores this process may use).
    machine, baseline, method, tolerances, method_options
        For recordings from folders, globs and files (and empty manifest cells).
    batch_size : int, optional
        Recordings per Dask task. Default: ``n / (8 workers)``, between 1 and 8.
    retries : int
        Dask ``retries`` of a task that raises (a batch raises only when its
        worker is broken: a recording's own failure is an outcome).
    reports : path, optional
        Folder for the HTML report of each machine whose latest recording in
        this run is a fault or an unexplained change (created if missing).
    alpha : float
        Family-wise drift false-alarm probability per machine (summary).
    progress : callable, optional
        ``progress(outcomes, total)`` wraps the iterator of outcomes as they
        arrive (e.g. a progress bar); must yield them all.
    diagnose_fn : callable, optional
        Replaces :func:`maglevid.diagnose.pipeline.diagnose` (same signature);
        must be importable by the workers.

    Returns
    -------
    FleetSummary
        Outcomes in job order, per-machine states, drift tests, problems.

    Raises
    ------
    DataError
        Bad sources or options, an empty fleet, an SQLite store with workers on
        other hosts.
    """
    from maglevid.diagnose.history import default_store_location, open_history

    t_start = time.perf_counter()
    started = datetime.now(timezone.utc)
    jobs = _jobs_of(sources, machine, baseline, method, tolerances, method_options)
    if not (0.0 < alpha < 1.0):
        raise DataError(f"`alpha` = {alpha!r}; expected 0 < alpha < 1")
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise DataError(f"`retries` = {retries!r}; expected an integer >= 0")
    location = _shared_location(
        os.fspath(store) if store is not None else default_store_location()
    )
    reports_dir = None
    if reports is not None:
        reports_dir = str(Path(reports).resolve())
        Path(reports_dir).mkdir(parents=True, exist_ok=True)
    unique, outcomes = _deduplicate(jobs)

    with open_history(location, schema=schema) as st:  # creates and migrates before workers
        machines = sorted({jobs[i].machine for i in unique})
        known, earlier, by_key = _stored_keys(st, machines)
        t_read = time.perf_counter()

        todo = [jobs[i] for i in unique]
        run_id = uuid.uuid4().hex
        with _cluster(scheduler, n_workers) as (client, n_live, address, local):
            _check_store_reachable(location, client, local)
            size = batch_size if batch_size is not None else _auto_batch_size(len(todo), n_live)
            independent, chains = plan_batches(todo, batch_size=size)
            ctx_common = {
                "store": location,
                "schema": schema,
                "reports_dir": reports_dir,
                "diagnose_fn": diagnose_fn,
                "run_id": run_id,
            }
            stream = _execute(client, todo, independent, chains, ctx_common, known, retries)
            if progress is not None:
                stream = iter(progress(stream, len(todo)))
            diagnosed_on = _collect(stream, unique, jobs, by_key, outcomes)
            t_done = time.perf_counter()

            final = [o for o in outcomes if o is not None]
            if len(final) != len(jobs):  # every job yields one outcome: a bug if not
                raise RuntimeError(f"{len(jobs) - len(final)} recordings have no outcome")
            tols = {job.machine: job.tolerances for job in jobs}
            summary = summarize_fleet(
                final,
                st,
                earlier=earlier,
                tolerances=tols,
                alpha=alpha,
                drifts=_drifts_on_cluster(client, machines, location, schema, alpha, tols, n_live),
            )
            t_summary = time.perf_counter()
            if reports_dir is not None:
                summary = _write_reports(
                    client, summary, diagnosed_on, run_id, reports_dir, location, schema
                )
            t_reports = time.perf_counter()
        run = _run_record(
            started,
            (t_start, t_read, t_done, t_summary, t_reports),
            scheduler=address,
            local_cluster=local,
            n_workers=n_live,
            batch_size=size,
            n_jobs=len(jobs),
            n_tasks=len(independent) + sum(len(c) for c in chains.values()),
            n_chains=len(chains),
            reports=reports_dir,
        )
        summary = replace(summary, run=run)
    return summary


def _jobs_of(
    sources: Any,
    machine: str | None,
    baseline: Any,
    method: str | None,
    tolerances: Any,
    method_options: Mapping[str, Any] | None,
) -> list[FleetJob]:
    """The jobs given, or those :func:`collect_jobs` finds in the sources; never none."""
    if isinstance(sources, FleetJob) or (
        isinstance(sources, Sequence)
        and not isinstance(sources, str)
        and sources
        and all(isinstance(j, FleetJob) for j in sources)
    ):
        jobs = [sources] if isinstance(sources, FleetJob) else list(sources)
    else:
        jobs = collect_jobs(
            sources,
            machine=machine,
            baseline=baseline,
            method=method,
            tolerances=tolerances,
            method_options=method_options,
        )
    if not jobs:
        raise DataError("the fleet is empty: no recordings to diagnose")
    return jobs


def _deduplicate(jobs: Sequence[FleetJob]) -> tuple[list[int], list[RecordingOutcome | None]]:
    """One recording per (machine, file): the same file named twice is diagnosed once.

    Returns the indices of the jobs to run and the outcomes so far (the duplicates').
    """
    first: dict[tuple[str, str], int] = {}
    unique: list[int] = []
    outcomes: list[RecordingOutcome | None] = [None] * len(jobs)
    for i, job in enumerate(jobs):
        key = (job.machine, os.path.realpath(job.recording))
        if key in first:
            outcomes[i] = RecordingOutcome(
                machine=job.machine,
                recording=job.recording,
                status="duplicate",
                verdict=f"same file as {jobs[first[key]].source or jobs[first[key]].recording}",
                source=job.source,
            )
        else:
            first[key] = i
            unique.append(i)
    return unique, outcomes


def _collect(
    stream: Iterable[tuple[int, RecordingOutcome, str | None]],
    unique: Sequence[int],
    jobs: Sequence[FleetJob],
    by_key: Mapping,
    outcomes: list[RecordingOutcome | None],
) -> dict[str, str | None]:
    """Place each outcome as it arrives (a skipped one with the stored verdict).

    Returns the worker that diagnosed each recording.
    """
    diagnosed_on: dict[str, str | None] = {}
    for k, out, worker_address in stream:
        i = unique[k]
        if out.status == "skipped":
            out = _fill_skipped(out, jobs[i], by_key)
        outcomes[i] = out
        diagnosed_on[out.recording] = worker_address
    return diagnosed_on


def _run_record(
    started: datetime,
    times: tuple[float, float, float, float, float],
    *,
    scheduler: str,
    local_cluster: bool,
    n_workers: int,
    batch_size: int,
    n_jobs: int,
    n_tasks: int,
    n_chains: int,
    reports: str | None,
) -> dict[str, Any]:
    """``summary.run``: where and how the run went, and where its time went."""
    t_start, t_read, t_done, t_summary, t_reports = times
    return {
        "started_at": started.isoformat(timespec="seconds"),
        "scheduler": scheduler,
        "local_cluster": local_cluster,
        "n_workers": n_workers,
        "batch_size": batch_size,
        "n_jobs": n_jobs,
        "n_tasks": n_tasks,
        "n_chains": n_chains,
        "seconds_total": time.perf_counter() - t_start,
        "seconds_store_read": t_read - t_start,
        "seconds_diagnosis": t_done - t_read,
        "seconds_summary": t_summary - t_done,
        "seconds_reports": t_reports - t_summary,
        "reports": reports,
    }


def _drifts_on_cluster(
    client: Any,
    machines: Sequence[str],
    location: str,
    schema: str | None,
    alpha: float,
    tolerances: Mapping[str, Any],
    n_workers: int,
) -> dict[str, list[dict[str, Any]]] | None:
    """Every machine's drift tests, in chunks on the workers (``None``: let the client do it)."""
    if not machines:
        return {}
    size = max(1, math.ceil(len(machines) / (4 * n_workers)))
    futures = [
        client.submit(
            machines_drifts,
            list(machines[k : k + size]),
            location,
            schema,
            alpha=alpha,
            tolerances={m: tolerances.get(m) for m in machines[k : k + size]},
            pure=False,
        )
        for k in range(0, len(machines), size)
    ]
    try:
        out: dict[str, list[dict[str, Any]]] = {}
        for part in client.gather(futures):
            out.update(part)
        return out
    except Exception as exc:  # workers gone: the client computes them itself
        logger.warning("drift tests on the cluster failed (%s); computing them here", exc)
        return None


def _write_reports(
    client: Any,
    summary: FleetSummary,
    diagnosed_on: Mapping[str, str | None],
    run_id: str,
    reports_dir: str,
    location: str,
    schema: str | None,
) -> FleetSummary:
    """Reports of the machines whose latest diagnosis (made in this run) is faulty.

    "Latest" is by recording time, known only once every recording is
    diagnosed; the Diagnosis stays on the worker that made it, which writes the
    report (:func:`~maglevid.fleet.worker.write_kept_report`). A machine whose
    worker has restarted since gets no report (logged).
    """
    live = set(client.scheduler_info().get("workers", {}))
    futures = {}
    for m in summary.machines:
        latest = m.latest
        if (
            not latest
            or not latest["in_this_run"]
            or latest["verdict_code"] not in REPORT_VERDICTS
        ):
            continue
        addr = diagnosed_on.get(latest["recording"])
        if addr not in live:
            logger.warning(
                "no report for %s: the worker that diagnosed %s is gone",
                m.name,
                latest["recording"],
            )
            continue
        futures[m.name] = client.submit(
            write_kept_report,
            run_id,
            m.name,
            latest["recording"],
            reports_dir,
            location,
            schema,
            workers=[addr],
            allow_other_workers=False,
            pure=False,
        )
    paths: dict[str, str] = {}
    for name, fut in futures.items():
        try:
            path = fut.result()
        except Exception as exc:  # a report must not cost the run
            logger.warning("report of %s failed: %s", name, exc)
            continue
        if path is not None:
            paths[name] = path
    try:
        client.run(drop_kept, run_id)
    except Exception:  # a worker that died has nothing kept anyway
        logger.debug("dropping the kept diagnoses failed", exc_info=True)
    by_machine = {m.name: m.latest["recording"] for m in summary.machines if m.name in paths}
    outcomes = tuple(
        replace(o, report=paths[o.machine])
        if o.machine in paths and o.recording == by_machine[o.machine] and o.status == "diagnosed"
        else o
        for o in summary.outcomes
    )
    machines = tuple(replace(m, report=paths.get(m.name, m.report)) for m in summary.machines)
    return replace(summary, outcomes=outcomes, machines=machines)


class _cluster:
    """Context manager: ``(client, n_workers, address, local)`` for the run."""

    def __init__(self, scheduler: Any, n_workers: int | None):
        self.scheduler = scheduler
        self.n_workers = n_workers
        self._own: list[Any] = []

    def __enter__(self) -> tuple[Any, int, str, bool]:
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise MissingDependencyError(
                "maglevid fleet runs on Dask: install the fleet extra "
                "(pip install 'maglevid[fleet]')"
            ) from exc

        if self.scheduler is not None and not isinstance(self.scheduler, str):
            client = self.scheduler  # the caller's client: not ours to close
            local = False
        elif isinstance(self.scheduler, str):
            client = Client(self.scheduler)
            self._own.append(client)
            local = False
        else:
            n = self.n_workers if self.n_workers is not None else default_n_workers()
            if isinstance(n, bool) or not isinstance(n, int) or n < 1:
                raise DataError(f"`n_workers` = {n!r}; expected an integer >= 1")
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=True,
                # The scheduler's HTTP server (dashboard, health) always starts: on
                # a free local port, since "None" falls back to 8787 and warns when
                # another user's cluster holds it.
                dashboard_address="127.0.0.1:0",
                # Workers' own logs stay quiet unless maglevid.fleet logs at INFO (-v):
                # what matters reaches the client as outcomes, and a worker's heartbeat
                # racing the shutdown would otherwise print a traceback after every run.
                silence_logs=logging.WARNING
                if logger.isEnabledFor(logging.INFO)
                else logging.CRITICAL,
            )
            self._own.append(cluster)
            client = Client(cluster)
            self._own.append(client)
            local = True
        info = client.scheduler_info()
        n_live = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
        if n_live == 0:
            client.wait_for_workers(1, timeout=120)
            info = client.scheduler_info()
            n_live = sum(w.get("nthreads", 1) for w in info.get("workers", {}).values())
        return client, max(1, n_live), str(info.get("address", "")), local

    def __exit__(self, *exc: object) -> None:
        for obj in reversed(self._own):  # client first, then the cluster
            try:
                obj.close()
            except Exception:  # shutting down: nothing left to save
                logger.debug("closing %r failed", obj, exc_info=True)


def _execute(
    client: Any,
    jobs: Sequence[FleetJob],
    independent: Sequence[Batch],
    chains: Mapping[str, Sequence[Batch]],
    ctx_common: Mapping[str, Any],
    known: Mapping[str, frozenset],
    retries: int,
) -> Iterator[tuple[int, RecordingOutcome, str | None]]:
    """Submit the batches; yield ``(job index, outcome, worker address)`` as they complete."""
    from distributed import as_completed

    contexts: dict[str, Any] = {}

    def context(machine: str) -> BatchContext:
        if machine not in contexts:
            contexts[machine] = BatchContext(
                known={machine: known.get(machine, frozenset())}, **ctx_common
            )
        return contexts[machine]

    pending: dict[Any, tuple[Batch, bool]] = {}

    def submit(batch: Batch, split: bool = False) -> Any:
        sub = [jobs[i] for i in batch.jobs]
        fut = client.submit(
            diagnose_batch,
            sub,
            context(sub[0].machine),
            retries=retries,
            pure=False,
            key=f"fleet-{sub[0].machine}-{batch.jobs[0]}-{len(batch.jobs)}-{int(split)}-"
            f"{time.monotonic_ns()}",
        )
        pending[fut] = (batch, split)
        return fut

    # A chain's batches wait in its queue; the head runs, the next is submitted when it is done.
    queues = {machine: deque(batches) for machine, batches in chains.items()}
    ac = as_completed([submit(b) for b in independent])
    for queue in queues.values():
        ac.add(submit(queue.popleft()))
    try:
        for fut in ac:
            batch, split = pending.pop(fut)
            try:
                worker_address, results = fut.result()
            except Exception as exc:  # the batch could not run (worker deaths, broken worker)
                if len(batch.jobs) > 1 and not split:
                    logger.warning(
                        "a batch of %d recordings failed (%s); resubmitting them one by one",
                        len(batch.jobs),
                        exc,
                    )
                    singles = [Batch((i,), batch.chain, batch.position) for i in batch.jobs]
                    if batch.chain is None:
                        for b in singles:
                            ac.add(submit(b, split=True))
                    else:  # in order: the singles go first in the chain's queue
                        queues[batch.chain].extendleft(reversed(singles))
                        ac.add(submit(queues[batch.chain].popleft(), split=True))
                    continue
                worker_address, results = None, [_lost(jobs[i], exc) for i in batch.jobs]
            finally:
                fut.release()
            for i, out in zip(batch.jobs, results):
                yield i, out, worker_address
            if batch.chain is not None and queues[batch.chain]:
                ac.add(submit(queues[batch.chain].popleft()))
    finally:
        for fut in list(pending):
            fut.cancel()
