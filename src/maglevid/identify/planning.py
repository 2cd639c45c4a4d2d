"""Experiment planning from the Cramér-Rao bound: how long, and how hard to excite.

The information about the parameters grows linearly with the record length N
and, because the loop is linear, splits into a part driven by the excitation
and a part driven by the noise (:mod:`maglevid.identify.cramer_rao`)::

    I(N, alpha) = N (alpha^2 I_r + I_e),      alpha = excitation std / reference std

``I_r`` and ``I_e`` per sample come from two simulations of the loop (the
excitation alone at the reference level; the noise alone). The sensor noise
levels are nuisance parameters (the ``ml`` method estimates them), eliminated
by the Schur complement. A parameter is *resolved* when the half-width of its
95 % interval is at most ``fraction x tolerance x |value|`` (``tolerance`` the
diagnosis's relative engineering tolerance, 5 % by default), i.e. when its
bound is below ``target = fraction tolerance |value| / 1.96``.

For each parameter the plan gives the record length needed at the present
excitation, the length needed at the largest allowed excitation, and the
excitation needed at the present length. The allowed excitation is the
smaller of the amplifier limit (``max_excitation_std``, V rms per input) and
the level that keeps the rotor's rms displacement within
``max_displacement`` of the air gap (the linearised model's range).

Noise model: sensor noise on x, i1, i2, a force disturbance on the rotor
(held over each sample, ``b_F = [0, 1/m, 0, 0]``) and amplifier noise added
after the logged ``u`` -- the ``ml`` predictor's model
(:func:`~maglevid.identify.cramer_rao.amb_linear_gaussian_model`); by default
the simulator's realistic bearing (its sensor noise and 0.1 N). The two
simulations are of the default loop around the linearised bearing
(:func:`_loop_record`: the loop of
:func:`~maglevid.simulate.loop.closed_loop_system` with the force and the
amplifier noise as two more inputs the controller never sees), so the split
``alpha^2 I_r + I_e`` is exact. The force costs information on the coil
parameters (R1, kw1: ~1.8x the std with sensor noise alone on the default
bearing) and adds some on the rotor's (it excites it).

Spectrum: the present excitation is white (a design) or the recording's own
``r`` (its waveform scaled to unit rms: ``spectrum = "recorded"``). The plan
also evaluates candidate spectra of the same rms (:data:`DEFAULT_SPECTRA`:
white noise through a second-order Butterworth low-pass at 20 Hz - 1 kHz) and
names, per parameter and for all together, the one that needs the shortest
record at its own largest allowed excitation (a low-frequency excitation moves
the rotor more per volt, so the displacement limit binds earlier). On the
nominal bearing a 100 Hz low-pass excitation gives 3-5x smaller bounds than
white noise at the same rms.

The loop is the default design on the nominal bearing
(:func:`~maglevid.simulate.amb.default_amb_controller` and ``_observer``),
which is how the simulated recordings are made; for a recording with another
controller the plan is that of the default loop around the estimated bearing.
The bound is asymptotic: a planned record of a few hundred samples is at the
edge of its validity.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.cramer_rao import (
    CramerRaoBound,
    NoiseModel,
    amb_linear_gaussian_model,
    bound_from_fisher,
    derived_parameters,
    eliminate_nuisance,
    evaluation_point,
    plant_from_v,
    predictor_statistics,
)
from maglevid.identify.result import central_jacobian, propagate_covariance
from maglevid.identify.uncertainty import operating_point
from maglevid.physics.amb import AMBParameters

__all__ = [
    "DEFAULT_FRACTION",
    "DEFAULT_MAX_DISPLACEMENT",
    "DEFAULT_MAX_EXCITATION_STD",
    "DEFAULT_SPECTRA",
    "DEFAULT_SPLITS",
    "MODEL_ERROR_GAIN",
    "MODEL_ERROR_RATIO",
    "DesignInformation",
    "ExperimentPlan",
    "PlanRow",
    "SpectrumPart",
    "amplifier_limits",
    "describe_excitation",
    "design_for_recording",
    "design_information",
    "excitation_signal",
    "format_seconds",
    "input_levels",
    "limit_share",
    "model_error_bias",
    "model_error_level",
    "model_error_of_excursion",
    "noise_of_result",
    "plan_experiment",
    "plan_for_recording",
    "plan_from_result",
    "smallest_satisfying",
    "spectrum_label",
    "v_of_result",
]

#: Fraction of the tolerance the 95 % half-width must reach.
DEFAULT_FRACTION = 0.5

#: Amplifier limit assumed when none is given [V rms per input]: a quarter of
#: a 24 V supply after the nominal bias voltage (17.5 ohm x 0.5 A = 8.75 V).
DEFAULT_MAX_EXCITATION_STD = 4.0

#: Largest rms rotor displacement allowed, as a fraction of the air gap: at
#: 2 % the nonlinear force law departs from the linearisation by ~0.1 %
#: (the error is second order in the amplitude).
DEFAULT_MAX_DISPLACEMENT = 0.02

#: Parameters planned by default: the ones a diagnosis names.
DEFAULT_PARAMETERS = ("R1", "R2", "kw1", "kw2", "L1", "L2", "ki1", "ki2", "x0")

_Z95 = 1.959963984540054

#: The linearisation's model error: ML's estimand on the nonlinear bearing is
#: the best linear model at the excitation, whose v_i differ from the settled
#: point's tangent linearisation by at most ``MODEL_ERROR_GAIN x e^2`` of
#: their value, ``e`` the loop's largest relative excursion
#: (:meth:`DesignInformation.excursion`). Second order because the force law
#: and flux of eq. (1) have no first-order term beyond the linearisation, and
#: with a zero-mean Gaussian excitation the quadratic terms add nothing to the
#: best linear gain (their odd moments vanish): the first term is cubic, ~e^2.
#: The gain is measured (benchmarks/measure_model_error.py, docs/gosiewski.md
#: "Model error of the linearisation"): ML's v_i on nonlinear records with
#: 1e-3 of the sensor noise and no force, N = 1e5, started at the settled
#: point; mean over 8 records of the healthy bearing at 1 V and 2 V (e = 0.41 %
#: and 0.81 %): 0.9-1.9 x e^2 for the v_i that move (v1, v2, v4, v6; the
#: 2 V / 1 V ratio 3.3-4.2, i.e. ~a^2); kw1 -20 % alike (8 records: 0.7-1.9
#: x e^2), single records of R1 +20 % too (<= 2.3 x e^2, a record's own
#: scatter ~1.4 x e^2 at 1e5).
MODEL_ERROR_GAIN = 2.0

#: Largest model-error bias the planner accepts, as a fraction of the
#: standard error of the record it plans (the Monte Carlo's target is
#: |bias| < 0.2 std; half of it leaves room for the law's own uncertainty).
MODEL_ERROR_RATIO = 0.1


#: Candidate excitation spectra the plan compares (module notes): white, and
#: white noise through a second-order Butterworth low-pass at these corners [Hz]
#: (corners at or above 0.8 x Nyquist are left out).
DEFAULT_SPECTRA = (
    "white",
    "lowpass:20",
    "lowpass:50",
    "lowpass:100",
    "lowpass:300",
    "lowpass:1000",
)


#: Causes the diagnosis fits to v1..v9 that are no free parameter of the bound (the mass
#: scales every coil and amplifier parameter; sensor gains and the bias current rescale
#: the measured states): `maglevid plan --parameters m` said only "unknown parameters"
#: while the diagnosis labelled its advice on m "Cramér-Rao plan" (found from outside,
#: seventeenth session).
_CAUSES_NOT_BOUND = ("m", "i0", "gx", "gi1", "gi2")


def _check_names(parameters: Sequence[str], names: Sequence[str]) -> None:
    unknown = [p for p in parameters if p not in names]
    if not unknown:
        return
    causes = [p for p in unknown if p in _CAUSES_NOT_BOUND]
    why = (
        f"; {', '.join(causes)} {'is' if len(causes) == 1 else 'are'} not a free parameter of "
        "the bound but a cause the diagnosis fits to v1..v9 (held at the baseline's here): "
        "`maglevid diagnose REC` plans it in its advice ('to resolve the tolerance'), from "
        "the same bound of v1..v9"
        if causes
        else ""
    )
    raise DataError(f"unknown parameters {unknown}; expected names among {list(names)}{why}")


def spectrum_label(spectrum: str) -> str:
    """Words for a spectrum name: ``"lowpass:100"`` -> ``"low-pass 100 Hz"``."""
    if spectrum.startswith("lowpass:"):
        return f"low-pass {float(spectrum.split(':', 1)[1]):g} Hz"
    return {"white": "white", "recorded": "as recorded"}.get(spectrum, spectrum)


def excitation_signal(spectrum: str, n_samples: int, dt: float, rng: Any) -> np.ndarray:
    """Unit-rms excitation on both inputs, shape ``(n_samples, 2)``, of a named spectrum.

    ``"white"``: white Gaussian (the simulator's). ``"lowpass:F"``: white Gaussian
    through a second-order Butterworth low-pass with corner ``F`` Hz, scaled
    back to unit rms (the same amplifier rms, its power moved below ``F``).
    """
    from scipy import signal

    gen = np.random.default_rng(rng)
    w = gen.standard_normal((int(n_samples), 2))
    if spectrum == "white":
        return w
    if not spectrum.startswith("lowpass:"):
        raise DataError(f"unknown excitation spectrum {spectrum!r}; use 'white' or 'lowpass:F'")
    try:
        fc = float(spectrum.split(":", 1)[1])
    except ValueError:
        raise DataError(f"`{spectrum}`: the corner must be a number of Hz") from None
    nyquist = 0.5 / dt
    if not 0 < fc < nyquist:
        raise DataError(f"`{spectrum}`: the corner must be in (0, {nyquist:g}) Hz (Nyquist)")
    sos = signal.butter(2, fc, fs=1.0 / dt, output="sos")
    r = signal.sosfilt(sos, w, axis=0)
    return r / np.std(r, axis=0)


#: Candidate splits of the excitation between the two inputs: the share of its
#: power on input 1 (0.5 = the same level on both, 1 = coil 1's amplifier alone).
DEFAULT_SPLITS = (0.0, 0.25, 0.5, 0.75, 1.0)


def input_levels(excitation_std: float, share: float = 0.5) -> tuple[float, float]:
    """The rms levels ``(a1, a2)`` [V] of a level and split (module notes).

    ``excitation_std`` is the power mean ``sqrt((a1^2 + a2^2) / 2)``: ``share``
    0.5 puts it on both inputs, 1 puts ``sqrt(2) x excitation_std`` on input 1
    alone (the same total power).
    """
    if not 0.0 <= share <= 1.0:
        raise DataError(f"`share` must be in [0, 1]; got {share!r}")
    return excitation_std * math.sqrt(2 * share), excitation_std * math.sqrt(2 * (1 - share))


def amplifier_limits(max_excitation_std: float | Sequence[float]) -> tuple[float, float]:
    """The amplifier limits ``(A1, A2)`` [V rms] of the two inputs (one value: both)."""
    try:
        lim = np.asarray(max_excitation_std, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        lim = np.zeros(0)
    lim = np.repeat(lim, 2) if lim.size == 1 else lim
    if lim.size != 2 or not np.all(np.isfinite(lim) & (lim > 0)):
        raise DataError(
            f"`max_excitation_std` must be one positive value or one per input; "
            f"got {max_excitation_std!r}"
        )
    return float(lim[0]), float(lim[1])


def limit_share(max_excitation_std: float | Sequence[float]) -> float:
    """The split that drives each input at its own amplifier limit."""
    a1, a2 = amplifier_limits(max_excitation_std)
    return a1 * a1 / (a1 * a1 + a2 * a2)


def describe_excitation(excitation_std: float, share: float = 0.5) -> str:
    """Words for a level and split: "excite coil 1 only at 1.6 V rms", ..."""
    a1, a2 = input_levels(excitation_std, share)
    if share == 0.5:
        return f"excite both coils at {a1:.3g} V rms"
    if a2 == 0 or a1 == 0:
        return f"excite coil {1 if a2 == 0 else 2} only at {max(a1, a2):.3g} V rms"
    return f"excite coil 1 at {a1:.3g} V rms and coil 2 at {a2:.3g} V rms"


def smallest_satisfying(
    ok: Callable[[float], bool], lo: float, hi: float, *, xtol: float
) -> float | None:
    """Smallest ``x`` in ``[lo, hi]`` where a monotone condition holds (bisection).

    ``ok`` is false below some ``x*`` and true above it (a variance that falls
    with the record length or the excitation). Returns ``lo`` when ``ok(lo)``,
    ``None`` when not ``ok(hi)``, else ``x*`` to within ``xtol`` (from above).
    """
    if not ok(hi):
        return None
    if ok(lo):
        return lo
    while hi - lo > xtol:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if ok(mid) else (mid, hi)
    return hi


@dataclass(frozen=True)
class SpectrumPart:
    """Per-sample information and loop excursions of one excitation spectrum, per input.

    Independent excitations on the two inputs add their information (the
    cross terms of eq. (2) average to zero), so input ``k`` alone at unit rms
    gives ``info[k]`` and any split is ``a1^2 info[0] + a2^2 info[1]``.
    """

    info: np.ndarray  # (2, p, p): input k alone at unit rms (no S term)
    x_rms: np.ndarray  # (2,): rms displacement per unit rms on input k [m]
    i_rms: np.ndarray  # (2, 2): rms current of coil c per unit rms on input k [A]


@dataclass(frozen=True)
class DesignInformation:
    """Per-sample information of a loop, split into excitation and noise parts.

    ``parts`` holds a :class:`SpectrumPart` for the present excitation spectrum
    (``spectrum``) and every candidate the plan may propose instead (module
    notes). Every method takes the level ``excitation_std`` [V rms, power
    mean over the two inputs] and its ``share`` on input 1
    (:func:`input_levels`; 0.5 = both alike, the present excitation).
    """

    v: np.ndarray
    dt: float
    noise: NoiseModel
    info_e: np.ndarray  # per sample, noise part (with the S term of eq. (2))
    x_rms_e: float  # rms displacement from the noise-driven loop [m]
    i_rms_e: np.ndarray  # (2,) rms coil currents from the noise-driven loop [A]
    m: float | None
    i0: float | None
    gap: float
    spectrum: str
    parts: Mapping[str, SpectrumPart]

    @property
    def spectra(self) -> tuple[str, ...]:
        """The candidate spectra other than the present one."""
        return tuple(sp for sp in self.parts if sp != self.spectrum)

    def _part(self, spectrum: str | None) -> SpectrumPart:
        try:
            return self.parts[self.spectrum if spectrum is None else spectrum]
        except KeyError:
            raise DataError(
                f"spectrum {spectrum!r} was not computed; known: {list(self.parts)}"
            ) from None

    def bound(
        self,
        *,
        n_samples: int,
        excitation_std: float,
        spectrum: str | None = None,
        share: float = 0.5,
    ) -> CramerRaoBound:
        """The bound for ``n_samples`` at ``excitation_std`` [V rms] split by ``share``."""
        return bound_from_fisher(
            self.v_information(
                n_samples=n_samples, excitation_std=excitation_std, spectrum=spectrum, share=share
            ),
            self.v,
            n_samples=n_samples,
            noise=self.noise,
            m=self.m,
            i0=self.i0,
        )

    def v_information(
        self,
        *,
        n_samples: float,
        excitation_std: float,
        spectrum: str | None = None,
        share: float = 0.5,
    ) -> np.ndarray:
        """Fisher information of v1..v9 (nuisance parameters eliminated), 9 x 9."""
        p = self._part(spectrum)
        a1, a2 = input_levels(excitation_std, share)
        info = a1 * a1 * p.info[0] + a2 * a2 * p.info[1] + self.info_e
        return eliminate_nuisance(n_samples * info, 9)

    def displacement_rms(
        self, excitation_std: float, spectrum: str | None = None, share: float = 0.5
    ) -> float:
        a = np.array(input_levels(excitation_std, share))
        x = self._part(spectrum).x_rms
        return math.sqrt(float(np.sum((a * x) ** 2)) + self.x_rms_e**2)

    def excursion(
        self, excitation_std: float, spectrum: str | None = None, share: float = 0.5
    ) -> float:
        """Largest relative excursion ``max(std x / x0, std i_c / i0)`` of the loop.

        What sets the linearisation's model error (the diagnosis's
        :func:`~maglevid.diagnose.pipeline.estimate_model_error`).
        """
        a = np.array(input_levels(excitation_std, share))
        x = self.displacement_rms(excitation_std, spectrum, share) / self.gap
        if not self.i0:
            return x
        i = np.sqrt((a**2) @ self._part(spectrum).i_rms ** 2 + self.i_rms_e**2) / self.i0
        return max(x, float(np.max(i)))

    def max_excitation(
        self,
        max_excitation_std: float | Sequence[float],
        max_displacement: float,
        spectrum: str | None = None,
        share: float = 0.5,
    ) -> float:
        """The largest level [V rms] within the amplifier and displacement limits.

        The amplifier limit is per input (``a_k`` at most ``max_excitation_std``,
        one value for both or one per input); the displacement limit is shared:
        the two inputs' contributions to the rms displacement add in power.
        """
        a1, a2 = input_levels(1.0, share)
        A1, A2 = amplifier_limits(max_excitation_std)
        a_amp = min(A1 / a1 if a1 > 0 else math.inf, A2 / a2 if a2 > 0 else math.inf)
        x = self._part(spectrum).x_rms
        per_level = math.hypot(a1 * x[0], a2 * x[1])  # rms displacement per V rms
        x_lim = max_displacement * self.gap
        head = math.sqrt(max(x_lim**2 - self.x_rms_e**2, 0.0))
        return min(a_amp, head / per_level if per_level > 0 else math.inf)


def _derived_jacobian(design: DesignInformation) -> np.ndarray:
    """d(v1..v9, physical parameters) / d(v1..v9) at the design's v (central differences)."""
    _, J = central_jacobian(
        lambda vv: derived_parameters(vv, m=design.m, i0=design.i0)[1], np.asarray(design.v, float)
    )
    return np.vstack([np.eye(9), J])  # v itself: exactly


