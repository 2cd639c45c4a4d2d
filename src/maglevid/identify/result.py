"""The one result type every identification method returns."""

from __future__ import annotations

import html
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
from scipy import special  # not scipy.stats: 0.6 s to import for one quantile

from maglevid._tables import html_table, number
from maglevid.data import unfreeze
from maglevid.exceptions import DataError
from maglevid.jsonable import to_jsonable
from maglevid.lti import StateSpace
from maglevid.physics.units import PARAMETER_INFO, parameter_unit

__all__ = ["RESULT_VERSION", "IdentificationResult", "central_jacobian", "propagate_covariance"]

#: Version of the ``to_dict`` layout; bump on incompatible change.
RESULT_VERSION = 1


@dataclass(frozen=True, eq=False)
class IdentificationResult:
    """What an identification method found, and how.

    Attributes
    ----------
    method : str
        Method name as accepted by ``maglevid identify --method``.
    model : StateSpace or None
        Identified discrete-time model (in physical coordinates where the method
        gives them).
    continuous_model : StateSpace or None
        The continuous-time model (eq. (8)) where it exists.
    parameters : mapping of str -> float
        Named estimates (e.g. ``v1..v9``, ``R1``, ``a1``), in a stable order.
    covariance : ndarray or None
        Covariance of ``parameters`` in that order; ``None`` when the method
        has none (never zeros).
    n_samples : int
        Number of samples (control periods) used.
    options : mapping
        Every option the method used, defaults included.
    residuals : ndarray or None
        One-step prediction errors, time first.
    fit : mapping of str -> float
        Fit diagnostics, e.g. ``one_step_fit_percent`` (never an open-loop
        simulation fit for an unstable model).
    singular_values : ndarray or None
        Singular values used for order selection.
    notes : tuple of str
        Anything assumed, changed or found marginal.
    extras : mapping
        Method-specific intermediate results (ARX coefficients, observer gain, ...).
    """

    method: str
    model: StateSpace | None
    parameters: Mapping[str, float]
    covariance: np.ndarray | None = None
    n_samples: int = 0
    options: Mapping[str, Any] = field(default_factory=dict)
    residuals: np.ndarray | None = None
    fit: Mapping[str, float] = field(default_factory=dict)
    singular_values: np.ndarray | None = None
    notes: tuple[str, ...] = ()
    continuous_model: StateSpace | None = None
    extras: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        params = {str(k): float(v) for k, v in dict(self.parameters).items()}
        object.__setattr__(self, "parameters", MappingProxyType(params))
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            if cov.shape != (len(params), len(params)):
                raise ValueError(
                    f"covariance has shape {cov.shape}; expected {(len(params), len(params))}"
                )
            cov.setflags(write=False)
            object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "options", MappingProxyType(dict(self.options)))
        object.__setattr__(
            self, "fit", MappingProxyType({k: float(v) for k, v in dict(self.fit).items()})
        )
        object.__setattr__(self, "extras", MappingProxyType(dict(self.extras)))
        object.__setattr__(self, "notes", tuple(self.notes))

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled as its fields, the read-only mappings as plain ones (a mappingproxy does
        not pickle): for worker processes and users' own pools."""
        return (
            IdentificationResult,
            (self.method, self.model, unfreeze(self.parameters), self.covariance,
             self.n_samples, unfreeze(self.options), self.residuals, unfreeze(self.fit),
             self.singular_values, self.notes, self.continuous_model,
             unfreeze(self.extras)),
        )  # fmt: skip

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(self.parameters)

    def std_errors(self) -> dict[str, float]:
        """Standard error of each parameter (NaN for all when there is no covariance)."""
        if self.covariance is None:
            return {k: float("nan") for k in self.parameters}
        se = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return dict(zip(self.parameters, se.tolist()))

    def confidence_intervals(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Two-sided normal-approximation intervals at ``level``."""
        z = float(special.ndtri(0.5 + level / 2))
        se = self.std_errors()
        return {k: (v - z * se[k], v + z * se[k]) for k, v in self.parameters.items()}

    def summary(self) -> str:
        """Plain-text table of the estimates with standard errors."""
        se = self.std_errors()
        lines = [
            f"maglevid identification: method={self.method}, N={self.n_samples}",
            f"{'parameter':>12} {'estimate':>14} {'std. error':>12}",
        ]
        for k, v in self.parameters.items():
            lines.append(f"{k:>12} {v:>14.6g} {se[k]:>12.3g}")
        for k, v in self.fit.items():
            lines.append(f"fit {k}: {v:.6g}")
        lines.extend(f"note: {n}" for n in self.notes)
        return "\n".join(lines)

    def _table_rows(
        self, level: float = 0.95
    ) -> list[tuple[str, float, float, float, float, str]]:
        se = self.std_errors()
        ci = self.confidence_intervals(level)
        return [
            (k, v, se[k], ci[k][0], ci[k][1], parameter_unit(k) or "")
            for k, v in self.parameters.items()
        ]

    def __repr__(self) -> str:
        return (
            f"<IdentificationResult method={self.method!r} N={self.n_samples} "
            f"parameters={len(self.parameters)} notes={len(self.notes)}>"
        )

    def _repr_html_(self) -> str:
        rows = [
            (k, number(v, 6), unit, number(e, 3), f"{number(lo)} … {number(hi)}")
            for k, v, e, lo, hi, unit in self._table_rows()
        ]
        titles = [PARAMETER_INFO.get(r[0], ("",))[0] for r in rows]
        table = html_table(
            ("parameter", "estimate", "unit", "std. error", "95 % interval"), rows, titles=titles
        )
        fit = "; ".join(f"{html.escape(k)} = {v:.4g}" for k, v in self.fit.items())
        notes = "".join(f"<li>{html.escape(n)}</li>" for n in self.notes)
        return (
            f"<div><b>maglevid identification</b>: {html.escape(self.method)}, "
            f"N = {self.n_samples}{table}"
            + (f"<p>fit: {fit}</p>" if fit else "")
            + (f"<ul>{notes}</ul>" if notes else "")
            + "</div>"
        )

    def resid(self, data: Any, **options: Any) -> Any:
        """Residual analysis on ``data``; see :func:`maglevid.identify.validation.resid`."""
        from maglevid.identify.validation import resid

        return resid(self, data, **options)

    def compare(self, data: Any, **options: Any) -> Any:
        """k-step and simulation fit; see :func:`maglevid.identify.validation.compare`."""
        from maglevid.identify.validation import compare

        return compare(self, data, **options)

    def to_dataframe(self, level: float = 0.95) -> Any:
        """The estimates as a ``pandas.DataFrame`` indexed by parameter name.

        Columns: ``estimate``, ``std_error``, ``ci_low``, ``ci_high`` (the
        two-sided ``level`` interval, normal approximation) and ``unit`` (SI,
        ``None`` where maglevid does not know the parameter).
        """
        import pandas as pd

        rows = self._table_rows(level)
        return pd.DataFrame(
            {
                "estimate": [r[1] for r in rows],
                "std_error": [r[2] for r in rows],
                "ci_low": [r[3] for r in rows],
                "ci_high": [r[4] for r in rows],
                "unit": [r[5] or None for r in rows],
            },
            index=pd.Index([r[0] for r in rows], name="parameter"),
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe, versioned dictionary: strict JSON (``json.dumps(..., allow_nan=False)``
        writes it), NaN as ``None`` and +-inf as ``"inf"``/``"-inf"`` (:func:`to_jsonable`;
        :meth:`from_dict` reads them back as numbers)."""
        return {
            "format": "maglevid-identification",
            "version": RESULT_VERSION,
            "method": self.method,
            "n_samples": self.n_samples,
            "options": to_jsonable(self.options),
            "parameters": to_jsonable(dict(self.parameters)),
            "std_errors": to_jsonable(self.std_errors()),
            "ci95": to_jsonable({k: list(v) for k, v in self.confidence_intervals(0.95).items()}),
            "covariance": None if self.covariance is None else to_jsonable(self.covariance),
            "model": None if self.model is None else self.model.to_dict(),
            "continuous_model": None
            if self.continuous_model is None
            else self.continuous_model.to_dict(),
            "poles": None if self.model is None else to_jsonable(self.model.poles()),
            "fit": to_jsonable(dict(self.fit)),
            "singular_values": None
            if self.singular_values is None
            else to_jsonable(np.asarray(self.singular_values)),
            "notes": list(self.notes),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> IdentificationResult:
        """Rebuild a result from :meth:`to_dict` (residuals and extras are not stored).

        ``IdentificationResult.from_dict(r.to_dict()).to_dict() == r.to_dict()``.

        Raises
        ------
        DataError
            Not a maglevid identification dictionary, or a newer version.
        """
        if not isinstance(d, Mapping) or d.get("format") != "maglevid-identification":
            raise DataError(
                "not a maglevid identification result (format 'maglevid-identification')"
            )
        if int(d.get("version", 0)) > RESULT_VERSION:
            raise DataError(
                f"identification result version {d.get('version')} is newer than this "
                f"maglevid reads ({RESULT_VERSION}); upgrade maglevid"
            )

        def model(key: str) -> StateSpace | None:
            return None if d.get(key) is None else StateSpace.from_dict(d[key])

        params = {k: _number(v) for k, v in d["parameters"].items()}
        sv = d.get("singular_values")
        return cls(
            method=d["method"],
            model=model("model"),
            parameters=params,
            covariance=None if d.get("covariance") is None else np.asarray(d["covariance"], float),
            n_samples=int(d.get("n_samples", 0)),
            options=dict(d.get("options") or {}),
            fit={k: _number(v) for k, v in (d.get("fit") or {}).items()},
            singular_values=None if sv is None else np.asarray(sv, dtype=float),
            notes=tuple(d.get("notes") or ()),
            continuous_model=model("continuous_model"),
        )


def _number(v: Any) -> Any:
    """A number written by :func:`to_jsonable` read back: ``None`` NaN, ``"inf"``/``"-inf"``
    infinite; anything else as it is."""
    if v is None:
        return float("nan")
    if isinstance(v, str) and v in ("inf", "-inf"):
        return float(v)
    return v


def propagate_covariance(
    f: Callable[[np.ndarray], np.ndarray],
    theta: np.ndarray,
    cov: np.ndarray,
    *,
    rel_step: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """Delta method: value and covariance of ``f(theta)`` given ``cov(theta)``.

    The Jacobian is :func:`central_jacobian`'s, with steps scaled to each
    parameter (``rel_step * max(|theta_i|, sqrt(cov_ii), tiny)``).
    """
    f0, J = central_jacobian(f, theta, cov, rel_step=rel_step)
    return f0, J @ cov @ J.T


def central_jacobian(
    f: Callable[[np.ndarray], np.ndarray],
    theta: np.ndarray,
    cov: np.ndarray | None = None,
    *,
    rel_step: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """``(f(theta), d f / d theta)`` by central differences.

    Step ``rel_step * max(|theta_i|, sqrt(cov_ii), tiny)`` per parameter
    (without ``cov``: ``rel_step * |theta_i|``, tiny where it is zero).
    """
    theta = np.asarray(theta, dtype=float)
    f0 = np.asarray(f(theta), dtype=float)
    J = np.empty((f0.size, theta.size))
    sd = np.zeros(theta.size) if cov is None else np.sqrt(np.clip(np.diag(cov), 0.0, None))
    for i in range(theta.size):
        h = rel_step * max(abs(theta[i]), sd[i], 1e-300)
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        J[:, i] = (np.asarray(f(tp), dtype=float) - np.asarray(f(tm), dtype=float)).ravel() / (
            2 * h
        )
    return f0, J
