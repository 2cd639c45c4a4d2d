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
``intersampled-suspension`` outputs sampled ``p > 1`` times per control  ``intersample-ml``
                            period (Sun et al.)                          (``intersample``
                                                                         without M and R)
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

Each kind is one module (``amb.py``, ``suspension.py``, ``levitator.py``,
``mimo.py``) whose object satisfies :class:`~maglevid.plants.base.PlantKind`:
recognition, methods and default, parameter map with units, fault hypotheses
and their signatures, report panels, and the diagnosis stages the pipeline
runs (docs/architecture.md, "Plant kinds"). A new kind is a new module and one
:func:`register_kind` call.

Examples
--------
>>> import numpy as np
>>> from maglevid.data import ClosedLoopData
>>> d = ClosedLoopData(y=np.zeros((50, 2)), u=np.zeros((50, 1)), dt=0.01)
>>> infer_kind(d)[0]
'levitator'
"""

from __future__ import annotations

from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.plants import amb, levitator, mimo, suspension
from maglevid.plants.amb import DIAGNOSED_PARAMETERS
from maglevid.plants.base import (
    KINDS,
    DiagnosisRun,
    DiagnosisStages,
    PlantKind,
    kind_of,
    register_kind,
    stated_kind,
)

__all__ = [
    "DIAGNOSED_PARAMETERS",
    "KINDS",
    "DiagnosisRun",
    "DiagnosisStages",
    "PlantKind",
    "choose_method",
    "infer_kind",
    "kind_of",
    "register_kind",
    "stated_kind",
    "unidentifiable_reason",
]

# Recognition tries the kinds in this order (the generic MIMO kind last).
for _module in (amb, suspension, levitator, mimo):
    register_kind(_module.KIND)


def infer_kind(data: ClosedLoopData) -> tuple[str, str]:
    """The recording's kind and why (one sentence): stated, else inferred from its shape.

    Returns
    -------
    (kind, reason) : (str, str)
        ``kind`` is a key of :data:`KINDS`.
    """
    kind, why = kind_of(data)
    return kind.name, why


def choose_method(data: ClosedLoopData) -> tuple[str, str]:
    """The default identification method for this recording, and why (kind and method)."""
    kind, why_kind = kind_of(data)
    method, reason = kind.choose_method(data)
    return method, f"plant kind {kind.name} ({why_kind}); method {method}: {reason}"


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