def model_error_bias(
    design: DesignInformation,
    excitation_std: float,
    *,
    spectrum: str | None = None,
    share: float = 0.5,
) -> np.ndarray:
    """Predicted model-error bias of every parameter of the bound at an excitation.

    The linearisation's model error (:data:`MODEL_ERROR_GAIN`): each v_i is
    biased by at most ``MODEL_ERROR_GAIN x e^2 x |v_i|``, ``e`` the largest
    relative excursion of the loop at this excitation
    (:meth:`DesignInformation.excursion`: the excitation's and the noise's
    together); the physical parameters take the worst case of their
    v_i's, ``|J| |b_v|`` (signs not assumed).

    Parameters
    ----------
    design : DesignInformation
    excitation_std : float
        Level [V rms, power mean over the two inputs].
    spectrum, share
        As :meth:`DesignInformation.bound`.

    Returns
    -------
    ndarray
        Bias magnitudes in the order of ``design.bound(...).names`` (v1..v9,
        then the physical parameters), in their units.

    Examples
    --------
    >>> d = design_information(n_simulate=2000, spectra=())
    >>> b = model_error_bias(d, 1.0)
    >>> bool(0 < b[0] / d.v[0] < 1e-3)
    True
    """
    e = design.excursion(excitation_std, spectrum, share)
    b_v = model_error_of_excursion(e) * np.abs(np.asarray(design.v, float))
    return np.abs(_derived_jacobian(design)) @ b_v


