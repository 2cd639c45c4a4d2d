"""Indirect closed-loop identification with a known linear controller.

The closed loop from the reference (or any exogenous signal) to the measured
outputs is stable even when the plant is not, so it can be fitted by output error
without an unstable predictor. The indirect method (Ljung 1999, sec. 13.5)
identifies that closed loop and solves for the plant with the known controller.
Here the two steps are done at once, in the *closed-loop parametrisation*: the
plant ``P(theta)`` (a SIMO transfer function with common denominator) is closed
with the known controller ``K`` (:func:`~maglevid.identify.closedloop.close_loop`)
and ``theta`` minimises the output error of the closed loop driven by the logged
exogenous signals::

    min_theta  sum_t || W (z_t - G_cl(theta; q) r_t - F_t(theta) x0 - c) ||^2

with ``z = [y; u]`` (the channels chosen), one free closed-loop initial state
``x0`` and one offset vector ``c`` per segment (linear, eliminated by least
squares for every ``theta``: variable projection, Golub & Pereyra 1973). The
plant comes straight out with its unstable poles; nothing is ever simulated open
loop. Because the controller is used as known, its gains and sample time must be
right (check them with :mod:`maglevid.diagnose.quality`), and saturated samples
must be excluded (segments).

The UAQ cascade is available as ``controller="uaq-cascade"``: inputs
``[yd, y, i]``, output ``u`` (:func:`maglevid.control.cascade_pid.cascade_state_space`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, signal

from maglevid.control.cascade_pid import CascadeGains, cascade_state_space
from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError, ModelError
from maglevid.identify.closedloop import (
    close_loop,
    continuous_or_note,
    covariance_from_jacobian,
    extend_covariance,
    fit_percent,
    pole_statistics,
    resolve_channel,
    resolve_segments,
    simo_polynomials_to_state_space,
)
from maglevid.identify.options import Option, declared
from maglevid.identify.pem import fit_pem
from maglevid.identify.result import IdentificationResult
from maglevid.lti import StateSpace

__all__ = ["METHODS", "OPTIONS_INDIRECT", "fit_indirect", "resolve_controller"]

log = logging.getLogger(__name__)

PRESETS = ("uaq-cascade",)


def resolve_controller(
    data: ClosedLoopData, controller: Any, controller_inputs: Sequence[str] | None
) -> tuple[StateSpace, list[str]]:
    """The known controller as a discrete StateSpace and the channel feeding each input.

    ``controller`` may be a :class:`StateSpace`, a dict (``StateSpace.to_dict``), the
    preset ``"uaq-cascade"`` (gains from ``data.loop["gains"]`` when present, else the
    UAQ gains), or ``None`` (then ``data.loop["controller"]`` is used).
    """
    c = data.loop.get("controller") if controller is None else controller
    if c is None and (data.loop.get("controller_law") or {}).get("kind") == "cascade-pid-pi":
        c = "uaq-cascade"  # the io preset of the UAQ legacy files documents the law
    if c is None:
        raise DataError(
            "the indirect method needs the controller: pass `controller=` (StateSpace, dict "
            "or 'uaq-cascade') or store it in data.loop['controller']"
        )
    if isinstance(c, str):
        if c != "uaq-cascade":
            raise DataError(f"unknown controller preset {c!r}; known: {PRESETS}")
        K = cascade_state_space(_cascade_gains_of(data))
        extras = data.metadata.get("extra_signals") or {}
        ref = "r:0" if data.r is not None else ("extra:yd" if "yd" in extras else "r:0")
        default_inputs = [ref, "y:0", "y:1"]
        if abs(K.dt - data.dt) > 1e-12 * data.dt:
            raise DataError(f"controller dt = {K.dt} differs from the recording's dt = {data.dt}")
    elif isinstance(c, StateSpace):
        K = c
        default_inputs = None
    elif isinstance(c, Mapping):
        if not {"A", "B", "C"} <= set(map(str, c)):
            # e.g. the simulated bearing's state feedback with integral action and observer
            # (eqs. (42)-(43)): a bare "missing ['A', 'B', 'C']" was all it said (found
            # from outside, issue 16, thirteenth session)
            kind = f" (a {c['kind']!r} description)" if "kind" in c else ""
            raise DataError(
                f"the indirect method needs the controller as one discrete state-space model "
                f"u = K(z) [inputs] (A, B, C, D); this record's loop['controller'] is not "
                f"one{kind}. For a two-coil bearing use method ml, physical, pbsid or ssarx "
                "(they need no controller model); or pass `controller=` as a StateSpace"
            )
        K = StateSpace.from_dict(dict(c))
        default_inputs = None
    else:
        raise DataError(f"`controller` must be a StateSpace, dict or preset; got {type(c)}")
    if not K.is_discrete or abs(K.dt - data.dt) > 1e-9 * data.dt:
        raise DataError(f"the controller must be discrete with dt = {data.dt}; it has {K.dt}")
    if K.ny != 1:
        raise DataError(f"the controller must have one output (u); it has {K.ny}")
    inputs = list(controller_inputs) if controller_inputs is not None else default_inputs
    if inputs is None or len(inputs) != K.nu:
        raise DataError(
            f"`controller_inputs` must list the {K.nu} channel(s) feeding the controller; "
            f"got {inputs!r}"
        )
    return K, inputs


def _cascade_gains_of(data: ClosedLoopData) -> CascadeGains | None:
    """Gains from ``loop["gains"]`` (CascadeGains fields) or from the io preset's
    ``loop["controller_law"]`` (outer/inner kp, ki, kd); ``None``: the UAQ gains."""
    gains = data.loop.get("gains")
    if gains:
        return CascadeGains(**{k: float(v) for k, v in dict(gains).items()})
    law = data.loop.get("controller_law")
    if law and "outer" in law and "inner" in law:
        o, i = law["outer"], law["inner"]
        return CascadeGains(
            kp=float(o["kp"]), ki=float(o["ki"]), kd=float(o["kd"]),
            kpi=float(i["kp"]), kii=float(i["ki"]), dt=float(law.get("Ts_s", data.dt)),
        )  # fmt: skip
    return None


#: The options of ``indirect`` (defaults: :func:`fit_indirect`'s signature).
OPTIONS_INDIRECT = (
    Option("controller", "object", "known controller: StateSpace, dict or 'uaq-cascade'"),
    Option("controller_inputs", "channels", "channel feeding each controller input"),
    Option("plant_input", "channel", "the plant input (the controller output)"),
    Option("plant_outputs", "channels", "plant outputs modelled (default: y among inputs)"),
    Option("fit_channels", "channels", "channels compared in the output-error cost"),
    Option("intermediate", "channel", "plant output that drives the rest of the plant"),
    Option("n", "int", "order of the common denominator", low=1),
    Option("nk", "int", "input delay in samples (>= 1: no algebraic loop)", low=1),
    Option("segments", "segments", "linear, unsaturated pieces [start, stop) (default all)"),
    Option("burn_in", "int", "samples of each segment left out of the cost", low=0),
    Option("initial", "object", "starting plant: StateSpace or theta = [a, b per output]"),
    Option("max_nfev", "int", "limit on residual evaluations of the fit", low=1),
)


@dataclass(frozen=True)
class _Channels:
    """The loop's signals for the closed-loop output error (resolved once)."""

    plant_input: Any  # the resolved plant input channel
    outputs: list[Any]  # resolved plant output channels
    intermediate: str | None
    feedback: list[int]  # per controller input: index of the plant output, -1 exogenous
    exogenous: np.ndarray  # (N, n_exo) signals driving the closed loop
    fits: list[Any]  # resolved channels of the cost
    z_index: list[int]  # per fit channel: closed-loop output row (outputs, then u)

    @property
    def specs(self) -> list[str]:
        return [p.spec for p in self.outputs]


