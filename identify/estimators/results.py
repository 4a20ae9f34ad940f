"""What an output-error or filter-error fit returns: the statsmodels shape."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd


@dataclass
class TimeDomainResults:
    """Maximum-likelihood estimates from time histories.

    Attributes
    ----------
    method : str
        ``"oe"`` (output error) or ``"fe"`` (filter error).
    params : Series
        The estimated parameters, by name: the model's, then initial states
        (``x0[<record>].<state>``), output biases (``bias[<record>].<output>``) and, for the
        filter error, the process-noise standard deviations (``F.<state>``).
    bse : Series
        Cramér-Rao bounds: the square roots of the diagonal of the inverse information matrix.
    bse_coloured : Series
        The bounds corrected for coloured residuals (Morelli & Klein 2016, sec. 6.3): what a
        repeated flight would scatter by when the residuals are not white.
    R : Series
        Diagonal of the residual (output error) or innovation (filter error) covariance, by output.
    cost : float
        ``det(R)``, the cost function at the estimates.
    history : list of float
        ``det(R)`` at each accepted iteration.
    converged : bool
        True when the relative change of ``det(R)`` fell below the tolerance.
    fitted, residuals : list of ndarray
        Per record, shape (N, ny): the model's outputs (predicted, for the filter error) and
        the measured minus those.
    """

    method: str
    params: pd.Series
    bse: pd.Series
    bse_coloured: pd.Series
    R: pd.Series
    cost: float
    history: list[float]
    converged: bool
    iterations: int
    fitted: list[np.ndarray] = field(repr=False, default_factory=list)
    residuals: list[np.ndarray] = field(repr=False, default_factory=list)
    cov: np.ndarray = field(repr=False, default=None)
    cov_coloured: np.ndarray = field(repr=False, default=None)
    #: why the fit did not converge ("" when it did)
    reason: str = ""

    @property
    def nobs(self) -> int:
        return int(sum(len(r) for r in self.residuals))

    def conf_int(self, n_sigma: float = 2.0, coloured: bool = True) -> pd.DataFrame:
        se = self.bse_coloured if coloured else self.bse
        return pd.DataFrame({"lower": self.params - n_sigma * se, "upper": self.params + n_sigma * se})

    def corr(self) -> pd.DataFrame:
        """Correlation of the estimates (from the Cramér-Rao covariance)."""
        d = np.sqrt(np.diag(self.cov))
        return pd.DataFrame(self.cov / np.outer(d, d), index=self.params.index, columns=self.params.index)

    def to_dict(self) -> dict:
        return {
            "method": self.method,
            "params": {k: float(v) for k, v in self.params.items()},
            "se": {k: float(v) for k, v in self.bse.items()},
            "se_coloured": {k: float(v) for k, v in self.bse_coloured.items()},
            "R": {k: float(v) for k, v in self.R.items()},
            "cost": self.cost,
            "iterations": self.iterations,
            "converged": self.converged,
            **({"reason": self.reason} if self.reason else {}),
            "nobs": self.nobs,
        }

    def summary(self) -> str:
        name = {"oe": "Output error", "fe": "Filter error"}.get(self.method, self.method)
        lines = [
            f"{name}: N = {self.nobs}, det(R) = {self.cost:.4g}, {self.iterations} iterations, "
            f"{'converged' if self.converged else 'NOT converged: ' + self.reason}",
            f"  {'parameter':<24}{'estimate':>14}{'CR bound':>12}{'coloured':>12}{'rel %':>8}",
        ]
        for k in self.params.index:
            v, se, sc = self.params[k], self.bse[k], self.bse_coloured[k]
            rel = 100 * sc / abs(v) if v != 0 else np.inf
            lines.append(f"  {k:<24}{v:>14.6g}{se:>12.3g}{sc:>12.3g}{rel:>8.1f}")
        lines.append("  residual standard deviations: " + ", ".join(f"{k} {np.sqrt(v):.3g}" for k, v in self.R.items()))
        return "\n".join(lines)