def model_error_of_excursion(excursion: float) -> float:
    """The linearisation's relative model-error bias of each v_i: ``MODEL_ERROR_GAIN e^2``.

    ``e`` is the loop's largest relative excursion (``max(std x / x0, std i_c / i0)``,
    :meth:`DesignInformation.excursion` for a design, the recording's own for a
    diagnosis). The one place the measured law is written (:data:`MODEL_ERROR_GAIN`);
    the planner and the diagnosis's advice both read it here.

    Examples
    --------
    >>> model_error_of_excursion(0.004)  # 1 V on the default bearing: 3.2e-5 of v_i
    3.2e-05
    """
    if not (math.isfinite(excursion) and excursion >= 0):
        raise DataError(f"`excursion` must be finite and >= 0; got {excursion!r}")
    return MODEL_ERROR_GAIN * excursion * excursion


def model_error_level(
    design: DesignInformation,
    *,
    n_samples: int,
    parameters: Sequence[str] = DEFAULT_PARAMETERS,
    ratio: float = MODEL_ERROR_RATIO,
    max_excitation_std: float | Sequence[float] = DEFAULT_MAX_EXCITATION_STD,
    max_displacement: float = DEFAULT_MAX_DISPLACEMENT,
    spectrum: str | None = None,
    share: float = 0.5,
) -> float:
    """The largest level [V rms] whose model-error bias is at most ``ratio`` standard errors.

    For a record of ``n_samples``: the bias grows with the level (~ a^2,
    :func:`model_error_bias`) and the standard error falls (~ 1/a), so their
    ratio grows ~ a^3 sqrt(N) / sigma and a longer record must be taken at a
    lower level, ``a ~ N^(-1/6)``. The level is at most the largest one
    within the amplifier and displacement limits
    (:meth:`DesignInformation.max_excitation`); every parameter in
    ``parameters`` must meet the ratio.
    """
    if not ratio > 0 or n_samples < 1:
        raise DataError(f"`ratio` must be > 0 and `n_samples` >= 1; got {ratio!r}, {n_samples!r}")
    a_max = design.max_excitation(max_excitation_std, max_displacement, spectrum, share)
    names = list(design.bound(n_samples=1, excitation_std=1.0).names)
    _check_names(parameters, names)
    index = [names.index(p) for p in parameters]

    def too_biased(a: float) -> bool:
        cov = design.bound(n_samples=n_samples, excitation_std=a, spectrum=spectrum, share=share)
        std = np.sqrt(np.diag(cov.covariance)[index])
        bias = model_error_bias(design, a, spectrum=spectrum, share=share)[index]
        return bool(np.any(bias > ratio * std))

    a = _largest_level(lambda a: not too_biased(a), a_max)
    return 0.0 if a is None else a


