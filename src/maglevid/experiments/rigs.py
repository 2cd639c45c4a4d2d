"""Real-rig results: the UAQ steel-ball levitator and the NTNU "Maggy" platform.

``maglevid reproduce rigs`` prints the tables of ``docs/real-rigs.md``: data quality
(levitating segments, controller replay, sample time, excitation, quantisation),
the unstable pole of the UAQ levitator by the direct, indirect, two-stage and
grey-box methods beside the published physics, and for Maggy the identified
controller, the dominant closed-loop mode and what the record can and cannot say
about the plant.

It also holds :func:`simulate_uaq_twin`, a nonlinear simulation of the UAQ rig
(physics of :mod:`maglevid.physics.levitator`, the exact cascade of
:mod:`maglevid.control.cascade_pid`, sensor quantisation), on which every method
is checked before it meets the real records.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy import signal

from maglevid.control.cascade_pid import (
    CascadeGains,
    cascade_state_space,
    replay_cascade,
)
from maglevid.data import ClosedLoopData
from maglevid.diagnose.quality import (
    compare_signals,
    controller_equation_error,
    estimate_quantisation_step,
    excitation_summary,
    find_levitation_segments,
    fit_cascade_gains,
    fit_controller_arx,
    persistent_excitation_order,
    quantisation_snr,
    scan_sample_time,
    split_segments,
)
from maglevid.exceptions import MaglevidError
from maglevid.experiments._parallel import Progress, no_progress
from maglevid.identify.greybox import fit_equilibrium_line, fit_greybox_levitator
from maglevid.identify.indirect import fit_indirect
from maglevid.identify.levitator import fit_levitator
from maglevid.identify.pem import fit_pem
from maglevid.identify.twostage import fit_two_stage
from maglevid.jsonable import to_json_nulls
from maglevid.physics.levitator import (
    LevitatorParameters,
    equilibrium,
    integrate_zoh,
    linearize,
    unstable_pole,
)
from maglevid.simulate.levitator import (
    UAQ_TWIN,
    simulate_uaq_twin,
)

__all__ = [
    "PAPER",
    "PAPER_HELP",
    "UAQ_TWIN",
    "add_paper_arguments",
    "format_text",
    "load_maggy",
    "load_uaq",
    "maggy_results",
    "run_reproduction",
    "simulate_uaq_twin",
    "uaq_pole_table",
    "uaq_quality_table",
]

log = logging.getLogger(__name__)

PAPER = "rigs"
PAPER_HELP = "real-rig results: UAQ levitator (unstable pole by four methods) and Maggy"

PUBLISHED = LevitatorParameters.uaq()


def simulate_pd_dither_levitator(
    n: int = 6000,
    *,
    params: LevitatorParameters = PUBLISHED,
    y0: float = 0.005,
    dt: float = 0.002,
    kp: float = 131.0,
    kd: float = 2.0,
    kc: float = 30.0,
    dither: float = 0.01,
    force_noise: float = 0.3,
    y_noise: float = 1e-5,
    i_noise: float = 1e-3,
    u_limits: tuple[float, float] = (-24.0, 24.0),
    force_colour: float = 0.0,
    chatter: float = 0.0,
    quantum: tuple[float, float] | None = None,
    rng: np.random.Generator | None = None,
) -> ClosedLoopData:
    """A rig log with a dither and no ``r`` column: a one-coil levitator under a PD loop.

    The PD law on the gap sets a current reference with a white binary dither
    ``d`` (+-``dither`` A) added, and a current amplifier applies ``u = kc (i_ref - i)
    + R i_ref`` (proportional with the resistive drop fed forward; clipped to
    ``u_limits``)::

        i_ref = i0 + kp (y - y0) + kd (y_k - y_{k-1})/dt + d_k,   u = kc (i_ref - i) + R i_ref

    The log holds only ``y = [gap, i]`` and ``u`` (what such rigs record); ``d``
    is kept in ``metadata["truth_dither"]`` for tests. Default gains place the
    linear closed-loop mechanical poles near 60 rad/s, damping 0.7, for the UAQ
    published physics at 5 mm (``kp b = p^2 + 60^2``, ``kd b = 2 0.7 60``, ``b = 2 g/i0``).

    What the grey box's noise model leaves out, as on the UAQ rig (docs/real-rigs.md),
    can be added: ``force_colour`` (``0 <= c < 1``) makes the force disturbance AR(1),
    ``w_k = c w_(k-1) + sqrt(1 - c^2) e_k`` (same variance, correlation time
    ``-dt/ln c``); ``chatter`` [A] adds to the measured current a narrow-band AR(2)
    noise of that rms at 48 Hz (pole radius 0.98: the 47-50 Hz loop chatter);
    ``quantum = (q_y, q_i)`` rounds the logged gap and current to those steps. The
    defaults (white, none, none) draw the same random numbers as before.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    i0, _ = equilibrium(params, y0)
    d = dither * np.sign(rng.standard_normal(n))
    w = rng.standard_normal(n) * force_noise
    ny_ = rng.standard_normal(n) * y_noise
    ni_ = rng.standard_normal(n) * i_noise
    if force_colour:
        w = signal.lfilter([np.sqrt(1.0 - force_colour**2)], [1.0, -force_colour], w)
    if chatter:
        rad, ang = 0.98, 2.0 * np.pi * 48.0 * dt
        ch = signal.lfilter([1.0], [1.0, -2.0 * rad * np.cos(ang), rad**2], rng.standard_normal(n))
        ni_ = ni_ + chatter * ch / np.std(ch)
    x = np.array([y0, 0.0, i0])
    Y, U = np.empty((n, 2)), np.empty(n)
    y_prev = y0
    for t in range(n):
        ym, im = x[0] + ny_[t], x[2] + ni_[t]
        if quantum is not None:
            ym, im = quantum[0] * np.round(ym / quantum[0]), quantum[1] * np.round(im / quantum[1])
        i_ref = i0 + kp * (ym - y0) + kd * (ym - y_prev) / dt + d[t]
        u = float(np.clip(kc * (i_ref - im) + params.R * i_ref, *u_limits))
        Y[t], U[t], y_prev = (ym, im), u, ym
        pw = replace(params, g=params.g + w[t])  # held force disturbance over the period
        x = integrate_zoh(pw, x, u, dt, substeps=4, gap_limits=(1e-4, 0.02))
    return ClosedLoopData(
        y=Y,
        u=U,
        dt=dt,
        names={"y": ("gap", "i"), "u": ("u",)},
        units={"y": ("m", "A"), "u": ("V",)},
        metadata={
            "source": "simulate_pd_dither_levitator",
            "truth": params.to_dict(),
            "truth_pole_rad_s": unstable_pole(params, float(np.mean(Y[:, 0]))),
            "truth_dither": d.tolist(),
        },
    )


