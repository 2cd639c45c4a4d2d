"""Is the state recoverable from ``[y; u_f]``? The loop matrix of eqs. (44)-(46).

The paper's exact ARX model of the observer/controller needs

.. math::

    \\begin{bmatrix} x(k) \\\\ e(k) \\end{bmatrix}
    = \\begin{bmatrix} C & 0 \\\\ -F & F_e \\end{bmatrix}^{-1}
      \\begin{bmatrix} y(k) \\\\ u_f(k) \\end{bmatrix}                \\qquad (46)

so the loop matrix ``M = [[C, 0], [-F, F_e]]`` must be square (``ny + nu = nx + ne``)
and nonsingular.

When is it singular? Write ``z = [x; e]``. ``M z = 0`` means ``C x = 0``, i.e.
``x = N a`` with ``N`` a basis of the null space of ``C`` (the unmeasured state
directions: for the bearing, the velocity), and then ``-F N a + F_e e = 0``. So
``M`` is singular exactly when the *restricted* matrix

.. math::

    S = [\\,-F N,\\; F_e\\,]  \\qquad (n_u \\times (n_x - \\mathrm{rank}\\,C + n_e))

is singular: some combination ``w' u_f`` of the controller outputs does not
depend on the unmeasured states nor on the integrals -- the row ``w'[-F, F_e]``
lies in the row space of ``[C, 0]`` -- so ``[y; u_f]`` carries one equation too
few about ``[x; e]``.

A mirror-symmetric controller for a symmetric bearing (same gains on both coils,
opposite signs on displacement, velocity and integral) is the textbook case:
``u_f1 + u_f2`` then depends on ``i1 + i2`` only (``w = [1, 1]``). It is the
natural result of any design with mirror-symmetric weights, because in a
symmetric bearing the common-mode current does not act on the rotor.

:func:`loop_matrix_condition` measures how close ``S`` is to singular
independently of the units of the states (its columns are scaled to unit
length); :func:`check_loop_matrix` raises :class:`~maglevid.exceptions.DesignError`
with this explanation when it is too large.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid._validation import as_matrix
from maglevid.exceptions import DesignError

__all__ = [
    "DEFAULT_MAX_CONDITION",
    "check_loop_matrix",
    "loop_matrix",
    "loop_matrix_condition",
    "restricted_loop_matrix",
]

#: Default largest accepted condition number, 1/sqrt(eps): beyond it eq. (46)
#: loses more than half of the double-precision digits.
DEFAULT_MAX_CONDITION = 1e8


def _check(C: Any, F: Any, Fe: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    C = as_matrix(C, "C")
    F = as_matrix(F, "F", (None, C.shape[1]))
    Fe = as_matrix(Fe, "Fe", (F.shape[0], None))
    return C, F, Fe


def loop_matrix(C: Any, F: Any, Fe: Any) -> np.ndarray:
    """``[[C, 0], [-F, F_e]]`` of eqs. (44)-(46), shape ``(ny + nu, nx + ne)``."""
    C, F, Fe = _check(C, F, Fe)
    ny, ne = C.shape[0], Fe.shape[1]
    return np.block([[C, np.zeros((ny, ne))], [-F, Fe]])  # eq. (44), second row


def restricted_loop_matrix(C: Any, F: Any, Fe: Any) -> np.ndarray:
    """``S = [-F N, F_e]`` with ``N`` an orthonormal basis of ``null(C)``.

    ``M`` of eq. (46) is singular exactly when ``S`` is (module notes). Raises
    :class:`DesignError` when ``M`` is not square or ``C`` lacks full row rank.
    """
    C, F, Fe = _check(C, F, Fe)
    (ny, nx), (nu, ne) = C.shape, Fe.shape
    if ny + nu != nx + ne:
        raise DesignError(
            f"the loop matrix [[C, 0], [-F, Fe]] is {ny + nu}x{nx + ne}, not square: the exact "
            f"ARX model of eqs. (45)-(47) needs ny + nu = nx + ne, here {ny} + {nu} != "
            f"{nx} + {ne}. Integrate fewer or more outputs (E has ne = {ne} rows)"
        )
    N = sla.null_space(C)
    if N.shape[1] != nx - ny:
        raise DesignError(
            f"C ({ny}x{nx}) does not have full row rank: some outputs are combinations of "
            "the others, so [y; u_f] cannot determine the state (eq. (46))"
        )
    return np.hstack([-F @ N, Fe])


def loop_matrix_condition(C: Any, F: Any, Fe: Any) -> float:
    """Unit-free condition number of the loop matrix of eq. (46).

    The 2-norm condition number of ``S = [-F N, F_e]`` (module notes) after
    scaling each column to unit length, so that it does not depend on the units
    of the unmeasured states and integrals. ``inf`` when exactly singular.

    For the bearing ``S`` is 2x2: the velocity and integral gains of the two
    coils. A value near 1 means the two coils' rows are far from proportional;
    a mirror-symmetric controller gives ``inf`` (or ~1e13-1e16 after rounding).

    Examples
    --------
    >>> import numpy as np
    >>> C = [[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]]
    >>> F = [[1e6, 700.0, 300.0, -300.0], [-1e6, -700.0, -300.0, 300.0]]
    >>> loop_matrix_condition(C, F, [[500.0], [-500.0]]) > 1e12  # mirror-symmetric
    True
    >>> round(loop_matrix_condition(C, F, [[500.0], [200.0]]), 2)  # asymmetric integral
    1.52
    """
    S = restricted_loop_matrix(C, F, Fe)
    norms = np.linalg.norm(S, axis=0)
    if np.any(norms == 0):
        return float("inf")
    s = np.linalg.svd(S / norms, compute_uv=False)
    return float("inf") if s[-1] == 0 else float(s[0] / s[-1])


def check_loop_matrix(
    C: Any, F: Any, Fe: Any, *, max_condition: float = DEFAULT_MAX_CONDITION
) -> float:
    """Raise :class:`DesignError` unless eq. (46) can be used; return the condition number.

    Parameters
    ----------
    C : array_like, shape (ny, nx)
    F : array_like, shape (nu, nx)
    Fe : array_like, shape (nu, ne)
    max_condition : float
        Largest accepted :func:`loop_matrix_condition` (default ``1e8``).

    Raises
    ------
    DesignError
        With the combination of controller outputs that carries no information on
        the unmeasured states and integrals, and what to do about it.
    """
    cond = loop_matrix_condition(C, F, Fe)
    if cond <= max_condition:
        return cond
    S = restricted_loop_matrix(C, F, Fe)
    norms = np.linalg.norm(S, axis=0)
    norms[norms == 0] = 1.0
    U, _, _ = np.linalg.svd(S / norms)
    w = U[:, -1]
    w = w / w[np.argmax(np.abs(w))]
    combo = " + ".join(f"({wi:.3g}) u_f{i + 1}" for i, wi in enumerate(w))
    msg = (
        f"the loop matrix [[C, 0], [-F, Fe]] of eq. (46) is singular or nearly so (unit-free "
        f"condition number {cond:.3g} > {max_condition:.3g}): the combination {combo} of the "
        "controller outputs does not depend on the unmeasured states (the null space of C) nor "
        "on the integral states -- its row of [-F, Fe] is a combination of the rows of [C, 0] "
        "-- so [y; u_f] cannot determine [x; e] and the paper's identification (eqs. (46)-(51)) "
        "is impossible."
    )
    if w.size == 2 and np.allclose(np.abs(w), 1.0, atol=1e-3) and w[0] * w[1] > 0:
        msg += (
            " This is the mirror-symmetric controller (same gains on both coils, opposite "
            "signs on displacement, velocity and integral): u_f1 + u_f2 then depends on the "
            "common-mode current only."
        )
    msg += (
        " Use a deliberately asymmetric design, e.g. design_pole_placement() on the extended "
        "model (maglevid.simulate.amb.default_amb_controller does), and check it with "
        "loop_matrix_condition()."
    )
    raise DesignError(msg)
