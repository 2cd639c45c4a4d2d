"""Kinds of plant: what a recording is, and which identification method suits it.

A recording is one of a few kinds of plant, and the kind decides the method
(``maglevid identify`` and ``maglevid diagnose`` without ``--method``; a
diagnosis of a two-coil bearing uses ``ml`` instead,
:mod:`maglevid.diagnose.default_method`):

==========================  ===========================================  ==============
kind                        recognised by                                default method
==========================  ===========================================  ==============
``amb-two-coil``            outputs ``[x, i1, i2]``, two coil voltages   ``physical``
                            (Gosiewski & Paszowski), or AMB design
                            parameters in ``loop["nominal"]``
``intersampled-suspension`` outputs sampled ``p > 1`` times per control  ``intersample``
                            period (Sun et al.)
``levitator``               one coil: one input and outputs ``[gap]`` or ``levitator``
                            ``[gap, current]`` (UAQ steel ball, a
                            permanent-magnet levitator)
``mimo``                    anything else (e.g. Maggy: 9 field channels,  ``n4sid``
                            2 inputs)
==========================  ===========================================  ==============

A recording may state its kind (``metadata["plant_kind"]`` or
``loop["plant_kind"]``, the latter first); a stated kind takes precedence over
the inference, and the reason says which it was. The AMB method is never chosen
for a one-input levitator.

Examples
--------
>>> import numpy as np
>>> from maglevid.data import ClosedLoopData
>>> d = ClosedLoopData(y=np.zeros((50, 2)), u=np.zeros((50, 1)), dt=0.01)
>>> infer_kind(d)[0]
'levitator'
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError

__all__ = [
    "KINDS",
    "PlantKind",
    "choose_method",
    "infer_kind",
    "stated_kind",
    "unidentifiable_reason",
]


@dataclass(frozen=True)
class PlantKind:
    """A kind of plant: its name, what it is, and its default identification method."""

    name: str
    description: str
    default_method: str
    method_reason: str


KINDS: dict[str, PlantKind] = {
    k.name: k
    for k in (
        PlantKind(
            "amb-two-coil",
            "two-coil voltage-controlled active magnetic bearing axis (Gosiewski & Paszowski)",
            "physical",
            "identifies the plant u -> y directly and transforms it to physical coordinates: "
            "exact whatever the controller and observer, and consistent under measurement "
            "noise through instruments made from the known excitation r",
        ),
        PlantKind(
            "intersampled-suspension",
            "suspension with outputs inter-sampled p times per control period (Sun et al.)",
            "intersample",
            "the direct inter-sampling method (Sun et al.) identifies the unstable plant "
            "from u and y alone",
        ),
        PlantKind(
            "levitator",
            "one-coil levitator (steel ball or permanent magnet under an electromagnet)",
            "levitator",
            "the levitator model family (force and inductance laws, flux lag) fitted as "
            "grey boxes on the levitating segments, the model chosen by multi-step "
            "prediction on held-out segments; one consensus pole whose interval covers "
            "the spread between segments and models",
        ),
        PlantKind(
            "mimo",
            "generic multi-input multi-output plant",
            "n4sid",
            "no physical model of this plant in maglevid: a black-box subspace model (N4SID) "
            "of u -> y",
        ),
    )
}


def _mapping(obj: Any) -> Mapping[str, Any]:
    return obj if isinstance(obj, Mapping) else {}


def stated_kind(data: ClosedLoopData) -> str | None:
    """The kind the recording states (``loop["plant_kind"]``, else ``metadata["plant_kind"]``)."""
    for source in (_mapping(data.loop), _mapping(data.metadata)):
        kind = source.get("plant_kind")
        if kind is not None:
            if kind not in KINDS:
                raise DataError(
                    f"the recording states plant_kind {kind!r}; expected one of {', '.join(KINDS)}"
                )
            return str(kind)
    return None


def infer_kind(data: ClosedLoopData) -> tuple[str, str]:
    """The recording's kind and why (one sentence): stated, else inferred from its shape.

    Returns
    -------
    (kind, reason) : (str, str)
        ``kind`` is a key of :data:`KINDS`.
    """
    kind = stated_kind(data)
    if kind is not None:
        return kind, f"the recording states plant_kind = {kind!r}"
    shape = f"{data.ny} output(s), {data.nu} input(s), p = {data.p}"
    if _mapping(data.loop).get("nominal"):
        return "amb-two-coil", f"AMB design parameters in loop['nominal'] ({shape})"
    if data.p > 1:
        return "intersampled-suspension", f"outputs inter-sampled ({shape})"
    if data.nu == 1 and data.ny in (1, 2):
        return "levitator", _levitator_reason(data, shape)
    if data.ny == 3 and data.nu == 2:
        return "amb-two-coil", f"outputs [x, i1, i2] and two coil voltages ({shape})"
    return "mimo", f"no physical model matches {shape}"


def _levitator_reason(data: ClosedLoopData, shape: str) -> str:
    outputs = "[gap, current]" if data.ny == 2 else "[gap]"
    plant = _mapping(_mapping(data.metadata).get("plant"))
    law = plant.get("inductance_model")
    return f"one input and outputs {outputs} ({shape}" + (f"; stated law {law})" if law else ")")


def choose_method(data: ClosedLoopData) -> tuple[str, str]:
    """The default identification method for this recording, and why (kind and method)."""
    kind, why_kind = infer_kind(data)
    k = KINDS[kind]
    method = k.default_method
    reason = k.method_reason
    if kind == "levitator" and data.ny == 1:
        method = "pem"
        reason = "a levitator log without the coil current: direct prediction error u -> gap"
    return method, f"plant kind {kind} ({why_kind}); method {method}: {reason}"


#: A command explained by the outputs to this R^2 is an exact linear feedback law.
EXACT_LAW_R2 = 0.9999


def unidentifiable_reason(data: ClosedLoopData) -> str | None:
    """Why a closed-loop record cannot give the open-loop plant, or ``None``.

    A record without an excitation ``r`` whose every command is an exact linear
    function (difference equation ``na = nb = 2``, ``nk = 0``) of the outputs
    leaves only the noise to drive the loop: the direct method's identifiability
    rests on the noise model alone, and a linear model ``u -> y`` fitted to it may
    equally be the inverse of the controller (Ljung 1999, sec. 13.4; Söderström &
    Stoica 1989, sec. 10.3). Saturated samples (at the command's extreme values)
    are left out of the law's fit, and the law is fitted on each quarter of the
    record (the best quarter counts: lift-off and rest are not under the law).
    """
    if data.r is not None or data.u is None or data.p != 1:
        return None
    worst = 1.0
    for j in range(data.nu):
        worst = min(worst, _best_law_r2(data.y_control, data.u[:, j]))
    if worst < EXACT_LAW_R2:
        return None
    return (
        "no excitation r, and every command is an exact linear function of the outputs "
        f"(controller difference equation na = nb = 2: R^2 >= {worst:.6f}): only noise "
        "drives the loop, so u -> y cannot be told from the controller's inverse and no "
        "open-loop pole is claimed; a dither added to the command (logged, or recoverable "
        "from the law) would identify the plant"
    )


def _best_law_r2(y: Any, u: Any, pieces: int = 4) -> float:
    from maglevid.diagnose.quality import fit_controller_arx
    from maglevid.exceptions import IdentificationError

    n = u.shape[0]
    best = 0.0
    for q in range(pieces):
        mask = np.zeros(n, dtype=bool)
        mask[q * n // pieces : (q + 1) * n // pieces] = True
        mask &= (u > u.min()) & (u < u.max())
        try:
            with np.errstate(all="ignore"):  # an exact law makes the covariance singular
                fit = fit_controller_arx(y, u, na=2, nb=2, nk=0, mask=mask)
        except IdentificationError:
            continue
        if np.isfinite(fit.r_squared):
            best = max(best, fit.r_squared)
    return best
