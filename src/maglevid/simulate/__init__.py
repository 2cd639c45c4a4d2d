"""Closed-loop simulation (Gosiewski & Paszowski, Figs. 1-2): the AMB under observer-based
state feedback with integral action, a fast kernel for linear recursions, excitation signals.

Modules defining ``SCENARIO`` are the scenarios of ``maglevid simulate``.
"""

from __future__ import annotations

from maglevid.simulate.amb import simulate_amb_loop, simulate_amb_loops
from maglevid.simulate.excitation import make_excitation
from maglevid.simulate.kernel import simulate_lti
from maglevid.simulate.loop import (
    LoopSignals,
    closed_loop_system,
    replay_feedback,
    simulate_linear_loop,
)

__all__ = [
    "LoopSignals",
    "closed_loop_system",
    "make_excitation",
    "replay_feedback",
    "simulate_amb_loop",
    "simulate_amb_loops",
    "simulate_linear_loop",
    "simulate_lti",
]
