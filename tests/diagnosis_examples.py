"""Diagnosis objects for the report and plotting tests (built by hand, not by a pipeline).

``faulty_diagnosis()``: the paper's Example II (R1 up 20 %) seen through an
identification with 0.3 % relative standard error on each of v1..v9 (one fixed
noise draw), compared with the nominal bearing and isolated by chi-square
signature matching. ``blocked_diagnosis()``: quality checks failed, nothing
identified. ``example_controller()``: observer + state feedback (eqs. (16)-(17))
placed on the nominal bearing at 10 kHz. ``example_trends()``: a month of R1
creeping up and a flat R2, with drift annotations in the layout of
``DriftResult.to_dict()``.
"""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import numpy as np
import scipy.linalg as sla
from scipy import stats

from maglevid.diagnose.compare import compare_parameters
from maglevid.diagnose.diagnosis import Diagnosis, QualityCheck
from maglevid.diagnose.isolate import isolate_fault
from maglevid.diagnose.percentage import percentage_index
from maglevid.identify.result import IdentificationResult, propagate_covariance
from maglevid.physics.amb import V_NAMES, AMBParameters, amb_state_space, parameters_from_v

NOMINAL = AMBParameters.nominal()
DT = 1e-4
REL_STD = 3e-3  # 0.3 % relative standard error on each v_i
PHYSICAL = ("R1", "R2", "L1", "L2", "Ls1", "Ls2", "ki1", "ki2", "kw1", "kw2", "x0", "K1", "K2")
CREATED = "2026-03-14T09:26:53+00:00"


def _physical_baseline(p: AMBParameters) -> dict[str, float]:
    return {
        "R1": p.R1,
        "R2": p.R2,
        "L1": p.L1,
        "L2": p.L2,
        "Ls1": p.Ls1,
        "Ls2": p.Ls2,
        "ki1": p.ki1,
        "ki2": p.ki2,
        "kw1": p.kw1,
        "kw2": p.kw2,
        "x0": p.x0,
        "K1": p.K1,
        "K2": p.K2,
    }


def _all_parameters(v: np.ndarray) -> np.ndarray:
    phys = parameters_from_v(v, m=NOMINAL.m, i0=NOMINAL.i0)
    return np.concatenate([v, [phys[k] for k in PHYSICAL]])


def identification(fault: dict[str, float], *, seed: int = 7) -> IdentificationResult:
    """An identification result of v1..v9 and the physical parameters, with covariance."""
    v_true = NOMINAL.with_fault(**fault).v()
    S = np.diag((REL_STD * v_true) ** 2)
    v_hat = v_true + np.random.default_rng(seed).multivariate_normal(np.zeros(9), S)
    theta, cov = propagate_covariance(_all_parameters, v_hat, S)
    names = (*V_NAMES, *PHYSICAL)
    return IdentificationResult(
        method="deadbeat",
        model=amb_state_space(v_hat, dt=DT),
        continuous_model=amb_state_space(v_hat),
        parameters=dict(zip(names, theta)),
        covariance=cov,
        n_samples=20_000,
        options={"order": 4, "deadbeat_steps": 2, "excitation": "PRBS", "m": 1.8, "i0": 0.5},
        fit={"one_step_fit_percent": 99.2, "residual_rms": 1.7e-7},
        notes=("m and i0 taken from the baseline (not identifiable from v alone)",),
    )


def faulty_diagnosis(fault: dict[str, float] | None = None) -> Diagnosis:
    """R1 up 20 % (Gosiewski & Paszowski, Example II), fully diagnosed."""
    fault = {"R1": 1.2} if fault is None else fault
    ident = identification(fault)
    v_hat = np.array([ident.parameters[k] for k in V_NAMES])
    S = np.asarray(ident.covariance)[:9, :9]
    se = ident.std_errors()
    estimates = {k: (ident.parameters[k], se[k]) for k in PHYSICAL}
    changes = compare_parameters(estimates, _physical_baseline(NOMINAL), tolerances=0.05)
    iso = isolate_fault(v_hat, S, NOMINAL)
    base_model = amb_state_space(NOMINAL)
    id_model = ident.continuous_model
    sig = [c for c in changes if c.significant]
    reasons = [
        f"{c.name} = {c.estimate:.4g} vs baseline {c.baseline:.4g}: "
        f"{c.change_percent:+.1f} % (tolerance ±{100 * c.tolerance:g} %)"
        for c in sig
    ]
    reasons.append(
        f"only {', '.join(iso.best.parameters)} changed fits all nine v_i: "
        f"χ² = {iso.best.chi2:.1f} with {iso.best.dof} dof (p = {iso.best.p_value:.2f}); "
        f"'nothing changed' is rejected (χ² = {iso.no_change.chi2:.0f}, {iso.no_change.dof} dof)"
    )
    what = iso.best.describe() if iso.explained else "significant changes, no single cause"
    return Diagnosis(
        verdict=f"Fault: {what}",
        verdict_code="fault" if iso.explained and sig else "unexplained_change",
        reasons=tuple(reasons),
        method="deadbeat",
        method_reason="the loop's C and F are known and nu + ny = nx: the deadbeat ARX gives "
        "the physical A, B directly (Gosiewski & Paszowski, Case I)",
        identification=ident,
        changes=tuple(changes),
        isolation=iso,
        quality=(
            QualityCheck("excitation SNR [dB]", True, 31.5, 20.0, "excitation well above noise"),
            QualityCheck("record length [periods]", True, 20000, 5000, "enough samples"),
            QualityCheck("saturation [%]", True, 0.0, 1.0, "no amplifier saturation"),
            QualityCheck(
                "residual whiteness p-value",
                False,
                0.004,
                0.01,
                "residuals slightly coloured: the standard errors may be optimistic",
                blocking=False,
            ),
        ),
        baseline={
            "source": "design (AMBParameters.nominal)",
            "parameters": {k: (v, 0.0) for k, v in _physical_baseline(NOMINAL).items()},
        },
        baseline_model=base_model,
        identified_model=id_model,
        percentage_index={
            "A_p": percentage_index(id_model.A, base_model.A),
            "B_p": percentage_index(id_model.B, base_model.B),
        },
        machine="AMB-7 test rig, axis X",
        recording="rig7/2026-03-14T0926 faulty.npz",
        recording_hash="sha256:3f1c9a0e5b7d2c4a",
        dt=DT,
        created_at=CREATED,
        notes=("baseline is the design model (zero standard error)",),
    )