# ========================================================================================
# UAQ levitator: real records
# ========================================================================================

UAQ_DIR = "maglev-uaq-levitador"
MAGGY_DIR = "maggy-ntnu"
SESSIONS = ("constante", "escalon", "multiescalon", "senoidal", "chirp")
LEGACY = ("datos_levitador.txt", "MONIT_SWEEP.txt")
#: README: levitating means a gap of 2-10 mm; the command lives in 0..9.86 V.
POSITION_RANGE = (2e-3, 10e-3)
U_LIMITS = (0.0, 9.86)
#: Largest |y - yd| under control for the quality table.
MAX_TRACKING = 2e-3
#: Wider limits for the identification segments: a 1 mm reference step drives the ball
#: to 1.96 mm (2.04 mm from its new reference) for a few samples, and the step is the
#: only excitation of the step sessions. Held at the magnet the ball reads 1.0-1.3 mm.
ID_POSITION_RANGE = (1.5e-3, 12e-3)
ID_MAX_TRACKING = 3e-3
#: Gap at which poles are compared with the published physics.
Y_REF = 0.005


def default_data_dir() -> Path:
    """``../shared/data`` beside the checkout (as ``tests/conftest.py``)."""
    return Path(__file__).resolve().parents[3].parent / "shared" / "data"


