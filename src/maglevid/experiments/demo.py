"""The bundled default job: a small fleet of bearings diagnosed over weeks.

Three bearings of the Gosiewski & Paszowski design, each recorded every few
days for eight weeks under the controller and deadbeat observer designed on
the nominal bearing:

* ``AMB-1`` stays healthy;
* ``AMB-2``'s coil 1 slowly heats up: R1 rises linearly to +15 % at week 8
  (the engineering tolerance on R1 is 10 %, reached at about week 5.3);
* ``AMB-3``'s amplifier 1 loses 20 % of its gain from week 5 on.

Every recording is written to ``OUT/recordings/<machine>/day-XX.npz`` (so any
of them can be diagnosed again from the command line) and diagnosed into the
SQLite history ``OUT/history.sqlite``; the bearings whose latest verdict is a
fault or a drift get an HTML report ``OUT/<machine>.html``; ``OUT/signals.png``
shows the signals of the last recording.

The bearings are the realistic ones (:func:`maglevid.simulate.simulate_amb_loop`
defaults): eq. (1) under the *nominal* bias voltages, so a fault moves the
operating point, with a 0.1 N broadband force disturbance on the rotor. The
sensors are quieter than the simulator's default (5 nm on the displacement, a
capacitive or high-end eddy-current sensor; 10 µA on the currents, an 18-bit
converter over +-2 A; against 0.1 µm and 0.1 mA): with 3 s records at
10 kHz the diagnosis's default, maximum likelihood (``ml``), gives the
resistance to about 0.4 % (one standard error; ``physical`` about 1 %), enough
to see the heating coil drift well before it crosses its tolerance
(docs/diagnosis.md, "The demo's numbers"). Recordings
are deterministic (seeded per machine and day), so running the demo again
adds nothing to the history: the store is idempotent on the recording's
content.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from maglevid.physics.amb import AMBParameters

__all__ = ["DEMO_NOISE_STD", "DEMO_TOLERANCES", "DemoBearing", "demo_fleet", "run_demo"]

logger = logging.getLogger(__name__)

#: Engineering tolerances of the demo (relative): 10 % on every parameter.
DEMO_TOLERANCES = 0.10

#: Sensor noise of the demo's rig [m, A, A] (module notes).
DEMO_NOISE_STD = (5e-9, 1e-5, 1e-5)

#: Start of the demo's "weeks".
START = datetime(2026, 9, 1, 8, 0, tzinfo=timezone.utc)


@dataclass(frozen=True)
class DemoBearing:
    """One simulated machine: name and its fault factors as a function of the day."""

    name: str
    description: str
    faults: Callable[[float], dict[str, float]]


def demo_fleet() -> tuple[DemoBearing, ...]:
    """The three bearings of the demo (see module docs)."""
    return (
        DemoBearing("AMB-1", "healthy", lambda day: {}),
        DemoBearing(
            "AMB-2",
            "coil 1 heating: R1 rising to +15 % at week 8",
            lambda day: {"R1": 1.0 + 0.15 * day / 56.0},
        ),
        DemoBearing(
            "AMB-3",
            "amplifier 1 gain -20 % from week 5",
            lambda day: {"kw1": 0.8} if day >= 35 else {},
        ),
    )


def _days(every: int, weeks: int) -> list[int]:
    return list(range(0, 7 * weeks + 1, every))


def run_demo(
    out: str | Path,
    *,
    weeks: int = 8,
    every_days: int = 3,
    n_samples: int = 30_000,
    seed: int = 0,
    progress: Callable[[Iterable[Any]], Iterator[Any]] | None = None,
) -> dict[str, Any]:
    """Simulate, record, diagnose and report the demo fleet; returns the verdict table.

    Parameters
    ----------
    out : path
        Output folder (created). An existing history there is reused.
    weeks, every_days : int
        Length of the campaign and the interval between recordings.
    n_samples : int
        Control periods per recording (dt = 0.1 ms).
    seed : int
        Base seed; each (machine, day) gets its own deterministic seed.
    progress : callable, optional
        Wraps the iterable of jobs (e.g. a tqdm bar).
    """
    from maglevid.diagnose.history import open_history
    from maglevid.diagnose.pipeline import diagnose
    from maglevid.io import write_recording
    from maglevid.simulate import simulate_amb_loop

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    nominal = AMBParameters.nominal()
    fleet = demo_fleet()
    jobs = [(b, day) for day in _days(every_days, weeks) for b in fleet]
    rows: list[dict[str, Any]] = []
    latest: dict[str, Any] = {}
    with open_history(out / "history.sqlite") as store:
        it: Iterable[Any] = progress(jobs) if progress is not None else jobs
        for bearing, day in it:
            factors = bearing.faults(day)
            plant = nominal.with_fault(**factors) if factors else nominal
            job_seed = seed * 100_003 + 1000 * (1 + fleet.index(bearing)) + day
            rec = simulate_amb_loop(
                plant,
                dt=1e-4,
                n_samples=n_samples,
                nominal=nominal,
                noise_std=DEMO_NOISE_STD,
                plant_model="nonlinear",  # the realistic bearing (nominal bias, force)
                rng=job_seed,
            )
            when = START + timedelta(days=day)
            rec = rec.with_metadata(machine=bearing.name, recorded_at=when.isoformat())
            path = out / "recordings" / bearing.name / f"day-{day:02d}.npz"
            path.parent.mkdir(parents=True, exist_ok=True)
            if not path.exists():
                write_recording(rec, path)
            diag = diagnose(
                rec,
                baseline="nominal",
                machine=bearing.name,
                tolerances=DEMO_TOLERANCES,
                history=store,
                recorded_at=when,
            )
            latest[bearing.name] = diag
            rows.append(
                {
                    "machine": bearing.name,
                    "day": day,
                    "truth": ", ".join(f"{p} {100 * (f - 1):+.1f} %" for p, f in factors.items())
                    or "healthy",
                    "verdict_code": diag.verdict_code,
                    "verdict": diag.verdict,
                }
            )
            logger.info("%s day %d: %s", bearing.name, day, diag.verdict_code)
        from maglevid.plotting.signals import plot_signals

        signals_png = out / "signals.png"
        plot_signals(  # the demo's own output folder: a rerun replaces its figure
            rec,
            path=signals_png,
            overwrite=True,
            title=f"{rec.metadata['machine']}: last recording",
        )
        reports = {}
        for name, diag in latest.items():
            if diag.verdict_code in ("fault", "drift", "unexplained_change"):
                from maglevid.diagnose.trend_summary import history_summary
                from maglevid.report import trends_from_history, write_report

                hist = history_summary(store, name, method=diag.method)
                trends = trends_from_history(hist, method=diag.method)
                from maglevid.report.html import is_maglevid_page

                page = out / f"{name}.html"
                path = write_report(
                    diag,
                    page,
                    trends=trends,
                    overwrite=is_maglevid_page(page),  # its own earlier page, nothing else
                    title=f"{name}: {next(b.description for b in fleet if b.name == name)}",
                )
                reports[name] = str(path)
        first_alarm = {}
        for r in rows:
            if r["verdict_code"] in ("fault", "drift") and r["machine"] not in first_alarm:
                first_alarm[r["machine"]] = r["day"]
    return {
        "out": str(out),
        "store": str(out / "history.sqlite"),
        "rows": rows,
        "reports": reports,
        "signals_plot": str(signals_png),
        "first_alarm_day": first_alarm,
        "bearings": {b.name: b.description for b in fleet},
    }
