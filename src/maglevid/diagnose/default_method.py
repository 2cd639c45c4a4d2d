"""The method ``diagnose`` uses when none is given, and how a machine's history continues.

A diagnosis asks the data for the physical parameters as precisely as they
allow, so for a two-coil bearing it uses maximum likelihood (``ml``,
:mod:`maglevid.identify.ml`; issue 13): on the realistic bearing (nonlinear
plant, nominal bias voltages, force disturbance, sensor noise; 4 s records) it
resolves the 5 % tolerances where the instrumental-variable ``physical`` method
cannot (healthy bearings "No significant change" instead of "Inconclusive",
R1 +20 % named instead of missed) at about 10x its time; the measured table is
in docs/diagnosis.md. The choice is the plant kind's (``diagnosis_method``,
``diagnosis_reason`` and ``former_diagnosis_method`` of its module in
:mod:`maglevid.plants`). ``maglevid identify`` and :func:`maglevid.identify` keep the
plant kind's default (:func:`maglevid.plants.choose_method`, ``physical``).

**Histories are per method** (methods have different biases; trends and the
``history`` baseline never mix them). A machine whose latest stored diagnosis
used the former default (``physical``) therefore continues with it when no
method is given, and the diagnosis says so in a note; ``--method ml`` once
starts the machine's ``ml`` series, and later diagnoses continue that one. No
stored entry is changed (docs/history.md, "Default method and existing
histories").
"""

from __future__ import annotations

from typing import Any

from maglevid.data import ClosedLoopData

__all__ = ["choose_diagnosis_method"]


def choose_diagnosis_method(
    data: ClosedLoopData, *, history: Any = None, machine: str | None = None
) -> tuple[str, str, str | None]:
    """The method for diagnosing ``data`` without a stated one: ``(method, reason, note)``.

    ``note`` is set when the machine's history decides (its latest diagnosis with
    estimates in ``history`` used the former default): the diagnosis prints it.
    """
    from maglevid.plants import choose_method
    from maglevid.plants.base import kind_of

    method, reason = choose_method(data)
    k = kind_of(data)[0]
    kind = k.name
    if getattr(k, "diagnosis_method", None) is None:
        return method, reason, None
    method, why = k.diagnosis_method, k.diagnosis_reason
    reason = f"plant kind {kind}; the diagnosis default {method}: {why}"
    former = getattr(k, "former_diagnosis_method", None)
    if history is None or machine is None or former is None:
        return method, reason, None
    used = history.methods(machine)
    if not used or list(used)[-1] != former:
        return method, reason, None
    note = (
        f"method {former}: continues machine {machine!r}'s history ({used[former]} "
        f"diagnoses with {former}, the diagnosis default before {method}); trends and "
        f"the history baseline are per method, so --method {method} starts its {method} "
        "series (later diagnoses then continue that one)"
    )
    return former, f"continues the machine's history (plant kind {kind})", note