def load_uaq(path: str | Path) -> ClosedLoopData:
    """Read a UAQ record with the io preset and give it the position reference as ``r``.

    ``maglevid.io.read_recording(path, mapping="uaq-levitador")`` keeps ``yd`` as an extra
    channel; the closed-loop methods want it as the exogenous signal ``r``, and the
    indirect method wants the cascade (``loop["controller"] = "uaq-cascade"``).
    """
    from maglevid.io import read_recording

    d = read_recording(path, mapping="uaq-levitador")
    yd = np.asarray(d.metadata["extra_signals"]["yd"]["values"], dtype=float)
    names = {**{k: tuple(v) for k, v in d.names.items()}, "r": ("yd",)}
    units = {**{k: tuple(v) for k, v in d.units.items()}, "r": ("m",)}
    loop = {"controller": "uaq-cascade", "gains": CascadeGains.uaq().to_dict()}
    return d.replace(r=yd, names=names, units=units, loop=loop)


def _uaq_path(data_dir: Path, name: str) -> Path:
    folder = data_dir / UAQ_DIR
    if name in LEGACY:
        return folder / name
    hits = sorted(folder.glob(f"dataset_{name}_*.txt"))
    if not hits:
        raise FileNotFoundError(f"no dataset_{name}_*.txt in {folder}")
    return hits[0]


def _signals(d: ClosedLoopData) -> tuple[np.ndarray, ...]:
    return d.y[:, 0], d.y[:, 1], d.u[:, 0], d.r[:, 0]


def uaq_segments(d: ClosedLoopData, *, for_identification: bool = False):
    """Levitating segments of a UAQ record: the README's thresholds (quality table), or
    the wider ones that keep the reference steps (identification; saturated samples
    kept - the direct and two-stage methods use the logged signals as they are)."""
    y, _, u, yd = _signals(d)
    return find_levitation_segments(
        y,
        dt=d.dt,
        position_range=ID_POSITION_RANGE if for_identification else POSITION_RANGE,
        command=u,
        command_limits=U_LIMITS,
        reference=yd,
        max_tracking_error=ID_MAX_TRACKING if for_identification else MAX_TRACKING,
        exclude_saturation=not for_identification,
    )


def uaq_quality_row(name: str, d: ClosedLoopData) -> dict[str, Any]:
    """Data quality of one UAQ record (one row of the quality table)."""
    y, i, u, yd = _signals(d)
    rep = uaq_segments(d)
    mask = rep.mask()
    row: dict[str, Any] = {
        "record": name,
        "N": d.n_samples,
        "usable_percent": 100 * rep.usable_fraction,
        "segments": len(rep.segments),
        "excluded_s": {k: round(v, 2) for k, v in rep.excluded_by_reason().items()},
    }
    w = np.column_stack([yd, y, i])
    lin = replay_cascade(yd, y, i).linear & (u > U_LIMITS[0]) & (u < U_LIMITS[1])
    ok = lin.copy()
    ok[2:] &= lin[1:-1] & lin[:-2]
    r, valid = controller_equation_error(cascade_state_space(), w, u)
    row["law_equation_error_V"] = float(np.sqrt(np.mean(r[ok & valid] ** 2)))
    if "id" in (d.metadata.get("extra_signals") or {}):
        idl = np.asarray(d.metadata["extra_signals"]["id"]["values"], dtype=float)
        rep2 = replay_cascade(yd, y, i, id_logged=idl)
        row["replay_id_rms_A"] = compare_signals(idl, rep2.id).rms
        row["replay_u_rms_V"] = compare_signals(u, rep2.u).rms
    try:
        g, _, _ = fit_cascade_gains(yd, y, i, u, dt=d.dt, mask=lin)
        row["fitted_gains"] = {
            k: round(getattr(g, k), 3) for k in ("kp", "ki", "kd", "kpi", "kii")
        }
    except MaglevidError as exc:  # pragma: no cover - real data always has samples
        row["fitted_gains"] = str(exc)
    scan = scan_sample_time(
        np.round(np.arange(0.005, 0.0151, 0.001), 4),
        lambda dt: controller_equation_error(cascade_state_space(CascadeGains(dt=dt)), w, u)[0][
            ok & valid
        ],
    )
    row["best_dt_s"] = scan.best
    row["dt_contrast"] = scan.contrast()
    row["y_step_um"] = 1e6 * estimate_quantisation_step(y)
    row["i_step_mA"] = 1e3 * estimate_quantisation_step(i)
    if mask.sum() > 100:
        row["y_std_um"] = 1e6 * float(np.mean([y[a:b].std() for a, b in rep.bounds()]))
        row["y_snr_dB"] = float(
            np.mean([quantisation_snr(y[a:b], 0.05 / 1023) for a, b in rep.bounds()])
        )
        seg = max(rep.bounds(), key=lambda s: s[1] - s[0])
        row["yd_pe_order"] = persistent_excitation_order(yd[seg[0] : seg[1]], max_order=20)[0]
        ex = excitation_summary(
            {"yd": yd[seg[0] : seg[1]], "y": y[seg[0] : seg[1]], "i": i[seg[0] : seg[1]]},
            dt=d.dt,
        )
        row["yd_f90_hz"] = ex["yd"]["f90_hz"]
        row["y_peak_hz"] = ex["y"]["peak_hz"]
        row["i_f50_hz"] = ex["i"]["f50_hz"]
    return row