def _largest_level(ok: Callable[[float], bool], a_max: float) -> float | None:
    """Largest ``a`` in ``[0, a_max]`` where ``ok`` (true below some level) holds.

    Bisection to 1e-4 of the level, from below (the returned level satisfies
    ``ok``); ``None`` when not even ``ok(0)``.
    """
    if ok(a_max):
        return a_max
    if not ok(0.0):
        return None
    lo, hi = 0.0, a_max
    while hi - lo > 1e-4 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def _loop_record(
    plant: AMBParameters,
    nominal: AMBParameters,
    dt: float,
    *,
    r: np.ndarray,
    noise: NoiseModel | None,
    rng: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``y`` and the logged ``u`` of the default loop around the linear ``plant``.

    The loop of :func:`~maglevid.simulate.loop.closed_loop_system` (inputs
    ``[r; v]``) with two more inputs the controller never sees: the force
    disturbance ``F`` on the rotor (``b_F = [0, 1/m, 0, 0]``, held over each
    sample) and amplifier noise added after the logged ``u``. Each enters the
    plant state through its ZOH input matrix ``B_w``, and the integral state
    ``e'`` through ``-E C_p B_w`` (as ``B_u`` does in that function), never the
    observer. The same noise model as the ``ml`` predictor's
    (:func:`~maglevid.identify.cramer_rao.amb_linear_gaussian_model`).
    """
    from maglevid.exceptions import DesignError
    from maglevid.lti import StateSpace, discretize
    from maglevid.physics.amb import amb_matrices, amb_state_space
    from maglevid.simulate.amb import default_amb_controller, default_amb_observer
    from maglevid.simulate.kernel import simulate_lti
    from maglevid.simulate.loop import closed_loop_system

    controller = default_amb_controller(nominal, dt)
    observer = default_amb_observer(nominal, dt)
    pd = amb_state_space(plant, dt)
    cl = closed_loop_system(pd, observer, controller)
    if float(np.max(np.abs(cl.poles()))) >= 1.0:
        raise DesignError("the default loop does not hold this bearing: nothing to plan")
    n = r.shape[0]
    gen = np.random.default_rng(rng)
    sensor = np.zeros(3) if noise is None else np.asarray(noise.sensor_std)
    force = 0.0 if noise is None else noise.force_std
    amp = np.zeros(2) if noise is None else np.asarray(noise.amplifier_std)
    v = gen.standard_normal((n, 3)) * sensor
    Ac, _ = amb_matrices(plant)
    bF = np.zeros((4, 1))
    bF[1, 0] = 1.0 / plant.m
    bFd = discretize(StateSpace(Ac, bF, np.eye(4)), dt).B
    Bw = np.hstack([bFd, pd.B])  # force, amplifier noise on u1, u2
    nxo = cl.A.shape[0] - 4 - controller.E.shape[0]
    Bz = np.vstack([Bw, np.zeros((nxo, 3)), -controller.E @ pd.C @ Bw])
    sys = StateSpace(cl.A, np.hstack([cl.B, Bz]), cl.C, np.hstack([cl.D, np.zeros((5, 3))]), dt)
    w = np.hstack([gen.standard_normal((n, 1)) * force, gen.standard_normal((n, 2)) * amp])
    out, _ = simulate_lti(sys, np.hstack([r, v, w]))
    return out[:, :3], out[:, 3:] + r


def design_information(
    plant: AMBParameters | None = None,
    *,
    nominal: AMBParameters | None = None,
    dt: float = 1e-4,
    noise: NoiseModel | None = None,
    n_simulate: int = 20_000,
    rng: int = 0,
    excitation: np.ndarray | None = None,
    spectra: Sequence[str] = DEFAULT_SPECTRA,
) -> DesignInformation:
    """:class:`DesignInformation` of the default loop around ``plant`` (module notes).

    Parameters
    ----------
    plant : AMBParameters, optional
        The bearing (default: the nominal one).
    nominal : AMBParameters, optional
        The bearing the controller and observer are designed on (default ``plant``).
    dt : float
        Control period [s].
    noise : NoiseModel, optional
        Sensor noise, force disturbance and amplifier noise. Default: the
        simulator's realistic default (its sensor noise and a 0.1 N force).
    n_simulate : int
        Samples of each simulation (the expectation of eq. (2) is their
        average; its relative sampling error is ~1 % at 2e4).
    rng : int
        Seed of the simulations.
    excitation : ndarray, shape (n, 2), optional
        The present excitation's waveform (e.g. a recording's ``r``); its
        spectrum is kept, its level scaled to unit rms per input. Default:
        white (``spectrum = "white"``).
    spectra : sequence of str
        Candidate spectra to compare (:data:`DEFAULT_SPECTRA`; ``()`` for none).
    """
    from maglevid.simulate.amb import DEFAULT_FORCE_STD, DEFAULT_NOISE_STD

    plant = AMBParameters.nominal() if plant is None else plant
    nominal = plant if nominal is None else nominal
    if noise is None:
        noise = NoiseModel(DEFAULT_NOISE_STD, force_std=DEFAULT_FORCE_STD)
    n = int(n_simulate)
    v = plant.v()
    model = amb_linear_gaussian_model(
        v, dt, noise, m=plant.m, estimate_noise=True, estimate_force=noise.force_std > 0
    )

    def per_sample(r: np.ndarray, with_noise: bool) -> tuple[np.ndarray, float, np.ndarray]:
        y, u = _loop_record(plant, nominal, dt, r=r, noise=noise if with_noise else None, rng=rng)
        st = predictor_statistics(model, y, u, nuisance=False)
        sd = np.std(y, axis=0)
        return st.fisher / r.shape[0], float(sd[0]), sd[1:3]

    zero = predictor_statistics(model, np.zeros((2, 3)), np.zeros((2, 2)), nuisance=False)
    s_term = zero.fisher / 2  # the S term of eq. (2) per sample (the data part is 0)

    def part(r: np.ndarray) -> SpectrumPart:
        # Each input alone (unit rms), the other silent: the information of a
        # split is the sum (SpectrumPart notes).
        runs = [per_sample(r * (np.arange(2) == k), False) for k in range(2)]
        return SpectrumPart(
            info=np.stack([info - s_term for info, _, _ in runs]),
            x_rms=np.array([x for _, x, _ in runs]),
            i_rms=np.stack([i for _, _, i in runs]),
        )

    info_e, x_rms_e, i_rms_e = per_sample(np.zeros((n, 2)), True)
    parts: dict[str, SpectrumPart] = {}
    if excitation is None:
        present = "white"
    else:
        present = "recorded"
        r = np.asarray(excitation, float)
        if r.ndim != 2 or r.shape[1] != 2 or not np.all(np.std(r, axis=0) > 0):
            raise DataError("`excitation` must be (n, 2) with both inputs excited")
        r = r[:n]
        parts[present] = part((r - r.mean(axis=0)) / np.std(r, axis=0))
    for name in dict.fromkeys([present, *spectra]):
        if name == "recorded" or (
            name.startswith("lowpass:") and float(name.split(":", 1)[1]) >= 0.4 / dt
        ):
            continue  # corners at or above 0.8 x Nyquist
        parts[name] = part(excitation_signal(name, n, dt, rng + 1))
    return DesignInformation(
        v=v,
        dt=dt,
        noise=noise,
        info_e=info_e,
        x_rms_e=x_rms_e,
        i_rms_e=i_rms_e,
        m=plant.m,
        i0=plant.i0,
        gap=plant.x0,
        spectrum=present,
        parts=parts,
    )


@dataclass(frozen=True)
class PlanRow:
    """What it takes to resolve one parameter.

    ``std_now`` is the standard deviation of the *difference* a diagnosis
    judges: the record's own bound and the baseline's (``baseline_std``)
    together. ``seconds_*`` are ``inf`` where no record of the present state
    reaches the target (the baseline alone is too uncertain).
    """

    name: str
    value: float
    target_std: float
    std_now: float
    seconds_now: float  # needed at the present excitation
    seconds_at_max: float  # needed at the largest allowed excitation
    excitation_for_length: float | None  # V rms at the present length (None: not reachable)
    best_spectrum: str = "white"  # the candidate spectrum and split with the shortest record
    seconds_best: float = math.inf  # needed with it, at its largest allowed excitation
    excitation_best: float = 0.0  # that excitation [V rms, power mean over the inputs]
    best_share: float = 0.5  # its share of the excitation power on input 1
    baseline_std: float = 0.0  # the baseline's own std [parameter units]
    seconds_rerecord: float = math.inf  # baseline and this state re-recorded: each [s]
    model_error: float = 0.0  # predicted model-error bias at the present excitation
    # The level [V rms] and length [s] that resolve it with the model-error bias
    # at most MODEL_ERROR_RATIO of the target std (None / inf: no level does).
    excitation_with_model_error: float | None = None
    seconds_with_model_error: float = math.inf

    @property
    def resolved(self) -> bool:
        return self.std_now <= self.target_std

    @property
    def baseline_limited(self) -> bool:
        """The baseline alone is uncertain beyond the target: no new record helps."""
        return self.baseline_std >= self.target_std

    def _percent(self, std: float) -> float:
        return 100 * _Z95 * std / abs(self.value) if self.value else math.inf

    def sentence(self, *, excitation_std: float, max_excitation_std: float) -> str:
        """One line for a report: "R1 needs 9 s at this excitation, or 3 s at 2.4 V rms"."""
        if self.resolved:
            return (
                f"{self.name} is resolved (std {self.std_now:.3g}, target {self.target_std:.3g})"
            )
        if self.baseline_limited:
            pct = self._percent(self.baseline_std)
            return (
                f"{self.name}: the baseline itself is uncertain by ±{pct:.2g} %"
                f" (95 %; target ±{self._percent(self.target_std):.2g} %), so no record of the "
                f"present state resolves it; re-record the baseline and this state, "
                f"{format_seconds(self.seconds_rerecord)} each "
                f"({describe_excitation(self.excitation_best, self.best_share)}, "
                f"{spectrum_label(self.best_spectrum)}), or widen the tolerance"
            )
        out = f"{self.name} needs {format_seconds(self.seconds_now)} at this excitation"
        out += f" ({excitation_std:.3g} V rms)"
        if max_excitation_std > excitation_std * 1.01:
            out += f", or {format_seconds(self.seconds_at_max)} at {max_excitation_std:.3g} V rms"
        return out

    def to_dict(self) -> dict[str, Any]:
        a1, a2 = input_levels(self.excitation_best, self.best_share)
        return {
            "name": self.name,
            "value": self.value,
            "target_std": self.target_std,
            "std_now": self.std_now,
            "baseline_std": self.baseline_std,
            "resolved": self.resolved,
            "baseline_limited": self.baseline_limited,
            "seconds_now": _finite(self.seconds_now),
            "seconds_at_max_excitation": _finite(self.seconds_at_max),
            "excitation_for_present_length": self.excitation_for_length,
            "best_spectrum": self.best_spectrum,
            "best_share_input_1": self.best_share,
            "seconds_with_best_spectrum": _finite(self.seconds_best),
            "excitation_with_best_spectrum": self.excitation_best,
            "best_input_levels": [a1, a2],
            "seconds_rerecord_baseline_and_state": _finite(self.seconds_rerecord),
            "model_error_bias": self.model_error,
            "model_error_in_std": self.model_error / self.std_now if self.std_now > 0 else None,
            "excitation_with_model_error": self.excitation_with_model_error,
            "seconds_with_model_error": _finite(self.seconds_with_model_error),
        }


def _finite(x: float) -> float | None:
    """JSON-safe: ``None`` for an infinite time (never reached)."""
    return float(x) if math.isfinite(x) else None


def format_seconds(seconds: float) -> str:
    """A record length in words: "560 ms", "9 s", "12 min", "no finite time"."""
    if not math.isfinite(seconds):
        return "no finite time"
    if seconds < 1:
        return f"{seconds * 1e3:.3g} ms"
    if seconds < 600:
        return f"{seconds:.3g} s"
    return f"{seconds / 60:.3g} min"


@dataclass(frozen=True)
class ExperimentPlan:
    """The plan: one row per parameter and the conditions it assumes."""

    rows: tuple[PlanRow, ...]
    n_samples: int
    dt: float
    excitation_std: float
    max_excitation_std: float
    amplifier_limit: float | tuple[float, float]
    displacement_limit: float
    tolerance: Mapping[str, float]
    fraction: float
    noise: NoiseModel
    spectrum: str = "white"
    best_spectrum: str = "white"  # shortest record for every open parameter together
    seconds_best: float = math.inf
    excitation_best: float = 0.0
    best_share: float = 0.5
    # The largest level whose model-error bias is at most model_error_ratio of
    # the standard error at this length (model_error_level), every parameter.
    excitation_model_error: float | None = None
    model_error_ratio: float = MODEL_ERROR_RATIO

    @property
    def seconds_now(self) -> float:
        """Record length that resolves every planned parameter at this excitation."""
        return max(r.seconds_now for r in self.rows)

    @property
    def seconds_at_max(self) -> float:
        return max(r.seconds_at_max for r in self.rows)

    def sentence(self) -> str:
        """The whole plan in one sentence (what the ``inconclusive`` verdict cites)."""
        return "; ".join(filter(None, [self._resolution_sentence(), self._model_error_sentence()]))

    def _model_error_sentence(self) -> str:
        """The linearisation's model error: a lower level where it is too large."""
        worst = max(self.rows, key=lambda r: r.model_error / r.std_now if r.std_now else 0.0)
        if not worst.std_now or worst.model_error <= self.model_error_ratio * worst.std_now:
            return ""
        out = (
            f"at this excitation the linearisation's model error biases {worst.name} by "
            f"{worst.model_error / worst.std_now:.2g} std"
        )
        if self.excitation_model_error is not None:
            out += (
                f"; excite at most {self.excitation_model_error:.3g} V rms for a record of "
                f"{format_seconds(self.n_samples * self.dt)} (bias <= "
                f"{self.model_error_ratio:g} std)"
            )
        return out

    def _resolution_sentence(self) -> str:
        open_rows = [r for r in self.rows if not r.resolved]
        if not open_rows:
            return "every planned parameter is resolved by this record"
        blocked = [r for r in open_rows if r.baseline_limited]
        rows = [r for r in open_rows if not r.baseline_limited]
        parts = [
            r.sentence(excitation_std=self.excitation_std, max_excitation_std=0.0) for r in blocked
        ]
        if rows:
            worst = max(rows, key=lambda r: r.seconds_now)
            out = (
                f"to resolve {', '.join(r.name for r in rows)} to {self.fraction:g} of the "
                f"tolerance, the record needs {format_seconds(worst.seconds_now)} at this "
                "excitation "
                f"({self.excitation_std:.3g} V rms)"
            )
            at_max = max(r.seconds_at_max for r in rows)
            if self.max_excitation_std > self.excitation_std * 1.01:
                out += f", or {format_seconds(at_max)} at {self.max_excitation_std:.3g} V rms"
            other = (self.best_spectrum, self.best_share) != (self.spectrum, 0.5)
            if other and self.seconds_best < 0.8 * min(worst.seconds_now, at_max):
                out += (
                    f"; a {spectrum_label(self.best_spectrum)} excitation needs "
                    f"{format_seconds(self.seconds_best)} "
                    f"({describe_excitation(self.excitation_best, self.best_share)})"
                )
            parts.append(out)
        return "; ".join(parts)

    def to_dict(self) -> dict[str, Any]:
        return {
            "spectrum": self.spectrum,
            "best_spectrum": self.best_spectrum,
            "best_share_input_1": self.best_share,
            "best_input_levels": list(input_levels(self.excitation_best, self.best_share)),
            "best_excitation": describe_excitation(self.excitation_best, self.best_share),
            "seconds_needed_with_best_spectrum": _finite(self.seconds_best),
            "excitation_with_best_spectrum": self.excitation_best,
            "n_samples": self.n_samples,
            "seconds": self.n_samples * self.dt,
            "dt": self.dt,
            "excitation_std": self.excitation_std,
            "max_excitation_std": self.max_excitation_std,
            "amplifier_limit": self.amplifier_limit,
            "displacement_limit": self.displacement_limit,
            "fraction": self.fraction,
            "tolerance": dict(self.tolerance),
            "noise": self.noise.to_dict(),
            "seconds_needed": _finite(self.seconds_now),
            "seconds_needed_at_max_excitation": _finite(self.seconds_at_max),
            "sentence": self.sentence(),
            "excitation_model_error": self.excitation_model_error,
            "model_error_ratio": self.model_error_ratio,
            "parameters": [r.to_dict() for r in self.rows],
        }


