"""Controllers and observers of Gosiewski & Paszowski: state feedback with integral
action (eqs. (39)-(42)), observers in the paper's sign convention (eqs. (17), (43)),
and the loop-matrix check the identification needs (eq. (46))."""

from __future__ import annotations

from maglevid.control.integral import (
    IntegralStateFeedback,
    check_integral_selector,
    closed_loop_poles,
    design_lqr,
    design_pole_placement,
    extended_model,
    integral_selector,
)
from maglevid.control.loop_matrix import (
    DEFAULT_MAX_CONDITION,
    check_loop_matrix,
    loop_matrix,
    loop_matrix_condition,
    restricted_loop_matrix,
)
from maglevid.control.observer import (
    OBSERVER_KINDS,
    Observer,
    design_deadbeat_observer,
    design_kalman_observer,
    design_observer_pole_placement,
    observability_indices,
)

__all__ = [
    "DEFAULT_MAX_CONDITION",
    "OBSERVER_KINDS",
    "IntegralStateFeedback",
    "Observer",
    "check_integral_selector",
    "check_loop_matrix",
    "closed_loop_poles",
    "design_deadbeat_observer",
    "design_kalman_observer",
    "design_lqr",
    "design_observer_pole_placement",
    "design_pole_placement",
    "extended_model",
    "integral_selector",
    "loop_matrix",
    "loop_matrix_condition",
    "observability_indices",
    "restricted_loop_matrix",
]