def uaq_quality_table(data_dir: Path, progress: Callable[[Iterable], Iterable] = iter) -> list:
    """Quality rows for the five sessions and the two legacy files."""
    rows = []
    for name in progress([*SESSIONS, *LEGACY]):
        rows.append(uaq_quality_row(name, load_uaq(_uaq_path(data_dir, name))))
    return rows


def _estimate(res: Any, key: str = "pole_rad_s") -> dict[str, float]:
    se = res.std_errors()[key]
    lo, hi = res.confidence_intervals(0.95)[key]
    return {"rad_s": res.parameters[key], "se": se, "ci_low": lo, "ci_high": hi}


def uaq_session_estimates(d: ClosedLoopData) -> dict[str, Any]:
    """Unstable-pole estimates of one session by every method (see docs/real-rigs.md)."""
    y, i, u, yd = _signals(d)
    lev = uaq_segments(d, for_identification=True).bounds()
    sat = (u <= U_LIMITS[0] + 1e-3) | (u >= U_LIMITS[1] - 1e-3)
    linear = split_segments(lev, sat, pad=(0, 2), min_length=150)
    steps = np.r_[False, np.diff(yd) != 0]
    oppts = split_segments(lev, steps, pad=(0, 150), min_length=300)
    gap = float(np.mean(np.concatenate([y[a:b] for a, b in lev])))
    out: dict[str, Any] = {
        "mean_gap_mm": 1e3 * gap,
        "published_at_mean_gap": unstable_pole(PUBLISHED, gap),
        "segments": {"levitating": lev, "linear": linear, "operating_points": oppts},
        "estimates": {},
        "notes": {},
    }
    est = out["estimates"]

    def run(label: str, fn: Callable[[], Any], key: str = "pole_rad_s") -> None:
        try:
            res = fn()
            est[label] = _estimate(res, key)
            out["notes"][label] = [n for n in res.notes if "pole" in n or "optimiser" in n]
        except MaglevidError as exc:
            est[label] = {"error": str(exc)}

    try:
        cons = fit_levitator(d)
        c = cons.extras["consensus"]
        y_c = float(cons.options["y_ref"])
        est["levitator consensus (own gap)"] = {
            "rad_s": c["pole_rad_s"], "se": float("nan"), "ci_low": c["ci95"][0],
            "ci_high": c["ci95"][1], "gap_mm": 1e3 * y_c,
            "published_there": unstable_pole(PUBLISHED, y_c),
        }  # fmt: skip
        out["notes"]["levitator consensus (own gap)"] = [c.get("inconclusive", c["chosen_model"])]
    except MaglevidError as exc:
        est["levitator consensus (own gap)"] = {"error": str(exc)}
    run("pem-arx i->y", lambda: fit_pem(d, input="y:1", na=2, nb=3, nk=0, segments=lev))
    run("pem-armax i->y", lambda: fit_pem(d, input="y:1", na=2, nb=3, nk=0, nc=2,
                                          structure="armax", segments=lev))  # fmt: skip
    run("two-stage i->y", lambda: fit_two_stage(d, input="y:1", nb=3, nk=0, segments=lev))
    if len(linear):
        init = linearize(UAQ_TWIN, gap, dt=d.dt)

        def indirect() -> Any:
            res = fit_indirect(d, controller="uaq-cascade", intermediate="y:1", initial=init,
                               segments=linear, max_nfev=60)  # fmt: skip
            out["indirect_voltage_pole"] = _estimate(res, "pole_rad_s")
            return res

        run("indirect u->[y,i] (i->y zero)", indirect, "intermediate_pole_rad_s")
    if not oppts and lev:
        # sine/chirp references: no constant operating point; linearise at segment means
        oppts = [s for s in lev if s[1] - s[0] >= 300]
        out["segments"]["operating_points"] = oppts
        out["notes"]["greybox"] = ["reference varies continuously: linearised at the mean gap"]
    if len(oppts):
        run("greybox", lambda: fit_greybox_levitator(d, segments=oppts, y_ref=Y_REF))
        run("greybox +lag +beta", lambda: fit_greybox_levitator(
            d, segments=oppts, y_ref=Y_REF, flux_lag=True, free_gain=True))  # fmt: skip
        run("greybox dynamics only", lambda: fit_greybox_levitator(
            d, segments=oppts, y_ref=Y_REF, use_equilibrium=False))  # fmt: skip
        gaps = [float(y[a:b].mean()) for a, b in oppts]
        if np.ptp(gaps) > 2e-4:
            line = fit_equilibrium_line(gaps, [float(i[a:b].mean()) for a, b in oppts],
                                        y_ref=Y_REF, dt=d.dt)  # fmt: skip
            est["equilibrium line"] = {
                "rad_s": line["pole_rad_s"],
                "se": line["pole_rad_s_se"],
                "ci_low": line["pole_rad_s"] - 1.96 * line["pole_rad_s_se"],
                "ci_high": line["pole_rad_s"] + 1.96 * line["pole_rad_s_se"],
                "a_mm": 1e3 * line["a"],
                "k_H": line["k"],
            }
    return out