def plan_experiment(
    design: DesignInformation,
    *,
    n_samples: int,
    excitation_std: float,
    parameters: Sequence[str] = DEFAULT_PARAMETERS,
    tolerance: float | Mapping[str, float] = 0.05,
    fraction: float = DEFAULT_FRACTION,
    max_excitation_std: float | Sequence[float] = DEFAULT_MAX_EXCITATION_STD,
    max_displacement: float = DEFAULT_MAX_DISPLACEMENT,
    splits: Sequence[float] = DEFAULT_SPLITS,
    baseline_covariance: Any = None,
    baseline_std: float | Mapping[str, float] | None = None,
    model_error_ratio: float = MODEL_ERROR_RATIO,
) -> ExperimentPlan:
    """Record length, excitation level, spectrum and split that resolve each parameter.

    Parameters
    ----------
    design : DesignInformation
        From :func:`design_information`.
    n_samples : int
        The present (or proposed) record length.
    excitation_std : float
        The present excitation [V rms per input, the same on both].
    parameters : sequence of str
        Names among v1..v9 and the physical parameters.
    tolerance : float or mapping
        Relative engineering tolerance (per parameter, default 5 %).
    fraction : float
        The 95 % half-width must be at most ``fraction x tolerance``.
    max_excitation_std : float or (float, float)
        Amplifier limit [V rms], one for both inputs or one per input.
    max_displacement : float
        Largest rms displacement as a fraction of the air gap.
    splits : sequence of float
        Candidate shares of the excitation power on input 1 (:func:`input_levels`);
        the share that drives each input at its own limit (:func:`limit_share`)
        is always a candidate.
    baseline_covariance : array_like, shape (9, 9), optional
        Covariance of the baseline's v1..v9 when it is itself an estimate (a
        stored history, an earlier fit); propagated to every parameter.
    baseline_std : float or mapping, optional
        The baseline's relative standard deviation per parameter (0.02 = 2 %;
        overrides ``baseline_covariance`` for the parameters it names).
    model_error_ratio : float
        Largest accepted model-error bias of the linearisation
        (:func:`model_error_bias`), in standard errors: the plan names the
        largest level within the limits that keeps it at this record length
        (:func:`model_error_level`) and, per parameter, the level and length
        that resolve it with the bias at most this fraction of the target.

    Returns
    -------
    ExperimentPlan

    Notes
    -----
    A diagnosis compares the record's estimate with the baseline, so the
    variance that decides is ``var1 / N + var_b`` (``var1`` the bound per
    sample): the record needs ``N = var1 / (target^2 - var_b)`` samples, and
    none suffices when ``var_b >= target^2``; then re-recording the baseline
    with the same design (``var1 / N`` each) needs ``N = 2 var1 / target^2``.
    """
    if not (0 < fraction <= 10) or n_samples < 1 or excitation_std < 0:
        raise DataError("`fraction` must be in (0, 10], `n_samples` >= 1, `excitation_std` >= 0")
    amp = amplifier_limits(max_excitation_std)
    if max_displacement <= 0:
        raise DataError("`max_displacement` must be positive")
    if not splits or not all(0.0 <= s <= 1.0 for s in splits):
        raise DataError(f"`splits` must be shares in [0, 1]; got {list(splits)}")
    tol = {p: _per_parameter(tolerance, p, 0.05) for p in parameters}
    # Largest excitation: the amplifier or the displacement limit, whichever is smaller.
    a_max = design.max_excitation(amp, max_displacement)
    now = design.bound(n_samples=1, excitation_std=excitation_std)
    names = list(now.names)
    _check_names(parameters, names)
    index = [names.index(p) for p in parameters]
    var_b = _baseline_variance(design, now, index, parameters, baseline_covariance, baseline_std)
    # Per-sample variances at each spectrum's and split's largest allowed excitation.
    at_max: dict[tuple[str, float], tuple[float, np.ndarray]] = {}
    for sp in design.parts:
        for share in dict.fromkeys([0.5, *splits, limit_share(amp)]):
            a_sp = design.max_excitation(amp, max_displacement, sp, share)
            cov = design.bound(n_samples=1, excitation_std=a_sp, spectrum=sp, share=share)
            at_max[(sp, share)] = (a_sp, np.diag(cov.covariance)[index])
    present = (design.spectrum, 0.5)
    bias_now = model_error_bias(design, excitation_std)[index]
    rows = []
    for j, (p, i) in enumerate(zip(parameters, index, strict=True)):
        value = float(now.values[i])
        t2 = (fraction * tol[p] * abs(value) / _Z95) ** 2
        var1_now = float(now.covariance[i, i])
        best = min(at_max, key=lambda c: at_max[c][1][j])
        rows.append(
            PlanRow(
                name=p,
                value=value,
                target_std=math.sqrt(t2),
                std_now=math.sqrt(var1_now / n_samples + var_b[j]),
                seconds_now=_samples_needed(var1_now, t2, var_b[j]) * design.dt,
                seconds_at_max=_samples_needed(at_max[present][1][j], t2, var_b[j]) * design.dt,
                excitation_for_length=_excitation_for(design, i, n_samples, t2 - var_b[j], a_max),
                best_spectrum=best[0],
                seconds_best=_samples_needed(at_max[best][1][j], t2, var_b[j]) * design.dt,
                excitation_best=at_max[best][0],
                best_share=best[1],
                baseline_std=math.sqrt(var_b[j]),
                seconds_rerecord=_samples_needed(2 * at_max[best][1][j], t2, 0.0) * design.dt,
                model_error=float(bias_now[j]),
                **_with_model_error(design, i, t2, var_b[j], a_max, model_error_ratio),
            )
        )
    # One candidate for every parameter not yet resolved (all of them when all are).
    open_j = [j for j, r in enumerate(rows) if not r.resolved] or list(range(len(rows)))

    def seconds(c: tuple[str, float]) -> float:
        return max(_samples_needed(at_max[c][1][j], rows[j].target_std ** 2, var_b[j])
                   for j in open_j) * design.dt  # fmt: skip

    best_all = min(at_max, key=seconds)
    return ExperimentPlan(
        rows=tuple(rows),
        n_samples=int(n_samples),
        dt=design.dt,
        excitation_std=float(excitation_std),
        max_excitation_std=a_max,
        amplifier_limit=amp[0] if amp[0] == amp[1] else amp,
        displacement_limit=float(max_displacement),
        tolerance=tol,
        fraction=float(fraction),
        noise=design.noise,
        spectrum=design.spectrum,
        best_spectrum=best_all[0],
        seconds_best=seconds(best_all),
        excitation_best=at_max[best_all][0],
        best_share=best_all[1],
        excitation_model_error=model_error_level(
            design,
            n_samples=n_samples,
            parameters=parameters,
            ratio=model_error_ratio,
            max_excitation_std=amp,
            max_displacement=max_displacement,
        ),
        model_error_ratio=float(model_error_ratio),
    )


