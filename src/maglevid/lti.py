"""Linear time-invariant state-space models and zero-order-hold sampling.

:class:`StateSpace` is an immutable ``(A, B, C, D, dt)`` model (``dt=None`` for
continuous time). :func:`discretize` implements the zero-order hold of
Gosiewski & Paszowski eq. (7); :func:`undiscretize` its inverse, eq. (8).

Both go through the augmented matrix

.. math::

    \\exp\\left(\\begin{bmatrix} A_c & B_c \\\\ 0 & 0 \\end{bmatrix} \\Delta t\\right)
    = \\begin{bmatrix} A & B \\\\ 0 & I \\end{bmatrix},

so the inverse is the principal matrix logarithm of ``[[A, B], [0, I]]``. This
form needs no inverse of ``A - I`` (eq. (8) as printed fails when ``A`` has an
eigenvalue at 1, e.g. an integrator) and is exact where eq. (8) is defined.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid._validation import as_matrix, as_signal, check_positive
from maglevid.exceptions import DataError, ModelError

__all__ = ["StateSpace", "discretize", "undiscretize"]


@dataclass(frozen=True, eq=False)
class StateSpace:
    """Immutable linear state-space model ``x' = A x + B u, y = C x + D u``.

    Parameters
    ----------
    A : array_like, shape (nx, nx)
    B : array_like, shape (nx, nu)
    C : array_like, shape (ny, nx)
    D : array_like, shape (ny, nu), optional
        Zero when omitted.
    dt : float or None
        Sample time in seconds; ``None`` for a continuous-time model.
    state_names, input_names, output_names : sequence of str, optional
        Labels used in summaries and plots.

    Examples
    --------
    >>> import numpy as np
    >>> sys = StateSpace([[0.0, 1.0], [4.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]])
    >>> np.sort(sys.poles().real)
    array([-2.,  2.])
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray | None = None
    dt: float | None = None
    state_names: tuple[str, ...] = field(default=())
    input_names: tuple[str, ...] = field(default=())
    output_names: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        A = as_matrix(self.A, "A")
        nx = A.shape[0]
        if A.shape != (nx, nx):
            raise DataError(f"`A` must be square; got shape {A.shape}")
        B = as_matrix(self.B, "B", (nx, None))
        C = as_matrix(self.C, "C", (None, nx))
        D = np.zeros((C.shape[0], B.shape[1])) if self.D is None else self.D
        D = as_matrix(D, "D", (C.shape[0], B.shape[1]))
        dt = None if self.dt is None else check_positive(self.dt, "dt")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "C", C)
        object.__setattr__(self, "D", D)
        object.__setattr__(self, "dt", dt)
        for attr, n in (
            ("state_names", nx),
            ("input_names", B.shape[1]),
            ("output_names", C.shape[0]),
        ):
            names = tuple(getattr(self, attr))
            if names and len(names) != n:
                raise DataError(f"`{attr}` has {len(names)} names; the model has {n}")
            object.__setattr__(self, attr, names)

    # ------------------------------------------------------------------ shape
    @property
    def nx(self) -> int:
        return self.A.shape[0]

    @property
    def nu(self) -> int:
        return self.B.shape[1]

    @property
    def ny(self) -> int:
        return self.C.shape[0]

    @property
    def is_discrete(self) -> bool:
        return self.dt is not None

    def __repr__(self) -> str:
        kind = f"dt={self.dt:g}" if self.dt is not None else "continuous"
        return f"StateSpace(nx={self.nx}, nu={self.nu}, ny={self.ny}, {kind})"

    # -------------------------------------------------------------- analysis
    def poles(self) -> np.ndarray:
        """Eigenvalues of ``A`` (z-plane for discrete, s-plane for continuous models)."""
        return np.linalg.eigvals(self.A)

    def is_stable(self) -> bool:
        """Asymptotic stability: all poles in the open unit disc / left half-plane."""
        p = self.poles()
        return bool(np.all(np.abs(p) < 1.0)) if self.is_discrete else bool(np.all(p.real < 0))

    def markov(self, n: int) -> np.ndarray:
        """Markov parameters ``[D, CB, CAB, ..., CA^(n-2)B]``, shape ``(n, ny, nu)``.

        For a discrete model these are the impulse response (Gosiewski & Paszowski
        eq. (9)); they are invariant under a change of state basis (eq. (12)).
        """
        out = np.empty((n, self.ny, self.nu))
        if n == 0:
            return out
        out[0] = self.D
        AkB = self.B.copy()
        for k in range(1, n):
            out[k] = self.C @ AkB
            AkB = self.A @ AkB
        return out

    def frequency_response(self, omega: Any) -> np.ndarray:
        """Complex response ``C (sI - A)^-1 B + D`` at angular frequencies ``omega`` [rad/s].

        Discrete models are evaluated at ``z = exp(j omega dt)``. Shape ``(len(omega), ny, nu)``.
        """
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        s = np.exp(1j * w * self.dt) if self.is_discrete else 1j * w
        # Hessenberg form makes each solve O(nx^2); plain solves are fine for small nx.
        out = np.empty((w.size, self.ny, self.nu), dtype=complex)
        eye = np.eye(self.nx)
        for k, sk in enumerate(s):
            out[k] = self.C @ np.linalg.solve(sk * eye - self.A, self.B) + self.D
        return out

    def transform(self, T: Any) -> StateSpace:
        """Realization in new coordinates ``x = T z`` (Gosiewski & Paszowski eq. (11))."""
        T = as_matrix(T, "T", (self.nx, self.nx))
        Ti = np.linalg.inv(T)
        return self._replace(A=Ti @ self.A @ T, B=Ti @ self.B, C=self.C @ T, state_names=())

    def simulate(self, u: Any, x0: Any = None) -> tuple[np.ndarray, np.ndarray]:
        """Simulate a discrete model: returns ``(y, x)`` with shapes ``(N, ny)``, ``(N, nx)``."""
        if not self.is_discrete:
            raise ModelError("simulate() needs a discrete model; call discretize() first")
        u = as_signal(u, "u", n_channels=self.nu)
        x = np.zeros(self.nx) if x0 is None else np.asarray(x0, dtype=float).reshape(self.nx)
        # x(k) for all k by the recursion; y = C x + D u in one product.
        X = np.empty((u.shape[0], self.nx))
        Bu = u @ self.B.T
        AT = self.A.T
        for k in range(u.shape[0]):
            X[k] = x
            x = x @ AT + Bu[k]
        return X @ self.C.T + u @ self.D.T, X

    # ------------------------------------------------------------ conversion
    def _replace(self, **changes: Any) -> StateSpace:
        kw = {
            "A": self.A,
            "B": self.B,
            "C": self.C,
            "D": self.D,
            "dt": self.dt,
            "state_names": self.state_names,
            "input_names": self.input_names,
            "output_names": self.output_names,
        }
        kw.update(changes)
        return StateSpace(**kw)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe dictionary (lists of floats)."""
        return {
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "D": self.D.tolist(),
            "dt": self.dt,
            "state_names": list(self.state_names),
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> StateSpace:
        """The model of :meth:`to_dict`; a dict without ``A``, ``B``, ``C`` is a DataError."""
        missing = [k for k in ("A", "B", "C") if k not in d]
        if missing:
            kind = f" (a {d['type']!r} description)" if isinstance(d.get("type"), str) else ""
            raise DataError(
                f"not a state-space model{kind}: keys {sorted(map(str, d))}, missing "
                f"{missing}; expected a dict with 'A', 'B', 'C' (and 'D', 'dt')"
            )
        return cls(
            d["A"],
            d["B"],
            d["C"],
            d.get("D"),
            d.get("dt"),
            tuple(d.get("state_names", ())),
            tuple(d.get("input_names", ())),
            tuple(d.get("output_names", ())),
        )

    def to_control(self) -> Any:
        """Convert to ``control.StateSpace`` (needs the optional python-control package)."""
        try:
            import control
        except ImportError as exc:  # pragma: no cover - depends on the environment
            raise ImportError(
                "python-control is not installed; `pip install maglevid[control]`"
            ) from exc
        dt = 0 if self.dt is None else self.dt
        # Channel names travel as python-control labels (x, i1, i2 rather than y[0..2]).
        labels = {
            key: list(names)
            for key, names in (
                ("states", self.state_names),
                ("inputs", self.input_names),
                ("outputs", self.output_names),
            )
            if names
        }
        return control.ss(
            np.array(self.A), np.array(self.B), np.array(self.C), np.array(self.D), dt, **labels
        )

    @classmethod
    def from_control(cls, sys: Any) -> StateSpace:
        """Build from a ``control.StateSpace`` (``dt=0`` or ``None`` means continuous)."""
        dt = getattr(sys, "dt", None)
        if dt is True:
            raise ModelError("control.StateSpace with dt=True has no numeric sample time")
        dt = None if not dt else float(dt)

        def names(attr: str, default: str) -> tuple[str, ...]:
            # python-control's default labels (x[0], u[0], y[0]) are not names.
            labels = list(getattr(sys, attr, None) or ())
            return (
                () if all(n == f"{default}[{i}]" for i, n in enumerate(labels)) else tuple(labels)
            )

        return cls(
            sys.A, sys.B, sys.C, sys.D, dt,
            names("state_labels", "x"), names("input_labels", "u"), names("output_labels", "y"),
        )  # fmt: skip


def _expm_balanced(M: np.ndarray) -> np.ndarray:
    # Balancing (a diagonal similarity) evens out rows and columns whose norms differ
    # by orders of magnitude, as in the AMB model (1 next to 7.8e5).
    Mb, T = sla.matrix_balance(M, permute=False)
    d = np.diag(T)
    return (sla.expm(Mb) * d[:, None]) / d[None, :]


def discretize(sys: StateSpace, dt: float) -> StateSpace:
    """Zero-order-hold sampling of a continuous model (Gosiewski & Paszowski eq. (7)).

    ``A = exp(A_c dt)``, ``B = int_0^dt exp(A_c s) ds B_c``, both read off the
    exponential of the augmented matrix ``[[A_c, B_c], [0, 0]] dt``.

    Parameters
    ----------
    sys : StateSpace
        Continuous-time model (``dt is None``).
    dt : float
        Sample time in seconds.

    Returns
    -------
    StateSpace
        Discrete model with the same ``C``, ``D`` and names.

    Examples
    --------
    >>> sys = StateSpace([[-1.0]], [[1.0]], [[1.0]])
    >>> round(float(discretize(sys, 0.1).A[0, 0]), 12) == round(float(np.exp(-0.1)), 12)
    True
    """
    if sys.is_discrete:
        raise ModelError(f"discretize() needs a continuous model; this one has dt={sys.dt}")
    dt = check_positive(dt, "dt")
    nx, nu = sys.nx, sys.nu
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx] = sys.A * dt
    M[:nx, nx:] = sys.B * dt
    E = _expm_balanced(M)  # eq. (7)
    return sys._replace(A=E[:nx, :nx], B=E[:nx, nx:], dt=dt)


def undiscretize(sys: StateSpace) -> StateSpace:
    """Continuous model whose zero-order-hold sampling is ``sys`` (eq. (8)).

    Computed as the principal logarithm of ``[[A, B], [0, I]]`` divided by ``dt``.
    Equivalent to ``A_c = ln(A)/dt, B_c = (A - I)^-1 A_c B`` where that is defined.

    Raises
    ------
    ModelError
        If ``A`` has an eigenvalue at zero or on the negative real axis: no real
        continuous model samples to it (the logarithm is complex), which usually
        means the sample time is too long for the dynamics or the estimate is wrong.
    """
    if not sys.is_discrete:
        raise ModelError("undiscretize() needs a discrete model (dt is None)")
    nx = sys.nx
    lam, V = np.linalg.eig(sys.A)
    scale = max(1.0, float(np.max(np.abs(lam))) if lam.size else 1.0)
    tol = 1e-12 * scale
    bad = lam[(np.abs(lam.imag) <= tol) & (lam.real <= tol)]
    if bad.size:
        raise ModelError(
            "the discrete model has eigenvalue(s) "
            + ", ".join(f"{b.real:.6g}" for b in bad)
            + " at zero or on the negative real axis, so ln(A) is not real and no "
            "continuous model samples to it under a zero-order hold (eq. (8)); "
            "check the sample time and the estimate"
        )
    L = _log_zoh_eig(sys.A, sys.B, lam, V)
    if L is None:
        L = _log_zoh_schur(sys.A, sys.B)
    return sys._replace(A=L[:nx, :nx] / sys.dt, B=L[:nx, nx:] / sys.dt, dt=None)


#: Largest condition number of A's eigenvector matrix for which ``undiscretize`` takes
#: the logarithm through the eigen-decomposition (its error ~ eps times it, < 1e-12).
_EIG_LOG_COND = 1e4


def _log_zoh_eig(
    A: np.ndarray, B: np.ndarray, lam: np.ndarray, V: np.ndarray
) -> np.ndarray | None:
    """``ln([[A, B], [0, I]])`` from ``A = V diag(lam) V^-1`` (eq. (8)), or ``None``.

    ``ln A`` commutes with ``A``, so the logarithm of the block matrix is
    ``[[ln A, f(A) B], [0, 0]]`` with ``f(z) = ln(z) / (z - 1)`` (``f(1) = 1``; the
    ``B`` block of the docstring's ``(A - I)^-1 ln(A) B``, defined also at ``z = 1``).
    On a diagonalisable ``A`` both are ``V g(lam) V^-1``: one 4 x 4 eigen-decomposition
    instead of the Schur-Pade logarithm of the (nx + nu) block matrix (10x faster, a
    fixed cost of every subspace fit). Returns ``None`` (the caller then takes the
    Schur route) when ``V`` is ill-conditioned (a defective or nearly defective ``A``)
    or the result is not real to rounding.
    """
    nx = A.shape[0]
    L = np.zeros((nx + B.shape[1], nx + B.shape[1]))
    if nx == 0:
        return L
    if not np.all(np.isfinite(lam)) or np.linalg.cond(V) > _EIG_LOG_COND:
        return None
    log_lam = np.log(lam)
    d = lam - 1.0
    f = np.ones_like(lam)
    small = np.abs(d) < 1e-5  # the series of ln(1 + d) / d: error below d^4
    ds = d[small]
    f[small] = 1.0 - ds / 2.0 + ds**2 / 3.0 - ds**3 / 4.0
    f[~small] = log_lam[~small] / d[~small]
    Vi = np.linalg.inv(V)
    logA = (V * log_lam) @ Vi
    FB = (V * f) @ (Vi @ B)
    big = max(1.0, float(np.max(np.abs(logA.real))), float(np.max(np.abs(FB.real), initial=0.0)))
    if max(np.max(np.abs(logA.imag)), np.max(np.abs(FB.imag), initial=0.0)) > 1e-9 * big:
        return None
    L[:nx, :nx] = logA.real
    L[:nx, nx:] = FB.real
    return L


def _log_zoh_schur(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``ln([[A, B], [0, I]])`` by scipy's Schur-Pade ``logm`` of the balanced matrix."""
    nx, nu = A.shape[0], B.shape[1]
    M = np.eye(nx + nu)
    M[:nx, :nx] = A
    M[:nx, nx:] = B
    Mb, T = sla.matrix_balance(M, permute=False)
    d = np.diag(T)
    Lb = sla.logm(Mb)
    L = (Lb * d[:, None]) / d[None, :]
    if np.iscomplexobj(L):
        if np.max(np.abs(L.imag)) > 1e-9 * max(1.0, np.max(np.abs(L.real))):
            raise ModelError("the matrix logarithm of the discrete model is not real")
        L = L.real
    return L