def uaq_pole_table(
    data_dir: Path, sessions: Iterable[str] = SESSIONS, progress: Callable = iter
) -> dict[str, Any]:
    """Estimates for each session beside the published physics (43.9 rad/s at 5 mm)."""
    out: dict[str, Any] = {
        "published": {
            "pole_rad_s_at_5mm": unstable_pole(PUBLISHED, Y_REF),
            "pole_z_at_5mm": float(np.exp(unstable_pole(PUBLISHED, Y_REF) * 0.01)),
            "i0_at_5mm": equilibrium(PUBLISHED, Y_REF)[0],
        },
        "sessions": {},
    }
    for name in progress(list(sessions)):
        out["sessions"][name] = uaq_session_estimates(load_uaq(_uaq_path(data_dir, name)))
    return out


# ========================================================================================
# Maggy
# ========================================================================================

MAGGY_ALPHA = 0.15  # field EMA constant of the upstream V2 PD firmware (an assumption)
#: s1z is +11 mT with the magnet resting and about -13.6 mT levitating (README); the
#: 4.5 Hz oscillation swings it by +-3 mT late in the record.
MAGGY_S1Z_RANGE = (-20.0, -5.0)


def load_maggy(path: str | Path) -> ClosedLoopData:
    """Read the Maggy record with the io preset (9 field channels, 2 PWM inputs)."""
    from maglevid.io import read_recording

    return read_recording(path, mapping="maggy-ntnu")


