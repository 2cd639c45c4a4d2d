"""The closed loop of a recording: plant + observer + controller (report, compare).

The controller of Gosiewski & Paszowski is an observer with state feedback and
integral action (eqs. (39)-(43)), as a recording's ``loop`` states it::

    x^(k+1) = (A + G C) x^(k) + B u(k) - G y(k)         (43), observer "prediction"
    e(k+1) = e(k) - E y(k+1)                             (39)
    u(k) = u_f(k) + r(k),   u_f(k) = -F x^(k) + Fe e(k)  (42)

with ``loop = {"controller": {"F", "Fe", "E"}, "observer": {"A", "B", "C", "G"}}``
(``Fe``/``E`` absent for plain state feedback). The observer runs on the
controller's *own* model (the nominal bearing), which does not change when the
bearing does; so the closed loop of the *identified* plant with the same
controller shows what a fault does to the running machine.

A controller is given to :func:`controller_state_space` in one of two forms:

* that ``loop`` mapping (a :class:`~maglevid.data.ClosedLoopData`'s ``loop``);
  an observer without ``A``, ``B``, ``C`` runs on the ``plant`` argument
  (normally the baseline plant sampled at the control period);
* a discrete :class:`~maglevid.lti.StateSpace` (or its ``to_dict`` mapping)
  whose output is ``u_f`` and whose input is ``y`` (``ny`` inputs) or
  ``v = [u; y]`` (``nu + ny`` inputs, the order of eq. (18)).

:func:`close_loop` connects a discrete plant (``D = 0``) with such a
controller and returns the closed loop from ``r`` to ``y``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from maglevid._validation import as_matrix
from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace

__all__ = ["close_loop", "controller_state_space"]


def _as_discrete_ss(spec: Any, name: str) -> StateSpace:
    if isinstance(spec, StateSpace):
        sys = spec
    elif isinstance(spec, Mapping) and {"A", "B", "C"} <= set(spec):
        sys = StateSpace.from_dict(dict(spec))
    else:
        raise DataError(
            f"`{name}` must be a discrete StateSpace or a mapping with A, B, C, dt; "
            f"got {type(spec).__name__}"
        )
    if not sys.is_discrete:
        raise ModelError(f"`{name}` must be discrete (it runs at the control period); dt is None")
    return sys


def controller_state_space(spec: Any, *, plant: StateSpace | None = None) -> StateSpace:
    """A controller as a discrete state-space map from ``[u; y]`` (or ``y``) to ``u_f``.

    Parameters
    ----------
    spec : mapping or StateSpace
        A recording's ``loop`` (``{"controller": {"F"[, "Fe", "E"]}, "observer":
        {"G"[, "A", "B", "C"]}}``, eqs. (39)-(43)), or a state-space controller;
        see the module notes.
    plant : StateSpace, optional
        Discrete model the observer runs on when the ``loop`` states none.

    Returns
    -------
    StateSpace
        Discrete; inputs ``[u; y]`` for the ``loop`` form.

    Raises
    ------
    DataError
        Unknown form or observer type, or gains whose shapes do not fit.

    Notes
    -----
    With ``z(k) = e(k-1)`` as the integrator's state (``e(k)`` needs ``y(k)``),
    eqs. (39), (42), (43) become ``x^+ = (A + G C) x^ + B u - G y``,
    ``z+ = z - E y`` and ``u_f = -F x^ + Fe z - Fe E y``: states ``[x^; z]``,
    inputs ``[u; y]``.
    """
    if isinstance(spec, StateSpace) or (isinstance(spec, Mapping) and "A" in spec):
        return _as_discrete_ss(spec, "controller")
    if not (
        isinstance(spec, Mapping)
        and isinstance(spec.get("controller"), Mapping)
        and isinstance(spec.get("observer"), Mapping)
    ):
        raise DataError(
            "`controller` must be a recording's loop {'controller': {F, Fe, E}, 'observer': "
            "{A, B, C, G}} or a discrete StateSpace (input y or [u; y], output u_f); got "
            + (str(sorted(spec)) if isinstance(spec, Mapping) else type(spec).__name__)
        )
    ctrl, obs = spec["controller"], spec["observer"]
    # Every observer maglevid designs (deadbeat, Kalman, pole placement, given) is
    # the prediction form of eq. (43); "type" records how its gain was designed.
    from maglevid.control.observer import OBSERVER_KINDS

    if obs.get("type", "prediction") not in ("prediction", *OBSERVER_KINDS):
        raise DataError(
            f"observer type {obs.get('type')!r} is not supported; expected 'prediction' "
            f"or one of {OBSERVER_KINDS} (x^(k+1) = (A + G C) x^(k) + B u(k) - G y(k), eq. (43))"
        )
    if {"A", "B", "C"} <= set(obs):
        A = as_matrix(obs["A"], "loop['observer']['A']")
        B = as_matrix(obs["B"], "loop['observer']['B']", (A.shape[0], None))
        C = as_matrix(obs["C"], "loop['observer']['C']", (None, A.shape[0]))
        dt = spec.get("dt", plant.dt if plant is not None else None)
    elif plant is not None:
        A, B, C, dt = plant.A, plant.B, plant.C, plant.dt
    else:
        raise DataError(
            "the loop's observer states no model (A, B, C) and no discrete baseline plant "
            "was given for it"
        )
    if dt is None:
        raise DataError("the control period is unknown: give the discrete plant")
    nx, nu, ny = A.shape[0], B.shape[1], C.shape[0]
    F = as_matrix(ctrl["F"], "loop['controller']['F']", (nu, nx))
    G = as_matrix(obs["G"], "loop['observer']['G']", (nx, ny))
    if "Fe" in ctrl or "E" in ctrl:
        E = as_matrix(ctrl["E"], "loop['controller']['E']", (None, ny))
        Fe = as_matrix(ctrl["Fe"], "loop['controller']['Fe']", (nu, E.shape[0]))
    else:
        E, Fe = np.zeros((0, ny)), np.zeros((nu, 0))
    ne = E.shape[0]
    Ak = np.zeros((nx + ne, nx + ne))
    Ak[:nx, :nx] = A + G @ C  # eq. (43)
    Ak[nx:, nx:] = np.eye(ne)  # eq. (39)
    Bk = np.zeros((nx + ne, nu + ny))
    Bk[:nx, :nu] = B
    Bk[:nx, nu:] = -G  # eq. (43)
    Bk[nx:, nu:] = -E  # eq. (39)
    Ck = np.hstack([-F, Fe])  # eq. (42)
    Dk = np.hstack([np.zeros((nu, nu)), -Fe @ E])  # e(k) = z(k) - E y(k) in eq. (42)
    return StateSpace(Ak, Bk, Ck, Dk, dt)


def close_loop(plant: StateSpace, controller: StateSpace) -> StateSpace:
    """Closed loop from the excitation ``r`` to the outputs ``y`` (``u = u_f + r``).

    Parameters
    ----------
    plant : StateSpace
        Discrete plant with ``D = 0`` (a sampled physical model).
    controller : StateSpace
        Discrete, from :func:`controller_state_space`: input ``y`` or ``[u; y]``,
        output ``u_f``; same sample time.

    Returns
    -------
    StateSpace
        States ``[x; x_k]``, input ``r``, outputs ``y``.

    Notes
    -----
    With ``x_k+ = A_k x_k + B_u u + B_y y`` and ``u_f = C_k x_k + D_u u + D_y y``,
    ``u = u_f + r`` gives ``(I - D_u) u = C_k x_k + D_y C x + r``, solved for ``u``
    (an algebraic loop only when ``D_u != 0``).
    """
    if not plant.is_discrete or not controller.is_discrete:
        raise ModelError("close_loop needs a discrete plant and a discrete controller")
    if not np.isclose(plant.dt, controller.dt, rtol=1e-9, atol=0.0):
        raise ModelError(
            f"plant dt={plant.dt:g} s and controller dt={controller.dt:g} s differ; "
            "the loop runs at one control period"
        )
    if np.any(plant.D != 0):
        raise ModelError("close_loop expects a strictly proper plant (D = 0)")
    nx, nu, ny = plant.nx, plant.nu, plant.ny
    if controller.ny != nu:
        raise DataError(f"the controller has {controller.ny} outputs; the plant has {nu} inputs")
    if controller.nu == nu + ny:
        Bu, By = controller.B[:, :nu], controller.B[:, nu:]
        Du, Dy = controller.D[:, :nu], controller.D[:, nu:]
    elif controller.nu == ny:
        Bu, By = np.zeros((controller.nx, nu)), controller.B
        Du, Dy = np.zeros((nu, nu)), controller.D
    else:
        raise DataError(
            f"the controller has {controller.nu} inputs; expected y ({ny}) or [u; y] ({nu + ny})"
        )
    nk = controller.nx
    # u = M (C_k x_k + D_y C x + r), M = (I - D_u)^-1, as a solve.
    M = np.linalg.solve(np.eye(nu) - Du, np.eye(nu))
    Ux = M @ Dy @ plant.C  # u per plant state
    Uk = M @ controller.C  # u per controller state
    A = np.zeros((nx + nk, nx + nk))
    A[:nx, :nx] = plant.A + plant.B @ Ux
    A[:nx, nx:] = plant.B @ Uk
    A[nx:, :nx] = Bu @ Ux + By @ plant.C
    A[nx:, nx:] = controller.A + Bu @ Uk
    B = np.vstack([plant.B @ M, Bu @ M])
    C = np.hstack([plant.C, np.zeros((ny, nk))])
    return StateSpace(
        A,
        B,
        C,
        None,
        plant.dt,
        input_names=tuple(f"r{i + 1}" for i in range(nu)),
        output_names=plant.output_names,
    )