def _loop_channels(
    data: ClosedLoopData,
    cin: list[str],
    plant_input: str,
    plant_outputs: Sequence[str] | None,
    fit_channels: Sequence[str] | None,
    intermediate: str | None,
) -> _Channels:
    """Which logged channel is the plant input, each plant output, each exogenous
    input of the controller and each fitted channel (clear errors otherwise)."""
    uch = resolve_channel(data, plant_input)
    chans = [resolve_channel(data, s) for s in cin]
    if plant_outputs is None:
        plant_outputs = [c.spec for c in chans if c.signal == "y"]
    pouts = [resolve_channel(data, s) for s in plant_outputs]
    if not pouts:
        raise DataError(
            "no plant outputs: give `plant_outputs` or feed y channels to the controller"
        )
    pspec = [p.spec for p in pouts]
    if intermediate is not None:
        intermediate = resolve_channel(data, intermediate).spec
        if intermediate not in pspec:
            raise DataError(f"`intermediate` {intermediate!r} is not a plant output {pspec}")
    feedback = [pspec.index(c.spec) if c.spec in pspec else -1 for c in chans]
    if all(f >= 0 for f in feedback):
        raise DataError("the controller has no exogenous input: nothing drives the closed loop")
    exo = np.column_stack([c.values for c, f in zip(chans, feedback) if f < 0])
    fits = [resolve_channel(data, s) for s in (fit_channels or pspec)]
    z_index = []
    for f in fits:
        if f.spec in pspec:
            z_index.append(pspec.index(f.spec))
        elif f.spec == uch.spec:
            z_index.append(len(pspec))
        else:
            raise DataError(f"fit channel {f.spec} is neither a plant output nor the plant input")
    return _Channels(uch, pouts, intermediate, feedback, exo, fits, z_index)


