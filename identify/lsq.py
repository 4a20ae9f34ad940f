"""Ordinary least squares (paper eqs. 10-18) with what an engineer reads first.

``LeastSquares(y, X).fit()`` returns :class:`LSResults` with ``params``, ``bse``
(standard errors), ``rsquared``, residual max and RMS, ``summary()`` -- the
statsmodels shape. Regressors that were not excited are dropped from the fit
and reported as not identifiable. Flight data residuals are coloured, so the
standard errors are estimated for coloured residuals rather than by the white-noise
formula, which would understate them: they follow Morelli & Klein (Aircraft
System Identification, 2016, sec. 5.2) -- the residual autocorrelation
weighted by the regressors' cross-products.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
from scipy.signal import lfilter


@dataclass
class LSResults:
    """Results of a least-squares fit.

    Attributes
    ----------
    params, bse : Series
        Estimates and standard errors of the identifiable parameters.
    unexcited : dict
        ``{regressor: reason}`` for regressors left out as not identifiable.
    rsquared : float
    resid : ndarray
    fitted : ndarray
    y : ndarray
        Per sample; None once :meth:`slim` has dropped them.
    """

    name: str
    params: pd.Series
    bse: pd.Series
    unexcited: dict
    rsquared: float
    resid: np.ndarray
    fitted: np.ndarray
    y: np.ndarray
    cov: np.ndarray = field(repr=False, default=None)
    kept: tuple | None = field(repr=False, default=None)  # (nobs, resid_max, resid_rms, rel_error_pct) once slim
    bse_white: pd.Series | None = None  # the white-residual formula (equation error) or Cramér-Rao bound
    method: str = "ee"  # "ee" equation error, "oe" output error, "fe" filter error
    converged: bool = True

    @property
    def nobs(self) -> int:
        return self.kept[0] if self.y is None else len(self.y)

    @property
    def resid_max(self) -> float:
        """Largest absolute residual."""
        return self.kept[1] if self.resid is None else float(np.max(np.abs(self.resid)))

    @property
    def resid_rms(self) -> float:
        return self.kept[2] if self.resid is None else float(np.sqrt(np.mean(self.resid**2)))

    @property
    def rel_error_pct(self) -> float:
        """Largest absolute residual relative to the range of the measurement [%]."""
        return self.kept[3] if self.y is None else 100.0 * self.resid_max / max(float(np.ptp(self.y)), 1e-12)

    def slim(self) -> "LSResults":
        """The same results without the per-sample arrays (measured, fitted, residual), their
        statistics kept: what a campaign of thousands of points holds of each fit."""
        return replace(
            self, resid=None, fitted=None, y=None, kept=(self.nobs, self.resid_max, self.resid_rms, self.rel_error_pct)
        )

    def conf_int(self, n_sigma: float = 2.0) -> pd.DataFrame:
        return pd.DataFrame({"lower": self.params - n_sigma * self.bse, "upper": self.params + n_sigma * self.bse})

    def to_dict(self) -> dict:
        return {
            "params": {k: float(v) for k, v in self.params.items()},
            "bse": {k: float(v) for k, v in self.bse.items()},
            "se": {k: float(v) for k, v in (self.bse if self.bse_white is None else self.bse_white).items()},
            "se_coloured": {k: float(v) for k, v in self.bse.items()},
            "method": self.method,
            "converged": self.converged,
            "rsquared": self.rsquared,
            "resid_max": self.resid_max,
            "resid_rms": self.resid_rms,
            "rel_error_pct": self.rel_error_pct,
            "nobs": self.nobs,
            "unexcited": dict(self.unexcited),
        }

    def summary(self) -> str:
        by = "" if self.method == "ee" else f" ({self.method})"
        lines = [
            f"{self.name}{by}: N = {self.nobs}, R^2 = {self.rsquared:.6f}, "
            f"residual max {self.resid_max:.3g}, RMS {self.resid_rms:.3g}, "
            f"relative {self.rel_error_pct:.2f} %",
            f"  {'parameter':<20}{'estimate':>14}{'std err':>12}{'t':>10}",
        ]
        for k in self.params.index:
            t = self.params[k] / self.bse[k] if self.bse[k] > 0 else np.inf
            lines.append(f"  {k:<20}{self.params[k]:>14.6g}{self.bse[k]:>12.3g}{t:>10.1f}")
        for k, why in self.unexcited.items():
            lines.append(f"  {k:<20}{'not identifiable':>14}  ({why})")
        return "\n".join(lines)


def lagged_gram(x: np.ndarray, e: np.ndarray, lags: int) -> np.ndarray:
    """``sum_ij x_i R(i-j) x_j'`` with ``R`` the autocorrelation of ``e``, summed up to its
    first zero crossing (at most ``lags``): the middle of a covariance for coloured residuals.

    Parameters
    ----------
    x : ndarray, shape (N, p)
        Regressors, or the output sensitivities of one output.
    e : ndarray, shape (N,)
        Residuals.
    lags : int
        Largest lag [samples].
    """
    n = len(e)
    lags = min(lags, n - 1)
    r = np.array([e[k:] @ e[: n - k] / n for k in range(lags + 1)])
    crossing = np.flatnonzero(r <= 0.0)
    last = int(crossing[0]) - 1 if crossing.size else lags
    # sum_k r_k (G_k + G_k'), G_k = sum_i x_(i+k) x_i', is Z'X + X'Z with Z_i = sum_k r_k x_(i+k):
    # the lags as one FIR filter over the reversed regressors instead of a product per lag
    z = lfilter(np.concatenate([[0.0], r[1 : last + 1]]), [1.0], x[::-1], axis=0)[::-1]
    return r[0] * (x.T @ x) + z.T @ x + x.T @ z


def colored_residual_cov(x: np.ndarray, e: np.ndarray, lags: int) -> np.ndarray:
    """Covariance of least-squares estimates for coloured residuals.

    ``(X'X)^-1 [sum_ij x_i R(i-j) x_j'] (X'X)^-1`` with ``R`` the residual
    autocorrelation (Morelli & Klein 2016, eq. 5.71), summed up to its first
    zero crossing (at most ``lags``): beyond it the estimate of ``R`` from
    least-squares residuals is dominated by their enforced orthogonality to X.

    Parameters
    ----------
    x : ndarray, shape (N, p)
    e : ndarray, shape (N,)
        Residuals.
    lags : int
        Largest lag of the autocorrelation [samples].
    """
    m = lagged_gram(x, e, lags)
    xtx_inv = np.linalg.inv(x.T @ x)
    cov = xtx_inv @ m @ xtx_inv
    return cov


class LeastSquares:
    """``y = X theta + v`` solved by least squares (eq. 18).

    Parameters
    ----------
    y : array_like, shape (N,)
    X : DataFrame, shape (N, p)
        Regressors by name; a column ``const`` of ones is the intercept.
    min_std : dict, optional
        ``{regressor: std}``: a regressor varying less than this was not
        excited and is left out.
    hac_lags : int
        Largest residual autocorrelation lag used for the standard errors [samples].
    name : str
    """

    def __init__(self, y, X: pd.DataFrame, min_std: dict | None = None, hac_lags: int = 240, name: str = "y") -> None:
        self.y = np.asarray(y, dtype=float)
        self.X = X
        self.min_std = min_std or {}
        self.hac_lags = hac_lags
        self.name = name

    def fit(self) -> LSResults:
        unexcited = {}
        keep = []
        columns = dict(zip(self.X.columns, self.X.to_numpy(dtype=float).T))  # one copy, not a Series per use
        for col, values in columns.items():
            if col == "const":
                keep.append(col)
                continue
            sd = float(np.std(values))
            if sd < self.min_std.get(col, 0.0) or sd == 0.0:
                unexcited[col] = f"std {sd:.2g} below {self.min_std.get(col, 0.0):.2g}"
                continue
            for other in keep:
                if other == "const":
                    continue
                r = np.corrcoef(values, columns[other])[0, 1]
                if abs(r) > 0.98:
                    unexcited[col] = f"collinear with {other} (r = {r:.3f})"
                    break
            else:
                keep.append(col)
        x = self.X[keep].to_numpy(dtype=float)
        theta, *_ = np.linalg.lstsq(x, self.y, rcond=None)
        fitted = x @ theta
        resid = self.y - fitted
        cov = colored_residual_cov(x, resid, self.hac_lags)
        white = float(resid @ resid) / max(len(resid) - x.shape[1], 1) * np.linalg.inv(x.T @ x)
        ss_tot = float(np.sum((self.y - self.y.mean()) ** 2))
        r2 = 1.0 - float(np.sum(resid**2)) / ss_tot if ss_tot > 0 else float("nan")
        return LSResults(
            self.name,
            pd.Series(theta, index=keep),
            pd.Series(np.sqrt(np.diag(cov)), index=keep),
            unexcited,
            r2,
            resid,
            fitted,
            self.y,
            cov,
            bse_white=pd.Series(np.sqrt(np.diag(white)), index=keep),
        )


def solve_normal(gram: np.ndarray, xty: np.ndarray) -> np.ndarray:
    """Least-squares coefficients from the normal equations of unit-norm columns, directions
    below 1e-12 of the largest eigenvalue dropped (as a rank-revealing solver would)."""
    w, v = np.linalg.eigh(gram)
    keep = w > 1e-12 * w[-1]
    return v[:, keep] @ ((v[:, keep].T @ xty) / w[keep])
