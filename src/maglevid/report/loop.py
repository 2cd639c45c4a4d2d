"""The closed loop seen by the report: plant + observer + controller.

The controller of Gosiewski & Paszowski is an observer with state feedback
(eqs. (16)-(17))::

    x^(k+1) = (A + G C) x^(k) + B u(k) - G y(k)        (17)
    u(k) = u_f(k) + r(k),   u_f(k) = -F x^(k)           (16)

optionally with an integral part ``q(k+1) = q(k) + C_i y(k)``,
``u_f(k) = -F x^(k) - F_i q(k)``. The observer runs on the controller's *own*
model (the nominal bearing), which does not change when the bearing does; so
the closed loop of the *identified* plant with the same controller shows what a
fault does to the running machine.

A controller is given to :func:`controller_state_space` in one of two forms:

* a discrete :class:`~maglevid.lti.StateSpace` (or its ``to_dict`` mapping)
  whose output is ``u_f`` and whose input is either ``y`` (``ny`` inputs) or
  ``v = [u; y]`` (``nu + ny`` inputs, the order of eq. (18));
* a mapping ``{"F": ..., "G": ...}`` (and optionally ``"Fi"``, ``"Ci"``) of the
  observer form above; its model ``{A, B, C}`` is the ``"model"`` entry
  (a discrete ``StateSpace`` or mapping) or the baseline plant sampled at
  ``dt``.

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
    spec : StateSpace or mapping
        See the module notes: a state-space controller, or the observer form
        ``{"F", "G"[, "Fi", "Ci", "model"]}`` of eqs. (16)-(17).
    plant : StateSpace, optional
        Discrete model the observer runs on when ``spec`` has no ``"model"``
        (normally the baseline plant sampled at the control period).

    Returns
    -------
    StateSpace
        Discrete; inputs ``[u; y]`` for the observer form.

    Raises
    ------
    DataError
        Unknown form, or gains whose shapes do not fit the model.
    """
    if isinstance(spec, StateSpace) or (isinstance(spec, Mapping) and "A" in spec):
        return _as_discrete_ss(spec, "controller")
    if not (isinstance(spec, Mapping) and {"F", "G"} <= set(spec)):
        raise DataError(
            "`controller` must be a discrete StateSpace (input y or [u; y], output u_f) or "
            "a mapping with the observer gains 'F' and 'G'; got "
            + (str(sorted(spec)) if isinstance(spec, Mapping) else type(spec).__name__)
        )
    model = spec.get("model")
    model = _as_discrete_ss(model, "controller['model']") if model is not None else plant
    if model is None:
        raise DataError(
            "the observer-form controller has no 'model' and no discrete baseline plant was "
            "given for its observer"
        )
    A, B, C = model.A, model.B, model.C
    nx, nu, ny = model.nx, model.nu, model.ny
    F = as_matrix(spec["F"], "controller['F']", (nu, nx))
    G = as_matrix(spec["G"], "controller['G']", (nx, ny))
    if "Fi" in spec:
        Fi = as_matrix(spec["Fi"], "controller['Fi']", (nu, None))
        ni = Fi.shape[1]
        Ci = as_matrix(spec.get("Ci", np.eye(ni, ny)), "controller['Ci']", (ni, ny))
    else:
        ni = 0
        Fi = np.zeros((nu, 0))
        Ci = np.zeros((0, ny))
    # States [x^, q]; inputs v = [u; y]; output u_f (eqs. (16)-(17)).
    Ak = np.zeros((nx + ni, nx + ni))
    Ak[:nx, :nx] = A + G @ C  # eq. (17)
    Ak[nx:, nx:] = np.eye(ni)
    Bk = np.zeros((nx + ni, nu + ny))
    Bk[:nx, :nu] = B
    Bk[:nx, nu:] = -G  # eq. (17)
    Bk[nx:, nu:] = Ci
    Ck = np.hstack([-F, -Fi])  # eq. (16)
    return StateSpace(Ak, Bk, Ck, None, model.dt)


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