def _v2_firmware_constants(a1: float, a2: float, n0: float, n1: float, dt: float) -> dict:
    """Solve the V2 PD firmware structure for (beta, c, Kp, Kd) given alpha.

    Firmware (``V2x_PD_example.ino``): ``r = b - 0.99 mean - c u_{k-1}``,
    ``m = alpha r + (1-alpha) m_prev``, ``d = beta (m - m_prev)/dt' + (1-beta) d_prev``,
    ``u = -Kp m - Kd d``. Hence ``u (D + c N q^-1) = N b + const`` with
    ``D = (1-(1-alpha) q^-1)(1-(1-beta) q^-1)``, ``N = n0 + n1 q^-1``,
    ``n0 = -alpha (Kp + Kd/dt')``, ``n1 = alpha (Kp (1-beta) + Kd/dt')``; the four
    ARX coefficients fix four unknowns once ``alpha`` is given.
    """
    al = MAGGY_ALPHA
    rho = n1 / n0
    beta = ((1 - al) + rho * (a1 + 2 - al) - a2) / ((1 - al) + rho)
    c = (a1 + 2 - al - beta) / n0
    kp = -(n0 + n1) / (al * beta)
    kd_dt = -n0 / al - kp
    return {"alpha": al, "beta": beta, "c": c, "Kp": kp, "Kd": kd_dt * (dt + 10e-6)}


def maggy_results(data_dir: Path) -> dict[str, Any]:
    """Controller, closed-loop mode and plant as far as the Maggy record allows."""
    d = load_maggy(data_dir / MAGGY_DIR / "PD_data_with_input.mat")
    B, U = np.asarray(d.y), np.asarray(d.u)
    names = d.channel_names("y")
    rep = find_levitation_segments(
        B[:, 2], dt=d.dt, position_range=MAGGY_S1Z_RANGE, command=U,
        command_limits=(-255.0, 255.0), guard=0.1, settle=0.3, min_duration=1.0,
    )  # fmt: skip
    seg = max(rep.bounds(), key=lambda s: s[1] - s[0])
    out: dict[str, Any] = {
        "dt_s": d.dt,
        "levitating_s": [round(a * d.dt, 3) for a in seg],
        "segments": rep.bounds(),
        "controller": {},
        "oscillation": {},
        "plant": {},
    }
    mask = np.zeros(d.n_samples, dtype=bool)
    mask[seg[0] : seg[1]] = True
    for j, un in enumerate(d.channel_names("u")):
        ok = mask & (np.abs(U[:, j]) < 255)
        pd = fit_controller_arx(np.hstack([B, np.r_[B[:1], B[:-1]]]), U[:, j], na=0, nb=1,
                                mask=ok)  # fmt: skip
        full = fit_controller_arx(B, U[:, j], na=2, nb=2, nk=0, mask=ok)
        main = int(np.argmax(np.abs(full.b).sum(axis=1)))
        others = np.delete(np.abs(full.b), main, axis=0).max()
        row = {
            "static_pd_r2": pd.r_squared,
            "arx22_r2": full.r_squared,
            "arx22_residual_rms_counts": full.residual_rms,
            "channel": names[main],
            "other_channels_max_over_main": float(others / np.abs(full.b[main]).max()),
            "a": full.a.tolist(),
            "b_main": full.b[main].tolist(),
            "poles": [complex(p) for p in full.poles()],
        }
        row["v2_firmware"] = _v2_firmware_constants(
            float(full.a[0]), float(full.a[1]), float(full.b[main, 0]), float(full.b[main, 1]),
            d.dt,
        )  # fmt: skip
        out["controller"][un] = row
    # Dominant closed-loop mode: spectra and an AR(8) model of the field channels.
    s0, s1 = seg
    ex = excitation_summary({n: B[s0:s1, k] for k, n in enumerate(names)} |
                            {u: U[s0:s1, k] for k, u in enumerate(d.channel_names("u"))},
                            dt=d.dt, nperseg=min(8192, s1 - s0))  # fmt: skip
    out["oscillation"]["peak_hz"] = {k: v["peak_hz"] for k, v in ex.items()}
    # The mode itself: an AR(20) model of s1x decimated to 100 Hz; the complex pole pair
    # nearest the spectral peak gives frequency and damping.
    q = round(0.01 / d.dt)
    from scipy import signal  # ~1 s to import: only where it is used

    x = signal.decimate(B[s0:s1, 0] - B[s0:s1, 0].mean(), q, ftype="fir", zero_phase=True)
    n_ar = 20
    X = np.column_stack([x[n_ar - k - 1 : x.size - k - 1] for k in range(n_ar)])
    th, *_ = np.linalg.lstsq(X, x[n_ar:], rcond=None)
    sp = np.log(np.roots(np.r_[1.0, -th]).astype(complex)) / (q * d.dt)
    sp = sp[sp.imag > 0]
    f_peak = out["oscillation"]["peak_hz"]["s1x"]
    best = sp[np.argmin(np.abs(sp.imag / (2 * np.pi) - f_peak))]
    out["oscillation"]["ar_mode_hz"] = float(abs(best) / (2 * np.pi))
    out["oscillation"]["ar_mode_damping"] = float(-best.real / abs(best))
    # Plant: direct ARX per axis, u_j -> the field channel the controller uses.
    for j, un in enumerate(d.channel_names("u")):
        ch = out["controller"][un]["channel"]
        k = names.index(ch)
        try:
            res = fit_pem(d, output=f"y:{k}", input=f"u:{j}", na=4, nb=4, nk=1,
                          segments=[seg])  # fmt: skip
            z = np.roots(res.extras["A"])
            out["plant"][f"{un}->{ch}"] = {
                **_estimate(res),
                "pole_z": res.parameters["pole_z"],
                "poles_z": [complex(p) for p in z],
                "one_step_fit_percent": res.fit["one_step_fit_percent"],
            }
        except MaglevidError as exc:  # pragma: no cover
            out["plant"][f"{un}->{ch}"] = {"error": str(exc)}
    return out