@dataclass(frozen=True)
class _ClosedLoopOutputError:
    """The cost of the module notes: ``W (z_t - G_cl(theta; q) r_t - F_t(theta) x0 - c)``
    over the segments, ``x0`` and ``c`` eliminated by least squares (variable projection)."""

    K: StateSpace
    ch: _Channels
    segs: list[tuple[int, int]]
    Z: np.ndarray  # the fitted channels
    w: np.ndarray  # their weights 1/std
    n: int
    nk: int
    dt: float
    burn_in: int

    def plant(self, theta: np.ndarray) -> StateSpace:
        """``P(theta)``: common denominator ``a``, one numerator per output from ``q^-nk``."""
        n, nk = self.n, self.nk
        a = np.r_[1.0, theta[:n]]
        bs = [np.r_[np.zeros(nk), theta[n + j * n : n + (j + 1) * n]]
              for j in range(len(self.ch.outputs))]  # fmt: skip
        return simo_polynomials_to_state_space(a, bs, self.dt)

    def simulate(self, theta: np.ndarray) -> list[np.ndarray] | None:
        """Per segment: fitted channels, closed-loop response incl. x0 and offsets;
        ``None`` when the closed loop with the known controller is not stable."""
        try:
            cl = close_loop(self.plant(theta), self.K, self.ch.feedback)
        except ModelError:
            return None
        rho = np.max(np.abs(cl.poles())) if cl.nx else 0.0
        if not np.isfinite(rho) or rho >= 1.0:
            return None
        z_index, w, burn_in = self.ch.z_index, self.w, self.burn_in
        Csel = cl.C[z_index]
        Dsel = cl.D[z_index]
        # Transfer functions of the selected channels: common denominator det(zI - A).
        den = np.poly(cl.A)
        out = []
        for a0, b0 in self.segs:
            r = self.ch.exogenous[a0:b0]
            m = b0 - a0
            forced = np.zeros((m, len(z_index)))
            for j in range(len(z_index)):
                for e in range(r.shape[1]):
                    bcol = cl.B[:, e : e + 1]
                    num = np.poly(cl.A - bcol @ Csel[j : j + 1]) - den + Dsel[j, e] * den
                    forced[:, j] += signal.lfilter(num, den, r[:, e])
            F = _free_response_basis(Csel, cl.A, m)
            basis = np.concatenate(
                [F, np.broadcast_to(np.eye(len(z_index))[None], (m, len(z_index), len(z_index)))],
                axis=2,
            )
            Wb = (basis * w[None, :, None])[burn_in:].reshape(-1, basis.shape[2])
            rhs = ((self.Z[a0:b0] - forced) * w[None, :])[burn_in:].reshape(-1)
            lin, *_ = np.linalg.lstsq(Wb, rhs, rcond=None)
            out.append(forced + basis @ lin)
        return out

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        sims = self.simulate(theta)
        segs, burn_in, nz = self.segs, self.burn_in, len(self.ch.z_index)
        if sims is None:
            return np.full(sum(b - a - burn_in for a, b in segs) * nz, 1e3)
        res = [((self.Z[a:b] - s) * self.w[None, :])[burn_in:].reshape(-1)
               for (a, b), s in zip(segs, sims)]  # fmt: skip
        return np.concatenate(res)