def _with_model_error(
    design: DesignInformation, i: int, t2: float, var_b: float, a_max: float, ratio: float
) -> dict[str, Any]:
    """The level and length that resolve parameter ``i`` with its model-error bias.

    The bias grows with the level and the record's std falls with the length,
    so the shortest record that resolves the parameter with its bias at most
    ``ratio`` of the target std is at the largest level whose bias is that
    (within ``a_max``), of the length that brings the std to the target.
    None / inf where the bias exceeds it at every level (the noise alone
    moves the loop that far) or the baseline alone is beyond the target.
    """
    limit = ratio * math.sqrt(max(t2 - var_b, 0.0))

    a = _largest_level(lambda a: bool(model_error_bias(design, a)[i] <= limit), a_max)
    if limit <= 0 or a is None:
        return {"excitation_with_model_error": None, "seconds_with_model_error": math.inf}
    var1 = float(design.bound(n_samples=1, excitation_std=a).covariance[i, i])
    seconds = _samples_needed(var1, t2, var_b) * design.dt if a > 0 else math.inf
    return {"excitation_with_model_error": a, "seconds_with_model_error": seconds}


def _per_parameter(value: float | Mapping[str, float], name: str, default: float) -> float:
    return float(value.get(name, default) if isinstance(value, Mapping) else value)


