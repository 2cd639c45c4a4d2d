"""Diagnosis of a single-magnet levitator (steel ball under an electromagnet).

A real rig's log (e.g. the UAQ levitator, read with the ``uaq-levitador``
preset) has no known excitation and no state-feedback loop, so the AMB route
(v1..v9 and fault isolation) does not apply. What can be diagnosed is the
physics of the single-magnet model: the unstable pole of the current-driven
plant at the operating gap (and the current gain and equilibrium current when
stated at that gap), compared with the published (or an earlier) parameter set.
These are law-independent; the force-law parameters (``a``, which includes any
offset of the gap sensor, ``k``) are reported but not compared
(:func:`levitator_estimates`).

Only the segments where the ball levitates under control are used
(:func:`maglevid.identify.levitator.find_levitator_segments`, the range learned
from the record): lift-off, falls, sticking to the magnet and losses of
tracking are cut out first, each with its reason.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from maglevid.data import ClosedLoopData
from maglevid.diagnose.diagnosis import QualityCheck

__all__ = [
    "LAW_INDEPENDENT",
    "MIN_LEVITATING_SECONDS",
    "is_levitator",
    "levitator_baseline",
    "levitator_checks",
]

#: Fewest seconds of usable levitation for a diagnosis: the grey box fits the
#: ~7 Hz unstable mode, so 10 s hold ~70 of its periods.
MIN_LEVITATING_SECONDS = 10.0


def is_levitator(data: ClosedLoopData) -> bool:
    """A single-magnet levitator log: [gap, current] outputs and the magnet's inductance law."""
    plant = data.metadata.get("plant") if hasattr(data.metadata, "get") else None
    return bool(
        data.ny == 2
        and isinstance(plant, Mapping)
        and "inductance_model" in plant
        and {"k0_H", "k_H", "a_m"} <= set(plant)
    )


def levitator_baseline(data: ClosedLoopData) -> Any:
    """The published parameter set stored with the recording (``metadata['plant']``), or
    ``None`` when the recording states none (a rig log without published physics)."""
    from maglevid.physics.levitator import LevitatorParameters

    if not is_levitator(data):
        return None
    plant = data.metadata["plant"]
    return LevitatorParameters(
        m=float(plant.get("m_kg", 0.018)),
        R=float(plant.get("R_ohm", 2.72)),
        k0=float(plant["k0_H"]),
        k=float(plant["k_H"]),
        a=float(plant["a_m"]),
    )


def levitator_checks(
    data: ClosedLoopData,
) -> tuple[tuple[QualityCheck, ...], list[tuple[int, int]]]:
    """Quality checks of a levitator log and the usable (levitating) segments.

    The levitating range is learned from the record
    (:func:`maglevid.identify.levitator.find_levitator_segments`), not fixed; the
    segments returned are the operating points (split at reference steps).
    """
    from maglevid.identify.levitator import find_levitator_segments

    rep, segs, how = find_levitator_segments(data)
    seconds = sum(b - a for a, b in segs) * data.dt
    total = data.n_samples * data.dt
    lost = rep.excluded_by_reason()
    why = ", ".join(f"{k} {v:.1f} s" for k, v in lost.items() if v > 0) or "nothing"
    ok = seconds >= MIN_LEVITATING_SECONDS
    checks = (
        QualityCheck(
            name="levitation",
            passed=ok,
            value=seconds,
            threshold=MIN_LEVITATING_SECONDS,
            message=(
                f"{seconds:.1f} s of {total:.1f} s levitating under control in {len(segs)} "
                f"segment(s) ({how}); excluded: {why}"
                + ("" if ok else ": too little usable levitation to identify the plant")
            ),
        ),
    )
    return checks, segs


#: Quantities the levitator verdict compares: the same physical quantity whatever force
#: law, flux lag, delay or sensor gain the identified model has.
LAW_INDEPENDENT = ("pole_rad_s", "current_gain", "i0")


def levitator_estimates(result: Any) -> tuple[dict[str, tuple[float, float]], float]:
    """``{name: (value, se)}`` of the compared levitator quantities, and the operating gap.

    Only law-independent quantities are compared (:data:`LAW_INDEPENDENT`): the unstable
    pole at the operating gap ``y_ref``, and the current gain and equilibrium current
    when the model states them at that gap. The force-law parameters (``a``, ``k``,
    ``Km``, ...) are not: they mean different things under different laws, ``a`` also
    absorbs a gap-sensor offset and ``k`` trades with ``a`` at one gap (docs/real-rigs.md:
    the healthy UAQ 'escalon' session has ``k`` 19 % above the published value with its
    pole within 1 %), so comparing them calls a healthy rig changed.
    """
    se = result.std_errors()
    p = result.parameters
    y_ref = float(result.options.get("y_ref"))
    gaps = result.extras.get("segment_gaps") or [y_ref]
    at_ref = abs(float(gaps[0]) - y_ref) <= 1e-3 * abs(y_ref)  # i0, gain: first segment's gap
    keys = [k for k in LAW_INDEPENDENT if k in p and (k == "pole_rad_s" or at_ref)]
    out = {k: (p[k], se[k]) for k in keys}
    if "consensus" in result.extras:  # the pole's interval is the consensus hull
        lo, hi = result.extras["consensus"]["ci95"]
        out["pole_rad_s"] = (
            p["pole_rad_s"],
            max(p["pole_rad_s"] - lo, hi - p["pole_rad_s"]) / 1.96,
        )
    return out, y_ref


def levitator_baseline_values(base: Any, y_ref: float) -> dict[str, tuple[float, float]]:
    """The baseline's pole, ``a``, ``k``, current gain and equilibrium current at ``y_ref``."""
    from maglevid.physics.levitator import current_gain, equilibrium, unstable_pole

    i0 = equilibrium(base, y_ref)[0]
    return {
        "pole_rad_s": (unstable_pole(base, y_ref), 0.0),
        "a": (base.a, 0.0),
        "k": (base.k, 0.0),
        "current_gain": (current_gain(base, y_ref), 0.0),
        "i0": (float(i0), 0.0),
    }


def levitator_without_baseline(
    result: Any,
    estimates: dict[str, tuple[float, float]],
    y_ref: float,
    quality: Any,
    notes: list[str],
    common: dict[str, Any],
) -> Any:
    """The diagnosis of a levitator log with no published physics and no history: the
    identified pole and parameters with their intervals, nothing compared."""
    from maglevid.diagnose.diagnosis import Diagnosis

    p, se = estimates["pole_rad_s"]
    lo, hi = (result.extras.get("consensus") or {}).get("ci95", (p - 1.96 * se, p + 1.96 * se))
    reasons = (
        f"unstable pole {p:.4g} rad/s (95 % CI {lo:.4g} … {hi:.4g}) at the operating gap "
        f"{1e3 * y_ref:.3g} mm; no baseline (no published physics in the recording, no "
        "history): nothing to compare with",
    )
    return Diagnosis(
        verdict="No baseline: identified, not compared",
        verdict_code="no_change",
        reasons=reasons,
        identification=result,
        quality=quality,
        baseline={"source": "none", "parameters": {}},
        identified_model=result.continuous_model,
        notes=(*notes, "record this diagnosis in a history store to compare later ones with it"),
        **common,
    )