@declared(*OPTIONS_INDIRECT)
def fit_indirect(
    data: ClosedLoopData,
    *,
    controller: Any = None,
    controller_inputs: Sequence[str] | None = None,
    plant_input: str = "u:0",
    plant_outputs: Sequence[str] | None = None,
    fit_channels: Sequence[str] | None = None,
    intermediate: str | None = None,
    n: int = 3,
    nk: int = 1,
    segments: Sequence[Sequence[int]] | None = None,
    burn_in: int = 0,
    initial: Sequence[float] | None = None,
    max_nfev: int | None = None,
) -> IdentificationResult:
    """Indirect closed-loop identification with a known linear controller.

    The options are declared in :data:`OPTIONS_INDIRECT`. Details:
    ``controller`` (see :func:`resolve_controller`) with ``controller_inputs``
    such as ``["r:0", "y:0", "y:1"]``: inputs that are plant outputs close the
    loop, the others drive it. ``fit_channels`` (default the plant outputs) may
    include ``plant_input``; each is weighted by ``1/std`` over the segments.
    ``intermediate`` is a plant output that is itself the input of the rest of
    the plant (the coil current of a voltage-driven levitator): the largest real
    zero of its numerator is reported as ``intermediate_pole_*`` (for the UAQ
    rig: the mechanical pole ``sqrt(2 g/(a + y0))``). A new segment after each
    saturation keeps the controller linear; its initial state is estimated.
    ``initial``: a discrete model of order ``n`` with ``ny`` outputs (e.g.
    :func:`maglevid.physics.levitator.linearize`) or ``theta = [a1..an, b(out
    1), ...]``; default a direct SIMO ARX estimate; it must give a stable
    closed loop with the controller.

    The steps: the loop's channels (:func:`_loop_channels`), the closed-loop
    output error of the module notes (:class:`_ClosedLoopOutputError`), its
    start (:func:`_starting_theta`), the least-squares fit, the parameters with
    their covariance (:func:`_indirect_parameters`) and the closed-loop fits.

    Returns
    -------
    IdentificationResult
        ``parameters``: ``a1..an``, ``b{j}_{k}`` and ``pole_z``, ``pole_rad_s`` (and
        ``intermediate_pole_*``); asymptotic covariance from the Jacobian of the
        weighted output errors (white-error assumption: optimistic when the errors
        are coloured, see notes).
    """
    K, cin = resolve_controller(data, controller, controller_inputs)
    ch = _loop_channels(data, cin, plant_input, plant_outputs, fit_channels, intermediate)
    segs = resolve_segments(data, segments, min_length=max(3 * (n + K.nx), burn_in + 10))
    Z = np.column_stack([f.values for f in ch.fits])
    w = 1.0 / np.array([max(np.std(np.concatenate([Z[a:b, j] for a, b in segs])), 1e-300)
                        for j in range(Z.shape[1])])  # fmt: skip
    cost = _ClosedLoopOutputError(K, ch, segs, Z, w, n, nk, data.dt, burn_in)
    notes: list[str] = [
        f"plant {ch.plant_input.name} -> {[p.name for p in ch.outputs]}; controller known "
        f"({'preset ' + controller if isinstance(controller, str) else 'given'})",
        "closed-loop output error: the predictor is the (stable) closed loop",
    ]
    options: dict[str, Any] = {
        "controller": controller if isinstance(controller, str) else "StateSpace",
        "controller_inputs": list(cin), "plant_input": plant_input,
        "plant_outputs": ch.specs, "fit_channels": [f.spec for f in ch.fits],
        "intermediate": ch.intermediate, "n": n, "nk": nk,
        "segments": [list(s) for s in segs], "burn_in": burn_in,
    }  # fmt: skip
    theta0 = _starting_theta(data, cost, initial, notes)
    sol = optimize.least_squares(
        cost.residuals, theta0, method="trf", x_scale="jac", max_nfev=max_nfev
    )
    if not sol.success:
        notes.append(f"optimiser stopped: {sol.message}")
    theta = sol.x
    params, ext = _indirect_parameters(cost, sol, data.dt, notes)
    sims = cost.simulate(theta)
    zhat = np.full(Z.shape, np.nan)
    for (a, b), s in zip(segs, sims or []):
        zhat[a + burn_in : b] = s[burn_in:]
    fit = {
        f"closed_loop_fit_percent_{f.name}": fit_percent(Z[:, j], zhat[:, j], segs)
        for j, f in enumerate(ch.fits)
    }
    fit["weighted_rms"] = float(np.sqrt(np.mean(sol.fun**2)))
    model = cost.plant(theta)
    model = StateSpace(model.A, model.B, model.C, model.D, data.dt, (),
                       (ch.plant_input.name,), tuple(p.name for p in ch.outputs))  # fmt: skip
    cont = continuous_or_note(model, notes)
    resid = Z - zhat  # NaN where there is no prediction (burn-in, outside the segments)
    return IdentificationResult(
        method="indirect",
        model=model,
        parameters=params,
        covariance=ext,
        n_samples=int(sum(b - a for a, b in segs)),
        options=options,
        residuals=resid,
        fit=fit,
        notes=tuple(notes),
        continuous_model=cont,
        extras={"closed_loop_prediction": zhat, "weights": w.tolist()},
    )