def _samples_needed(var1: float, t2: float, var_b: float) -> float:
    """``N`` with ``var1 / N + var_b = t2`` (inf when ``var_b >= t2``: plan_experiment notes)."""
    return var1 / (t2 - var_b) if t2 > var_b else math.inf


def _baseline_variance(
    design: DesignInformation,
    now: CramerRaoBound,
    index: Sequence[int],
    parameters: Sequence[str],
    baseline_covariance: Any,
    baseline_std: float | Mapping[str, float] | None,
) -> np.ndarray:
    """The baseline's variance of each planned parameter (0 for an exact baseline)."""
    var_b = np.zeros(len(index))
    if baseline_covariance is not None:
        cov = np.asarray(baseline_covariance, dtype=float)
        if cov.shape != (9, 9) or not np.all(np.isfinite(cov)):
            raise DataError(f"`baseline_covariance` must be a finite 9x9 matrix; got {cov.shape}")

        def chain(vv: np.ndarray) -> np.ndarray:
            return np.concatenate([vv, derived_parameters(vv, m=design.m, i0=design.i0)[1]])

        _, full = propagate_covariance(chain, np.asarray(design.v, float), cov)
        var_b = np.clip(np.diag(full)[list(index)], 0.0, None)
    if baseline_std is not None:
        unknown = set(baseline_std) - set(now.names) if isinstance(baseline_std, Mapping) else ()
        if unknown:
            raise DataError(f"`baseline_std` names unknown parameters {sorted(unknown)}")
        for j, (p, i) in enumerate(zip(parameters, index, strict=True)):
            if isinstance(baseline_std, Mapping) and p not in baseline_std:
                continue
            rel = _per_parameter(baseline_std, p, 0.0)
            if not (math.isfinite(rel) and rel >= 0):
                raise DataError(f"`baseline_std` of {p} must be >= 0; got {rel}")
            var_b[j] = (rel * float(now.values[i])) ** 2
    return var_b