# ========================================================================================
# maglevid reproduce rigs
# ========================================================================================


def add_paper_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--data",
        default=None,
        help="folder holding maglev-uaq-levitador/ and maggy-ntnu/ (default: ../shared/data)",
    )
    parser.add_argument(
        "--sessions",
        default=",".join(SESSIONS),
        help="UAQ sessions for the pole table (comma-separated; default: all five)",
    )
    parser.add_argument("--skip-maggy", action="store_true", help="leave the Maggy record out")


def run_reproduction(
    args: argparse.Namespace, *, progress: Progress | None = None
) -> dict[str, Any]:
    """Compute every table of docs/real-rigs.md (takes a minute or two).

    ``progress`` (see :data:`~maglevid.experiments._parallel.Progress`, default
    none) reports the records read.
    """
    progress = progress or no_progress

    data_dir = Path(args.data) if args.data else default_data_dir()
    if not (data_dir / UAQ_DIR).is_dir():
        raise FileNotFoundError(f"no {UAQ_DIR}/ under {data_dir}; pass --data")

    def prog(it: Iterable, desc: str = "records") -> Iterable:
        return progress(it, desc=desc)

    out: dict[str, Any] = {
        "data": str(data_dir),
        "quality": uaq_quality_table(data_dir, progress=prog),
        "poles": uaq_pole_table(
            data_dir, [s for s in args.sessions.split(",") if s], progress=prog
        ),
    }
    if not args.skip_maggy and (data_dir / MAGGY_DIR).is_dir():
        out["maggy"] = maggy_results(data_dir)
    return to_json_nulls(out)


def _f(v: Any, fmt: str = ".3g") -> str:
    return "-" if v is None else format(v, fmt)