def _starting_theta(
    data: ClosedLoopData, cost: _ClosedLoopOutputError, initial: Any, notes: list[str]
) -> np.ndarray:
    """The start of the fit: ``initial`` or a direct SIMO ARX estimate; it must give a
    stable closed loop with the known controller."""
    n, nk, ny = cost.n, cost.nk, len(cost.ch.outputs)
    if initial is None:
        theta0 = _simo_arx_start(data, cost.ch.plant_input.spec, cost.ch.specs, n, nk, cost.segs)
        notes.append("start: direct SIMO ARX estimate")
    elif isinstance(initial, StateSpace):
        theta0 = _theta_from_state_space(initial, n, nk, ny)
        notes.append("start: the given initial plant model")
    else:
        theta0 = np.asarray(initial, dtype=float)
        if theta0.shape != (n + ny * n,):
            raise DataError(f"`initial` must have {n + ny * n} values; got {theta0.shape}")
    if cost.simulate(theta0) is None:
        raise IdentificationError(
            "the starting plant does not give a stable closed loop with the known controller; "
            "give `initial` (e.g. from physics) or check the controller"
        )
    return theta0


def _indirect_parameters(
    cost: _ClosedLoopOutputError, sol: Any, dt: float, notes: list[str]
) -> tuple[dict[str, float], np.ndarray]:
    """``a1..an``, ``b{out}_{k}``, the pole (and the intermediate pole) with the
    covariance from the Jacobian of the weighted output errors, by the delta method."""
    n, nk, theta = cost.n, cost.nk, sol.x
    cov = covariance_from_jacobian(sol.jac, sol.fun, theta.size)
    notes.append(
        "covariance assumes white output errors; closed-loop output errors are coloured, "
        "so the intervals are optimistic (compare segments)"
    )
    names = [f"a{j}" for j in range(1, n + 1)] + [
        f"b{p.name}_{k}" for p in cost.ch.outputs for k in range(nk, nk + n)
    ]
    pv, Jp, pn = pole_statistics(lambda t: np.r_[1.0, t[:n]], theta, dt)
    notes.extend(pn)
    params = dict(zip(names, theta.tolist()))
    params.update(pv)
    jacs = [Jp]
    if cost.ch.intermediate is not None:
        j = cost.ch.specs.index(cost.ch.intermediate)
        sl = slice(n + j * n, n + (j + 1) * n)

        def bpoly(t: np.ndarray) -> np.ndarray:
            b = t[sl]
            return b / b[0]

        iv, Ji, inotes = pole_statistics(bpoly, theta, dt, prefix="intermediate_")
        notes.extend(inotes)
        params.update(iv)
        jacs.append(Ji)
    return params, extend_covariance(cov, jacs)