def _excitation_for(
    design: DesignInformation, i: int, n_samples: int, var_max: float, a_max: float
) -> float | None:
    """Smallest excitation at which parameter ``i``'s variance is ``var_max`` or less."""

    def ok(a: float) -> bool:
        cov = design.bound(n_samples=n_samples, excitation_std=a).covariance
        return var_max > 0 and float(cov[i, i]) <= var_max

    return smallest_satisfying(ok, 0.0, a_max, xtol=1e-3 * a_max)


def design_for_recording(
    data: ClosedLoopData,
    *,
    v: Any = None,
    noise: NoiseModel | None = None,
    spectra: Sequence[str] = DEFAULT_SPECTRA,
    n_simulate: int = 20_000,
) -> DesignInformation:
    """:func:`design_information` for an existing recording (:func:`plan_for_recording`)."""
    v = evaluation_point(data, v)
    noise = NoiseModel.from_data(data) if noise is None else noise
    if noise is None:
        raise DataError("no noise model: pass `noise` (e.g. the ml fit's sensor_noise_std)")
    m, i0 = operating_point(data.loop)
    if m is None or i0 is None:
        raise DataError("planning needs the mass and bias current (loop['operating_point'])")
    plant = plant_from_v(np.asarray(v, float), m=m, i0=i0)
    nom = data.loop.get("nominal") if isinstance(data.loop, Mapping) else None
    nominal = AMBParameters(**nom) if isinstance(nom, Mapping) else plant
    if data.r is None:
        raise DataError("planning from a recording needs its excitation r")
    return design_information(
        plant,
        nominal=nominal,
        dt=data.dt,
        noise=noise,
        excitation=np.asarray(data.r),
        spectra=spectra,
        n_simulate=n_simulate,
    )


def plan_for_recording(
    data: ClosedLoopData,
    *,
    v: Any = None,
    noise: NoiseModel | None = None,
    **options: Any,
) -> ExperimentPlan:
    """:func:`plan_experiment` for an existing recording.

    The bearing is the one ``v`` describes (an estimate, e.g. the ``ml``
    result's v1..v9; by default the simulated truth), with the mass and bias
    current of ``data.loop["operating_point"]``; the loop is the default
    design on ``data.loop["nominal"]``; the present length and excitation
    are the recording's (``std`` of ``r``, mean over the two inputs; its
    waveform is the present spectrum, ``"recorded"``).
    ``options`` go to :func:`plan_experiment` (``parameters``, ``tolerance``,
    ``fraction``, ``max_excitation_std``, ``max_displacement``).
    """
    design = design_for_recording(data, v=v, noise=noise)
    exc = float(np.mean(np.std(np.asarray(data.r), axis=0)))
    return plan_experiment(design, n_samples=data.n_samples, excitation_std=exc, **options)


def noise_of_result(result: Any) -> NoiseModel | None:
    """The noise model an identification result states: the ``ml`` fit's sensor noise
    and force estimates, else the white-noise covariance of an IV/LS fit (no force);
    ``None`` when it states none."""
    extras = getattr(result, "extras", {}) or {}
    s = extras.get("sensor_noise_std")
    if s is None and extras.get("noise_covariance") is not None:
        s = np.sqrt(np.clip(np.diag(np.asarray(extras["noise_covariance"], float)), 0, None))
    if s is None or not np.all(np.asarray(s, float) > 0):
        return None
    f = extras.get("force_std")  # the ml fit's estimate of the force disturbance
    f = float(f) if isinstance(f, (int, float)) and np.isfinite(f) and f > 0 else 0.0
    return NoiseModel(tuple(np.asarray(s, float).tolist()), force_std=f)  # type: ignore[arg-type]


def v_of_result(result: Any) -> list[float]:
    """v1..v9 of an AMB identification result (``DataError`` without them)."""
    try:
        return [float(result.parameters[f"v{i}"]) for i in range(1, 10)]
    except (KeyError, AttributeError, TypeError):
        raise DataError("planning needs an AMB identification result with v1..v9") from None


def plan_from_result(data: ClosedLoopData, result: Any, **options: Any) -> ExperimentPlan:
    """:func:`plan_for_recording` at an identification result's estimate.

    The bearing is the result's v1..v9, the noise the result's own statement
    (:func:`noise_of_result`), else the recording's metadata.
    ``plan_from_result(data, fit, parameters=("R1",), tolerance=0.05).sentence()``
    gives e.g. "to resolve R1 to 0.5 of the tolerance, the record needs 9 s at
    this excitation (1 V rms), or 560 ms at 4 V rms".

    Raises
    ------
    DataError
        The result has no v1..v9, or no noise level can be found.
    """
    return plan_for_recording(
        data, v=v_of_result(result), noise=noise_of_result(result), **options
    )