def format_text(result: dict[str, Any]) -> str:
    """The tables of docs/real-rigs.md as plain text."""
    L: list[str] = ["UAQ levitator: data quality"]
    L.append(
        f"{'record':>22} {'N':>5} {'usable%':>7} {'eq.err V':>8} {'kp':>7} {'ki':>6} {'kd':>6} "
        f"{'kpi':>6} {'kii':>7} {'dt':>6} {'y um':>5} {'i mA':>5} {'SNR dB':>6} {'PE':>3}"
    )
    for r in result["quality"]:
        g = r["fitted_gains"] if isinstance(r["fitted_gains"], dict) else {}
        L.append(
            f"{r['record']:>22} {r['N']:>5} {r['usable_percent']:>7.1f} "
            f"{r['law_equation_error_V']:>8.4f} {_f(g.get('kp'), '.2f'):>7} "
            f"{_f(g.get('ki'), '.2f'):>6} {_f(g.get('kd'), '.3f'):>6} "
            f"{_f(g.get('kpi'), '.2f'):>6} "
            f"{_f(g.get('kii'), '.0f'):>7} {r['best_dt_s']:>6.3f} {r['y_step_um']:>5.1f} "
            f"{r['i_step_mA']:>5.2f} {_f(r.get('y_snr_dB'), '.1f'):>6} "
            f"{_f(r.get('yd_pe_order'), 'd'):>3}"
        )
        if "replay_id_rms_A" in r:
            L.append(
                f"{'':>22} stage-wise replay: id {1e3 * r['replay_id_rms_A']:.2f} mA rms, "
                f"u {r['replay_u_rms_V']:.3f} V rms"
            )
    P = result["poles"]
    pub = P["published"]
    L.append("")
    L.append(
        f"UAQ levitator: unstable pole [rad/s] (published physics at 5 mm: "
        f"{pub['pole_rad_s_at_5mm']:.2f} rad/s, z = {pub['pole_z_at_5mm']:.4f})"
    )
    for name, s in P["sessions"].items():
        L.append(
            f"  {name}: mean gap {s['mean_gap_mm']:.2f} mm, published physics there "
            f"{s['published_at_mean_gap']:.1f} rad/s"
        )
        for label, e in s["estimates"].items():
            if "error" in e:
                L.append(f"    {label:>30}: failed ({e['error'][:70]})")
            else:
                at = f"  at {e['gap_mm']:.2f} mm" if "gap_mm" in e else ""
                L.append(
                    f"    {label:>30}: {_f(e['rad_s'], '7.1f')} +- {_f(e['se'], '.2g'):>6}  "
                    f"[{_f(e['ci_low'], '.1f')}, {_f(e['ci_high'], '.1f')}]{at}"
                )
        if "indirect_voltage_pole" in s:
            e = s["indirect_voltage_pole"]
            L.append(
                f"    {'indirect u->y (voltage plant)':>30}: {e['rad_s']:7.1f} +- "
                f"{_f(e['se'], '.2g'):>6}"
            )
    if "maggy" in result:
        M = result["maggy"]
        L.append("")
        L.append(
            f"Maggy: levitating {M['levitating_s'][0]:.2f}-{M['levitating_s'][1]:.2f} s "
            f"(dt = {M['dt_s'] * 1e6:.1f} us)"
        )
        for un, c in M["controller"].items():
            v = c["v2_firmware"]
            L.append(
                f"  {un}: uses {c['channel']} only "
                f"(others < {c['other_channels_max_over_main']:.1e}"
                f" of it); static PD R^2 {c['static_pd_r2']:.4f}, 2nd-order law R^2 "
                f"{c['arx22_r2']:.6f}, residual {c['arx22_residual_rms_counts']:.4f} counts"
            )
            L.append(
                f"      V2 firmware reading (alpha = {v['alpha']}): beta {v['beta']:.4f}, "
                f"feed-through c {v['c']:.5f}/count, Kp {v['Kp']:.1f}, Kd {v['Kd']:.3f}"
            )
        o = M["oscillation"]
        L.append(
            "  closed-loop oscillation: spectral peaks "
            + ", ".join(
                f"{k} {v:.2f} Hz" for k, v in o["peak_hz"].items() if k in ("s1x", "s1z", "u1")
            )
            + (
                f"; AR mode {o['ar_mode_hz']:.2f} Hz, damping {o['ar_mode_damping']:.3f}"
                if "ar_mode_hz" in o
                else ""
            )
        )
        for k, p in M["plant"].items():
            if "error" in p:
                L.append(f"  plant {k}: failed")
                continue
            zs = ", ".join(f"{complex(z['re'], z['im']):.3f}" for z in p["poles_z"])
            L.append(
                f"  plant {k} (direct ARX(4,4,1)): poles z = {zs}; largest real "
                f"{p['pole_z']:.4f}; one-step fit {p['one_step_fit_percent']:.1f} %"
            )
    return "\n".join(L)