def _free_response_basis(C: np.ndarray, A: np.ndarray, m: int, block: int = 64) -> np.ndarray:
    """``C A^k`` for ``k = 0..m-1``, shape ``(m, rows of C, nx)``: one block of ``block``
    powers by recursion, then whole blocks by one batched product with ``A^block``."""
    nz, nx = C.shape
    head = np.empty((min(block, m), nz, nx))
    M = C.copy()
    for k in range(head.shape[0]):
        head[k] = M
        M = M @ A
    if m <= block:
        return head
    out = np.empty((m, nz, nx))
    Ab = np.linalg.matrix_power(A, block)
    P = np.eye(nx)
    for start in range(0, m, block):
        stop = min(m, start + block)
        out[start:stop] = head[: stop - start] @ P
        P = P @ Ab
    return out


def _theta_from_state_space(P: StateSpace, n: int, nk: int, ny: int) -> np.ndarray:
    """``[a, b_1, ..., b_ny]`` of a discrete SIMO model (``C adj(zI-A) b`` through
    ``det(zI - A + b c_j) - det(zI - A)``)."""
    if not P.is_discrete or P.nx != n or P.nu != 1 or P.ny != ny:
        raise DataError(
            f"`initial` must be a discrete model with {n} states, 1 input and {ny} outputs; "
            f"got {P!r}"
        )
    den = np.poly(P.A)
    out = [den[1:]]
    for j in range(ny):
        num = np.poly(P.A - P.B @ P.C[j : j + 1]) - den + P.D[j, 0] * den
        if np.any(np.abs(num[:nk]) > 1e-12 * max(1.0, np.max(np.abs(num)))):
            raise DataError(f"`initial` has a direct term; nk = {nk} needs none")
        out.append(np.r_[num[nk:], np.zeros(nk - 1)][:n])
    return np.concatenate(out)


def _simo_arx_start(
    data: ClosedLoopData,
    u: str,
    outputs: list[str],
    n: int,
    nk: int,
    segs: list[tuple[int, int]],
) -> np.ndarray:
    """Starting values: ARX of the first output gives ``A``; each numerator by least
    squares of ``A y_j = B_j u`` with that ``A``."""
    first = fit_pem(data, output=outputs[0], input=u, na=n, nb=n, nk=nk, segments=segs)
    a = np.array(first.extras["A"])
    uu = resolve_channel(data, u).values
    theta = [a[1:]]
    for spec in outputs:
        y = resolve_channel(data, spec).values
        rows, tg = [], []
        for a0, b0 in segs:
            t = np.arange(a0 + n + nk, b0)
            lhs = sum(a[j] * y[t - j] for j in range(n + 1))
            cols = [uu[t - nk - j] for j in range(n)]
            rows.append(np.column_stack([*cols, np.ones(t.size)]))
            tg.append(lhs)
        b, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(tg), rcond=None)
        theta.append(b[:n])
    return np.concatenate(theta)


METHODS = {"indirect": fit_indirect}
