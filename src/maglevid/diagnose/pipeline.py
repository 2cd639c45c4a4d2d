"""From a bearing's recording to a diagnosis a person can act on.

:func:`diagnose` runs, in order:

1. the data-quality checks (:mod:`maglevid.diagnose.checks`): a failed blocking
   check gives "cannot diagnose, because ..." instead of a wrong answer;
2. the choice of an identification method for this recording (and why);
3. the identification of v1..v9 and the physical parameters with covariance;
4. the comparison with a baseline, significant twice over
   (:mod:`maglevid.diagnose.compare`);
5. fault isolation by signature matching in v-space
   (:mod:`maglevid.diagnose.isolate`);
6. with a history store: the drift test over the machine's earlier diagnoses
   (:mod:`maglevid.diagnose.drift`) and storing this diagnosis (idempotent on
   the recording's content hash).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Mapping
from dataclasses import fields
from datetime import datetime, timezone
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.diagnose.checks import run_checks
from maglevid.diagnose.compare import DEFAULT_TOLERANCE, compare_parameters
from maglevid.diagnose.diagnosis import Diagnosis
from maglevid.diagnose.isolate import (
    HYPOTHESES,
    IsolationResult,
    MeasuredOperatingPoint,
    isolate_fault,
)
from maglevid.diagnose.resolve import tolerance_of, unresolved_parameters
from maglevid.exceptions import DataError, MaglevidError
from maglevid.jsonable import thaw, to_json_nulls
from maglevid.lti import StateSpace
from maglevid.physics.amb import V_NAMES, AMBParameters, amb_state_space, parameters_from_v
from maglevid.physics.units import parameter_unit

__all__ = ["DIAGNOSED_PARAMETERS", "choose_method", "diagnose", "recording_hash"]

logger = logging.getLogger(__name__)

#: Physical parameters compared with the baseline (the report's forest plot).
DIAGNOSED_PARAMETERS: tuple[str, ...] = (
    "R1", "R2", "L1", "L2", "Ls1", "Ls2", "ki1", "ki2", "kw1", "kw2", "x0", "K1", "K2",
)  # fmt: skip

_BASELINE_FIELDS = {f.name for f in fields(AMBParameters)}


def recording_hash(data: ClosedLoopData) -> str:
    """SHA-256 of a recording's signals and description (the history's idempotency key)."""
    h = hashlib.sha256()
    for sig in ("y", "u", "r", "u_f"):
        a = data.y if sig == "y" else getattr(data, sig)
        h.update(sig.encode())
        if a is not None:
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    desc = data.to_dict()
    desc["metadata"] = {k: v for k, v in desc["metadata"].items() if k not in ("source",)}
    h.update(json.dumps(desc, sort_keys=True, default=str).encode())
    return h.hexdigest()


def choose_method(
    data: ClosedLoopData, *, history: Any = None, machine: str | None = None
) -> tuple[str, str]:
    """The method :func:`diagnose` uses for this recording without a stated one, and why:
    the plant kind's, ``ml`` for a two-coil bearing, or the method a machine's history
    in ``history`` continues with (:mod:`maglevid.diagnose.default_method`)."""
    from maglevid.diagnose.default_method import choose_diagnosis_method

    return choose_diagnosis_method(data, history=history, machine=machine)[:2]


def _baseline_from_loop(data: ClosedLoopData) -> AMBParameters | None:
    nominal = data.loop.get("nominal") if hasattr(data.loop, "get") else None
    if not nominal:
        return None
    return AMBParameters(
        **{k: float(v) for k, v in dict(nominal).items() if k in _BASELINE_FIELDS}
    )


def _physical_dict(p: AMBParameters) -> dict[str, float]:
    out = {k: float(getattr(p, k)) for k in _BASELINE_FIELDS}
    out.update(p.derived())
    out.update(dict(zip(V_NAMES, p.v().tolist())))
    return out


def _baseline_from_history(
    store: Any,
    machine: str,
    method: str,
    fallback: AMBParameters | None,
    notes: list[str],
    *,
    before: Any = None,
    exclude_recording: str | None = None,
) -> tuple[dict[str, tuple[float, float]], AMBParameters | None, np.ndarray | None, str]:
    try:
        est = store.latest_estimates(
            machine, method=method, before=before, exclude_recording=exclude_recording
        )
    except MaglevidError:  # a machine new to the store
        est = {}
    if not est:
        notes.append(
            f"no earlier diagnosis of {machine!r} in the history: compared with the design"
        )
        return {}, fallback, None, "design (no history yet)"
    vals = {k: (e.value, e.std_error if e.std_error is not None else 0.0) for k, e in est.items()}
    try:
        params = AMBParameters(
            **{k: vals[k][0] for k in _BASELINE_FIELDS if k in vals},
            **{k: getattr(fallback, k) for k in ("m", "i0") if fallback is not None},
        )
    except (MaglevidError, TypeError) as exc:
        notes.append(f"the stored baseline is not a valid parameter set ({exc}); using the design")
        params = fallback
    v_cov = None
    if all(k in vals for k in V_NAMES):
        v_cov = np.diag([vals[k][1] ** 2 for k in V_NAMES])
    return vals, params, v_cov, "earlier identification (history)"


#: Smallest relative model error of each v_i: the conversions (ZOH logarithm,
#: eq. (4) read off a realisation) and a real bearing's unmodelled dynamics are
#: not trusted below 0.1 %, far below any engineering tolerance.
MODEL_ERROR_FLOOR = 1e-3


def measured_operating_point(data: ClosedLoopData) -> MeasuredOperatingPoint | None:
    """Where the bearing sat in the recording: the mean levels of its logged deviations.

    A recording from a bearing under its controller logs ``y = [x, i1 - i0, i2 - i0]``
    (deviations from the design point, ``loop["operating_point"]["i0"]``). Their
    means are the settled displacement and coil currents the fault moved the
    bearing to (the nominal bias voltages hold the design point only in the
    nominal bearing). ``None`` when the recording does not say it logs
    deviations from a design point.
    """
    op = data.loop.get("operating_point") if hasattr(data.loop, "get") else None
    if not op or "i0" not in op or data.y.shape[1] != 3:
        return None
    x, d1, d2 = (float(m) for m in np.mean(data.y, axis=0))
    return MeasuredOperatingPoint(x, d1, d2, "mean levels of the recording")


def estimate_model_error(data: ClosedLoopData, p: AMBParameters | None) -> float:
    """Relative model error of each identified v_i for this recording.

    The linearisation of eq. (1) misses terms of second order in the
    excursions: relative to v they are of the order of the largest relative
    excursion ``max(std x / x0, std i1 / i0, std i2 / i0)`` (measured: noise-free
    nonlinear records at 0.3-0.4 % excursion give v within 0.15 % of the
    linearisation at the settled point). Never below :data:`MODEL_ERROR_FLOOR`.
    """
    if p is None or data.y.shape[1] != 3:
        return MODEL_ERROR_FLOOR
    sd = np.std(data.y, axis=0) / np.array([p.x0, p.i0, p.i0])
    return float(max(MODEL_ERROR_FLOOR, np.max(sd)))


def _physical_model_errors(v: np.ndarray, eps: float, m: float, i0: float) -> dict[str, float]:
    """Model-error std of each physical parameter: eq. (4) inverted, J diag(eps v) J^T."""
    base = parameters_from_v(v, m=m, i0=i0)
    J = np.empty((len(base), 9))
    for i in range(9):
        h = 1e-6 * abs(v[i])
        vp, vm = v.copy(), v.copy()
        vp[i] += h
        vm[i] -= h
        hi, lo = parameters_from_v(vp, m=m, i0=i0), parameters_from_v(vm, m=m, i0=i0)
        J[:, i] = [(hi[k] - lo[k]) / (2 * h) for k in base]
    sd = np.sqrt(np.einsum("ij,j,ij->i", J, (eps * v) ** 2, J))
    out = dict(zip(base, sd.tolist()))
    out.update({k: float(eps * abs(vi)) for k, vi in zip(V_NAMES, v)})
    return out


def _excitation_rms(data: ClosedLoopData) -> float | None:
    """RMS of the known excitation r [V] (largest channel), when the recording has one."""
    if data.r is None:
        return None
    rms = float(np.max(np.std(np.asarray(data.r), axis=0)))
    return rms if rms > 0 else None


def _free_estimate_reasons(changes: list[Any]) -> list[str]:
    """The free estimates (every parameter fitted) that are significant twice over."""
    return [
        f"free estimate (every parameter fitted): {c.name} = {c.estimate:.5g} vs baseline "
        f"{c.baseline:.5g}, {c.change_percent:+.1f} % "
        f"(95 % CI {100 * c.change_ci[0] / c.baseline:+.1f} … "
        f"{100 * c.change_ci[1] / c.baseline:+.1f} %, tolerance ±{100 * c.tolerance:.0f} %)"
        for c in changes
        if c.significant
    ]


def _inconclusive(head: str, unresolved: list[Any]) -> tuple[str, str]:
    names = ", ".join(u.parameter for u in unresolved[:4]) + (
        f" and {len(unresolved) - 4} more" if len(unresolved) > 4 else ""
    )
    return (
        f"Inconclusive: {head}, but the data cannot resolve the tolerance of {names}: "
        + unresolved[0].advice(),
        "inconclusive",
    )


def _verdict_without_isolation(
    changes: list[Any], reasons: list[str]
) -> tuple[str, str, list[str]]:
    sig = [c for c in changes if c.significant]
    if sig:
        names = ", ".join(c.name for c in sig)
        return f"Significant change: {names}", "unexplained_change", reasons
    wide = [
        c.name
        for c in changes
        if c.baseline and (c.change_ci[1] - c.change_ci[0]) / 2 > c.tolerance * abs(c.baseline)
    ]
    if wide:
        return (
            f"Inconclusive: no significant change, but the intervals of {', '.join(wide)} are "
            "wider than their tolerance (a longer record or more excitation would resolve them)",
            "inconclusive",
            reasons,
        )
    return "No significant change", "no_change", reasons


def _verdict(
    changes: list[Any],
    iso: IsolationResult | None,
    tolerances: Mapping[str, float] | float,
    unresolved: list[Any],
) -> tuple[str, str, list[str]]:
    """Verdict, code and reasons (see docs/diagnosis.md, "Verdicts").

    ``unresolved`` holds the single-cause hypotheses whose interval is wider
    than their tolerance (:func:`maglevid.diagnose.resolve.unresolved_parameters`).
    The headline number of a fault is the constrained fit ("only R1 changed");
    the free estimates follow in the reasons, labelled as such.
    """
    reasons = _free_estimate_reasons(changes)
    if iso is None:
        return _verdict_without_isolation(changes, reasons)
    best, none = iso.best, iso.no_change
    me = f" (model error ±{100 * iso.model_error:.2g} % of each v_i included)"
    if not best.parameters:
        reasons.append(
            f"every v_i is consistent with the baseline: chi2 = {none.chi2:.3g} "
            f"with {none.dof} dof (p = {none.p_value:.2g}){me}"
        )
        if unresolved:
            return (*_inconclusive("no change detected", unresolved), reasons)
        return "No significant change", "no_change", reasons
    if not iso.explained:
        reasons.append(
            f"no single physical cause (or pair) explains the changes within their model error: "
            f"best {best.describe()}, chi2 = {best.chi2:.3g} with {best.dof} dof "
            f"(p = {best.p_value:.2g}){me}"
        )
        if any(c.significant for c in changes):
            return "Unexplained change in the bearing's dynamics", "unexplained_change", reasons
        if unresolved:
            return (*_inconclusive("the dynamics changed", unresolved), reasons)
        return (
            "Change within tolerance: the dynamics moved, but no parameter beyond its tolerance",
            "within_tolerance",
            reasons,
        )
    names = " and ".join(best.parameters)
    reasons.insert(
        0,
        f"only {names} changed fits all nine v_i: chi2 = {best.chi2:.3g} with {best.dof} dof "
        f"(p = {best.p_value:.2g}); 'nothing changed' is rejected (chi2 = {none.chi2:.3g}, "
        f"{none.dof} dof, p = {none.p_value:.2g}; against the best single cause "
        f"p = {iso.single_cause_p_value:.2g}){me}",
    )
    for h in iso.indistinguishable:
        reasons.append(f"cannot be told apart from: {h.describe()} (chi2 = {h.chi2:.3g})")
    named = [u for u in unresolved if u.parameter in best.parameters]
    if named:
        return (*_inconclusive(f"the data point to {best.describe()}", named), reasons)
    label = f"(fit with only {names} changed)"
    factors = zip(best.parameters, best.factors)
    if any(abs(f - 1) > tolerance_of(k, tolerances) for k, f in factors):
        return f"Fault {label}: {best.describe()}", "fault", reasons
    return f"Change within tolerance {label}: {best.describe()}", "within_tolerance", reasons


def _cannot_diagnose(
    reasons: list[str], quality: Any, common: dict[str, Any], *, prefix: str = ""
) -> Diagnosis:
    """The verdict when the data do not allow a diagnosis: say why, guess nothing."""
    return Diagnosis(
        verdict="Cannot diagnose: " + prefix + "; ".join(reasons),
        verdict_code="cannot_diagnose",
        reasons=tuple(reasons),
        quality=quality,
        **common,
    )


def _diagnose_levitator(
    data: ClosedLoopData,
    baseline: Any,
    common: dict[str, Any],
    tol: float | Mapping[str, float],
    level: float,
    method_options: Mapping[str, Any] | None,
    notes: list[str],
    store: Any,
    machine: str | None,
    when: Any,
) -> Diagnosis:
    """The levitator route: segments, grey box, pole and ``a`` against the baseline."""
    from maglevid.diagnose import levitator as lev
    from maglevid.identify.registry import get_method

    quality, segs = lev.levitator_checks(data)
    failed = [q for q in quality if not q.passed and q.blocking]
    if failed:
        return _cannot_diagnose([q.message for q in failed], quality, common)
    opts = {"segments": segs, **dict(method_options or {})}
    try:
        result = get_method(common["method"])(data, **opts)
    except MaglevidError as exc:
        return _cannot_diagnose([str(exc)], quality, common, prefix="identification failed: ")
    notes.extend(result.notes)
    estimates, y_ref = lev.levitator_estimates(result)
    if not np.isfinite(estimates["pole_rad_s"][0]):
        return _cannot_diagnose(
            [n for n in result.notes if n.startswith("no pole")] or ["no pole identified"],
            quality, common, prefix="identification gave no pole: ",
        )  # fmt: skip
    if baseline == "history" and store is not None and machine is not None:
        try:
            stored = store.latest_estimates(
                machine,
                method=common["method"],
                before=when,
                exclude_recording=common["recording_hash"],
            )
        except MaglevidError:
            stored = {}
        base_vals = {k: (e.value, e.std_error or 0.0) for k, e in stored.items() if k in estimates}
        source_b = "earlier identification (history)"
    else:
        base_vals, source_b = {}, ""
    if not base_vals and lev.levitator_baseline(data) is None:
        return lev.levitator_without_baseline(result, estimates, y_ref, quality, notes, common)
    if not base_vals:
        base = lev.levitator_baseline(data)
        base_vals = lev.levitator_baseline_values(base, y_ref)
        source_b = "published physics of the rig (recording metadata)"
        if baseline == "history":
            notes.append(
                "no earlier diagnosis in the history: compared with the published physics"
            )
    changes = compare_parameters(estimates, base_vals, tolerances=tol, level=level)
    sig = [c for c in changes if c.significant]
    pole = next(c for c in changes if c.name == "pole_rad_s")
    lo, hi = result.confidence_intervals(level)["pole_rad_s"]
    reasons = [
        f"unstable pole {pole.estimate:.4g} rad/s (95 % CI {lo:.4g} … {hi:.4g}) at the "
        f"operating gap {1e3 * y_ref:.3g} mm; baseline {pole.baseline:.4g} rad/s "
        f"({pole.change_percent:+.1f} %, {pole.status})"
    ]
    reasons += [
        f"{c.name} = {c.estimate:.4g} vs baseline {c.baseline:.4g}: {c.change_percent:+.1f} %"
        for c in sig
        if c.name != "pole_rad_s"
    ]
    if sig:
        verdict = "Changed against the baseline: " + ", ".join(
            f"{c.name} {c.change_percent:+.1f} %" for c in sig
        )
        code = "unexplained_change"
        notes.append(
            "a levitator has no fault-isolation model in maglevid yet: the change is reported "
            "with its numbers, not attributed to a cause ('a' also absorbs a gap-sensor offset)"
        )
    elif any(c.statistically_significant for c in changes):
        verdict, code = "Change within tolerance", "within_tolerance"
    else:
        verdict, code = "No significant change", "no_change"
    return Diagnosis(
        verdict=verdict,
        verdict_code=code,
        reasons=tuple(reasons),
        identification=result,
        changes=tuple(changes),
        quality=quality,
        baseline={"source": source_b, "parameters": {k: list(v) for k, v in base_vals.items()}},
        identified_model=result.continuous_model,
        notes=tuple(notes),
        **common,
    )


def _percentage_index(ident: StateSpace | None, base: StateSpace | None) -> dict[str, Any] | None:
    if ident is None or base is None:
        return None
    from maglevid.diagnose.percentage import percentage_index

    return {
        "A_p": percentage_index(ident.A, base.A, zero_tol=1e-10),
        "B_p": percentage_index(ident.B, base.B, zero_tol=1e-10),
    }


def diagnose(
    recording: ClosedLoopData | str | os.PathLike[str],
    *,
    baseline: str | AMBParameters | Mapping[str, float] = "nominal",
    machine: str | None = None,
    method: str | None = None,
    tolerances: float | Mapping[str, float] | None = None,
    history: Any = None,
    recorded_at: datetime | str | None = None,
    method_options: Mapping[str, Any] | None = None,
    mapping: Any = None,
    alpha: float = 0.01,
    level: float = 0.95,
    drift: bool = True,
) -> Diagnosis:
    """Diagnose one recording of a bearing against a baseline.

    Parameters
    ----------
    recording : ClosedLoopData or path
        The recording (any format :func:`maglevid.io.read_recording` reads).
    baseline : "nominal", "history", AMBParameters or mapping
        ``"nominal"``: the design parameters stored in the recording's loop
        (``loop["nominal"]``); ``"history"``: the machine's latest identification
        in ``history`` (falls back to the design for the first diagnosis); or
        explicit parameters.
    machine : str, optional
        Machine name (needed with a history store; default: the recording's
        ``metadata["machine"]``).
    method : str, optional
        Identification method; default chosen by :func:`choose_method`: ``"ml"``
        for a two-coil bearing (unless the machine's history in ``history``
        continues with ``"physical"``, said in a note), the plant kind's otherwise.
    tolerances : float or mapping, optional
        Relative engineering tolerance per parameter (default 5 %).
    history : HistoryStore or str, optional
        Store (or its path/URL) to read the baseline and trends from and to
        record this diagnosis in.
    recorded_at : datetime or ISO string, optional
        When the recording was taken (default: ``metadata["recorded_at"]``, else now).
    method_options : mapping, optional
        Options passed to the identification method.
    mapping : optional
        Column mapping for reading a user's own log.
    alpha : float
        Significance level of the isolation and drift tests.
    level : float
        Confidence level of the intervals.
    drift : bool
        Test the machine's stored history for drift after recording (default).
        A fleet run tests drift once per machine at the end instead.

    Returns
    -------
    Diagnosis
    """
    from maglevid.identify.registry import get_method

    notes: list[str] = []
    source: str | None = None
    if not isinstance(recording, ClosedLoopData):
        from maglevid.io import read_recording

        source = str(recording)
        data = read_recording(recording, mapping=mapping)
    else:
        data = recording
        source = data.metadata.get("source") if hasattr(data.metadata, "get") else None
    machine = machine or (data.metadata.get("machine") if hasattr(data.metadata, "get") else None)
    tol: float | Mapping[str, float] = DEFAULT_TOLERANCE if tolerances is None else tolerances
    rhash = recording_hash(data)
    when = recorded_at or data.metadata.get("recorded_at") or datetime.now(timezone.utc)
    created = datetime.now(timezone.utc).isoformat(timespec="seconds")

    store = history
    if isinstance(history, (str, os.PathLike)):
        from maglevid.diagnose.history import open_history

        store = open_history(history)

    from maglevid.diagnose.default_method import choose_diagnosis_method

    chosen, why, note = choose_diagnosis_method(data, history=store, machine=machine)
    if method is not None and method != chosen:
        why = "chosen by the user"
    elif note is not None:
        notes.append(note)
    method = method or chosen

    common = {
        "machine": machine,
        "recording": source,
        "recording_hash": rhash,
        "dt": data.dt,
        "created_at": created,
        "method": method,
        "method_reason": why,
    }
    from maglevid.plants import infer_kind

    if infer_kind(data)[0] == "levitator" and method in ("levitator", "greybox-levitator"):
        diag = _diagnose_levitator(
            data, baseline, common, tol, level, method_options, notes, store, machine, when
        )
        diag = _record(store, diag, data, when, method_options, notes)
        return diag

    quality = run_checks(data)
    failed = [q for q in quality if not q.passed and q.blocking]
    if failed:
        diag = _cannot_diagnose([q.message for q in failed], quality, common)
        diag = _record(store, diag, data, when, method_options, notes)
        return diag

    design = _baseline_from_loop(data)
    base_vals: dict[str, tuple[float, float]]
    base_cov = None
    if isinstance(baseline, AMBParameters):
        base_params, source_b = baseline, "given parameters"
        base_vals = {k: (v, 0.0) for k, v in _physical_dict(baseline).items()}
    elif isinstance(baseline, Mapping):
        base_params, source_b = None, "given values"
        base_vals = {k: (float(v), 0.0) for k, v in baseline.items()}
        try:
            base_params = AMBParameters(
                **{k: float(v) for k, v in baseline.items() if k in _BASELINE_FIELDS}
            )
            base_vals = {
                **{k: (v, 0.0) for k, v in _physical_dict(base_params).items()},
                **base_vals,
            }
        except (MaglevidError, TypeError):
            notes.append("the baseline is not a full parameter set: no fault isolation")
    elif baseline == "nominal":
        if design is None:
            raise DataError(
                "baseline='nominal' needs the design parameters in the recording "
                "(loop['nominal']); give the baseline explicitly or use a history"
            )
        base_params, source_b = design, "design (nominal parameters in the recording)"
        base_vals = {k: (v, 0.0) for k, v in _physical_dict(design).items()}
    elif baseline == "history":
        if store is None or machine is None:
            raise DataError("baseline='history' needs `history` (a store) and `machine`")
        base_vals, base_params, base_cov, source_b = _baseline_from_history(
            store, machine, method, design, notes, before=when, exclude_recording=rhash
        )
        if not base_vals and design is not None:
            base_vals = {k: (v, 0.0) for k, v in _physical_dict(design).items()}
    else:
        raise DataError(
            "`baseline` must be 'nominal', 'history', AMBParameters or a mapping; "
            f"got {baseline!r}"
        )

    try:
        result = get_method(method)(data, **dict(method_options or {}))
    except MaglevidError as exc:
        diag = _cannot_diagnose([str(exc)], quality, common, prefix="identification failed: ")
        diag = _record(store, diag, data, when, method_options, notes)
        return diag
    notes.extend(result.notes)
    est = result.parameters
    se = result.std_errors()
    estimates = {k: (est[k], se[k]) for k in est}
    compared = {k: estimates[k] for k in DIAGNOSED_PARAMETERS if k in estimates}
    op = measured_operating_point(data)
    eps = estimate_model_error(data, base_params or design)
    model_errors: dict[str, float] = {}
    has_v = all(k in est for k in V_NAMES)
    if has_v and (base_params or design) is not None:
        ref = base_params or design
        v_now = np.array([est[k] for k in V_NAMES])
        try:
            model_errors = _physical_model_errors(v_now, eps, ref.m, ref.i0)
        except MaglevidError as exc:
            notes.append(f"no model-error term for the parameters: {exc}")
    changes = compare_parameters(
        compared, base_vals, tolerances=tol, level=level, model_errors=model_errors
    )

    iso = None
    if base_params is not None and has_v and result.covariance is not None:
        idx = [list(est).index(k) for k in V_NAMES]
        v_hat = np.array([est[k] for k in V_NAMES])
        v_cov = result.covariance[np.ix_(idx, idx)]
        try:
            iso = isolate_fault(
                v_hat,
                v_cov,
                base_params,
                baseline_covariance=base_cov,
                hypotheses=[h for h in HYPOTHESES],
                alpha=alpha,
                operating_point=op,
                model_error=eps,
            )
        except (MaglevidError, ArithmeticError, np.linalg.LinAlgError) as exc:
            # ArithmeticError: an overflow in the hypothesis fits (issue 17: pure
            # noise gave an OverflowError traceback); the quality gate now refuses
            # such records before, and this keeps any other one a note.
            notes.append(f"fault isolation not possible: {exc or type(exc).__name__}")
    unresolved = []
    if iso is not None:
        unresolved = unresolved_parameters(
            iso,
            tol,
            level=level,
            duration_s=data.n_samples * data.dt,
            excitation_rms=_excitation_rms(data),
        )
    verdict, code, reasons = _verdict(changes, iso, tol, unresolved)
    if op is not None:
        reasons.append(
            f"operating point from the recording's mean levels: x = {1e6 * op.x:+.3g} um, "
            f"coil currents {1e3 * op.dI1:+.3g} mA and {1e3 * op.dI2:+.3g} mA from the design "
            "bias; every hypothesis is linearised there"
        )

    base_model = amb_state_space(base_params) if base_params is not None else None
    ident_model = result.continuous_model
    diag = Diagnosis(
        verdict=verdict,
        verdict_code=code,
        reasons=tuple(reasons),
        identification=result,
        changes=tuple(changes),
        isolation=iso,
        quality=quality,
        baseline={
            "source": source_b,
            "parameters": {k: list(v) for k, v in base_vals.items()},
            "loop": thaw(data.loop),
        },
        baseline_model=base_model,
        identified_model=ident_model,
        percentage_index=_percentage_index(ident_model, base_model),
        notes=tuple(notes),
        resolution=tuple(u.to_dict() for u in unresolved),
        **common,
    )
    diag = _record(store, diag, data, when, method_options, notes)
    if store is not None and drift:
        drifts = _drifts(store, diag, tol, alpha)
        if drifts:
            words = "; ".join(_drift_words(d) for d in drifts)
            extra = {
                "drifts": tuple(drifts),
                "reasons": (*diag.reasons, f"over the history: {words}"),
            }
            if diag.verdict_code in ("no_change", "within_tolerance"):
                kind = "drifting" if any(d["kind"] == "drift" for d in drifts) else "a step"
                extra["verdict"] = f"No fault yet, but {kind}: {words}"
                if diag.verdict_code == "within_tolerance":
                    # Keep the isolated cause: the trend may show first in a parameter the
                    # cause moves through the operating point (x0 for a heating coil).
                    extra["verdict"] += f". {diag.verdict}"
                extra["verdict_code"] = "drift"
            diag = _replace_diagnosis(diag, **extra)
    return diag


def _replace_diagnosis(diag: Diagnosis, **changes: Any) -> Diagnosis:
    from dataclasses import replace

    return replace(diag, **changes)


def _record(
    store: Any,
    diag: Diagnosis,
    data: ClosedLoopData,
    when: Any,
    method_options: Mapping[str, Any] | None,
    notes: list[str],
) -> Diagnosis:
    """Store ``diag``; the returned Diagnosis says when it was already stored (idempotent)."""
    if store is None:
        return diag
    if diag.machine is None:
        raise DataError(
            "storing a diagnosis needs a machine name (`machine=` or metadata['machine'])"
        )
    from maglevid.diagnose.history import hash_options

    estimates: dict[str, Any] = {}
    base = diag.baseline.get("parameters", {}) if diag.baseline else {}
    if diag.identification is not None:
        cis = diag.identification.confidence_intervals()
        for k, (v, se) in diag.estimates().items():
            if not np.isfinite(v):
                continue
            b = base.get(k)
            estimates[k] = (
                v,
                se if np.isfinite(se) else None,
                cis[k][0] if np.isfinite(cis[k][0]) else None,
                cis[k][1] if np.isfinite(cis[k][1]) else None,
                parameter_unit(k),
                None if b is None else float(b[0]),
            )
    summary = diag.to_dict()
    summary.pop("identification", None)
    options = dict(method_options or {})
    stored = store.record_diagnosis(
        diag.machine,
        recording_hash=diag.recording_hash,
        recorded_at=when,
        method=diag.method,
        verdict=diag.verdict,
        verdict_code=diag.verdict_code,
        estimates=estimates,
        summary=to_json_nulls(json.loads(json.dumps(summary, default=str))),
        options=options,
        options_hash=hash_options(options),
        recording_path=diag.recording,
        dt=data.dt,
        n_samples=data.n_samples,
    )
    logger.info("stored diagnosis of %s (%s)", diag.machine, diag.verdict_code)
    if stored.created:
        return diag
    note = (
        f"already stored: this recording was diagnosed with {diag.method} and these options "
        f"before (diagnosis {stored.id} in the store); nothing was written"
    )
    return _replace_diagnosis(diag, notes=(*diag.notes, note))


#: Fewest diagnoses in a machine's history before a drift test is made.
MIN_DRIFT_POINTS = 4


def _iso_day(seconds: float) -> str | None:
    """An ISO timestamp (UTC) from seconds since 1970; ``None`` beyond the calendar."""
    try:
        return datetime.fromtimestamp(float(seconds), tz=timezone.utc).isoformat(
            timespec="seconds"
        )
    except (OverflowError, ValueError, OSError):  # a near-flat trend: far beyond 9999
        return None


def _drift_words(d: Mapping[str, Any]) -> str:
    """One history finding in words: a dated step, or a drift and where it heads."""
    if d.get("kind") == "step":
        return (
            f"{d['parameter']} stepped {d['step_percent']:+.3g} % between "
            f"{(d['step_after'] or '?')[:10]} and {(d['step_before'] or '?')[:10]} "
            f"(change-point test p = {d['p_value']:.2g})"
        )
    head = f"{d['parameter']} {d['slope_percent_per_day']:+.2g} %/day (p = {d['p_value']:.2g}"
    if d.get("already_beyond"):
        return head + f", the trend is already beyond ±{d['tolerance_percent']:.0f} %)"
    if d.get("projected_crossing"):
        return (
            head + f", projected to leave ±{d['tolerance_percent']:.0f} % "
            f"on {d['projected_crossing'][:10]})"
        )
    return head + ")"


def _drifts(
    store: Any,
    diag: Diagnosis,
    tolerances: float | Mapping[str, float],
    alpha: float,
) -> list[dict[str, Any]]:
    """Trend test on each diagnosed parameter of the machine's stored history.

    ``alpha`` is the family-wise level over the parameters: each of the
    ``len(DIAGNOSED_PARAMETERS)`` tests runs at ``alpha / len(...)`` (Bonferroni),
    so a healthy machine raises a false drift alarm with probability <= alpha
    per diagnosis rather than ~13 alpha; the step test adds at most alpha / 10.
    Each diagnosis re-tests the growing history; the slope's scale is floored at the
    stated standard errors (``scale_floor``), which keeps a healthy machine's false
    drift alarms over 12 looks within alpha (docs/history.md, repeated looks).
    """
    from maglevid.diagnose.drift import STEP_SHARE, detect_drift, detect_step

    alpha_each = alpha / len(DIAGNOSED_PARAMETERS)
    model_error = {c.name: c.model_error for c in diag.changes}
    out = []
    base = diag.baseline.get("parameters", {}) if diag.baseline else {}
    for k in DIAGNOSED_PARAMETERS:
        try:
            tr = store.trend(diag.machine, k, method=diag.method)
        except MaglevidError:
            continue
        ok = np.isfinite(tr.value) & np.isfinite(tr.std_error) & (tr.std_error > 0)
        if ok.sum() < MIN_DRIFT_POINTS or np.ptp(tr.time[ok]) <= 0:
            continue
        b = float(base[k][0]) if k in base else float(tr.value[ok][0])
        t = tolerances.get(k, DEFAULT_TOLERANCE) if isinstance(tolerances, Mapping) else tolerances
        res = detect_drift(
            tr.time[ok] / 86400.0,
            tr.value[ok],
            tr.std_error[ok],
            alpha=alpha_each,
            tolerance=float(t) * abs(b),
            baseline=b,
            scale_floor=True,  # repeated looks: see detect_drift and docs/history.md
        )
        # A step (change-point test): the line's t-test rarely sees one (its residuals are
        # the step), so it is a detector too, at a tenth of the level: the false-alarm
        # rate per diagnosis stays <= 1.1 alpha, and a real step has p ~ 1e-9.
        step = detect_step(
            tr.time[ok] / 86400.0, tr.value[ok], tr.std_error[ok], alpha=alpha_each / STEP_SHARE
        )
        # Significant twice over, as a comparison: a trend whose change over the
        # observed span stays within this recording's model error of the parameter is
        # not evidence of a physical change (different excursions, not wear).
        days = tr.time[ok] / 86400.0
        relevant = abs(res.slope) * float(np.ptp(days)) > model_error.get(k, 0.0)
        if not ((res.drifting and relevant) or step.is_step):
            continue
        entry = {
            "parameter": k,
            "slope_percent_per_day": 100.0 * res.slope / b if b else float("nan"),
            "p_value": res.p_value,
            "n_points": int(ok.sum()),
            "projected_crossing": None,
            "tolerance_percent": 100.0 * float(t),
            "method": res.method,
            "kind": "drift",
        }
        if step.is_step:
            times = np.sort(tr.time[ok])
            entry.update(
                kind="step",
                p_value=step.p_value,
                step_percent=100.0 * step.size / b if b else float("nan"),
                step_after=_iso_day(times[step.index - 1]),
                step_before=_iso_day(times[step.index]),
            )
            out.append(entry)
            continue
        crossing = res.projected_crossing_time
        if crossing is not None and np.isfinite(crossing):
            if crossing * 86400.0 <= float(np.max(tr.time[ok])):
                entry["already_beyond"] = True  # never project a crossing already past
            else:
                entry["projected_crossing"] = _iso_day(crossing * 86400.0)
        out.append(entry)
    return out