def blocked_diagnosis() -> Diagnosis:
    """The quality checks stopped the diagnosis: nothing identified."""
    return Diagnosis(
        verdict="Cannot diagnose: the excitation is too weak and the amplifiers saturate",
        verdict_code="cannot_diagnose",
        reasons=(
            "excitation SNR 3.2 dB < 20 dB: the excitation is buried in noise",
            "amplifier saturation 12 % of samples > 1 %: the loop was not linear",
        ),
        quality=(
            QualityCheck("excitation SNR [dB]", False, 3.2, 20.0, "excitation buried in noise"),
            QualityCheck("record length [periods]", True, 8000, 5000, "enough samples"),
            QualityCheck("saturation [%]", False, 12.0, 1.0, "amplifiers saturate <often>"),
        ),
        baseline={"source": "design (AMBParameters.nominal)"},
        baseline_model=amb_state_space(NOMINAL),
        machine="AMB-7",
        recording="rig7/2026-03-15 quiet.npz",
        dt=DT,
        created_at=CREATED,
    )


def example_controller() -> dict[str, dict]:
    """The loop of a recording: observer + integral state feedback (eqs. (39)-(43)).

    Designed on the nominal bearing at 10 kHz with ``solve_discrete_are`` (stable
    by construction): LQR on the extended model of eq. (41) (integral of the
    displacement, ``E = [[1, 0, 0]]``) gives ``u = -K [x; e]``, ``K = [F, -Fe]``;
    a Kalman-type gain gives the prediction observer's ``G = -L``. Laid out as
    ``ClosedLoopData.loop`` (the simulator's layout).
    """
    sys = amb_state_space(NOMINAL, dt=DT)
    A, B, C = sys.A, sys.B, sys.C
    E = np.array([[1.0, 0.0, 0.0]])
    Ae = np.block([[A, np.zeros((4, 1))], [-E @ C @ A, np.eye(1)]])  # eq. (41)
    Be = np.vstack([B, -E @ C @ B])
    Q, R = np.diag([1e10, 1e3, 1.0, 1.0, 1e9]), np.eye(2)
    P = sla.solve_discrete_are(Ae, Be, Q, R)
    K = np.linalg.solve(R + Be.T @ P @ Be, Be.T @ P @ Ae)
    W, V = np.diag([1e-12, 1e-6, 1e-4, 1e-4]), np.diag([1e-12, 1e-6, 1e-6])
    Pe = sla.solve_discrete_are(A.T, C.T, W, V)
    L = np.linalg.solve(C @ Pe @ C.T + V, C @ Pe @ A.T).T
    return {
        "controller": {"type": "state_feedback_integral", "F": K[:, :4], "Fe": -K[:, 4:],
                       "E": E},
        "observer": {"type": "prediction", "A": A, "B": B, "C": C, "G": -L},
        "extended": {"A": Ae, "B": Be, "K": K},
    }  # fmt: skip


def example_trends() -> dict[str, dict]:
    """Weekly R1 (creeping up, then the fault) and R2 (flat), with drift annotations."""
    rng = np.random.default_rng(11)
    t0 = datetime(2026, 1, 3, 9, 0, tzinfo=timezone.utc)
    times = [t0 + timedelta(days=7 * k) for k in range(10)]
    secs = np.array([t.timestamp() for t in times])
    out = {}
    for name, base, slope_per_week in (("R1", 17.5, 0.38), ("R2", 17.5, 0.0)):
        se = np.full(10, 0.005 * base)
        v = base + slope_per_week * np.arange(10) + rng.normal(0.0, se)
        w = 1 / se**2
        tw = float(np.sum(w * secs) / np.sum(w))
        X = np.column_stack([np.ones(10), secs - tw]) * np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(X, v * np.sqrt(w), rcond=None)
        r = v * np.sqrt(w) - X @ coef
        phi = float(r @ r) / 8
        cov = phi * np.linalg.inv(X.T @ X)
        tstat = coef[1] / np.sqrt(cov[1, 1])
        p = float(2 * stats.t.sf(abs(tstat), 8))
        out[name] = {
            "time": [t.isoformat() for t in times],
            "value": v.tolist(),
            "std_error": se.tolist(),
            "drift": {
                "method": "wls",
                "slope": float(coef[1]),
                "t_ref": tw,
                "value_at_ref": float(coef[0]),
                "p_value": p,
                "drifting": p < 0.01,
            },
        }
    return out
