"""The extension's parameter covariance and draws from it, for Monte Carlo bands on replays."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from diagnose.result import Diagnosis
from diagnose.stepwise import StepwiseResult

#: Part 60's gear-change tolerances (2.c.4) the replays are judged against: airspeed [kt],
#: altitude [ft], pitch [deg] (or 20 % of the measured pitch change, the larger).
TOLERANCES = {"tas_kt": 3.0, "alt_ft": 100.0, "theta_deg": 1.5}


def beta_covariance(res: StepwiseResult, data: pd.DataFrame) -> np.ndarray:
    """Covariance of a coefficient's stepwise fit (intercept and every term's columns).

    ``rss / (n_eff - p) (X'X)^-1``: the residual variance counted over the effective number of
    independent samples (the residuals are autocorrelated), as the stepwise F-tests count it.
    """
    x = np.column_stack([np.ones(len(data))] + [t.design(data) for t in res.terms])
    r = data[f"r_{res.coefficient}"].to_numpy() - x @ res.beta
    dof = max(res.n_eff - x.shape[1], 1.0)
    return float(r @ r) / dof * np.linalg.pinv(x.T @ x)


def draws(diag: Diagnosis, n: int, seed: int = 0) -> list[Diagnosis]:
    """``n`` diagnoses whose fitted terms are drawn from their estimates' covariance (each
    coefficient's on its own; coefficients without terms unchanged)."""
    rng = np.random.default_rng(seed)
    covs = {c: beta_covariance(r, diag.data) for c, r in diag.results.items() if r.terms}
    out = []
    for _ in range(n):
        results = {
            c: replace(r, beta=rng.multivariate_normal(r.beta, covs[c], method="eigh")) if c in covs else r
            for c, r in diag.results.items()
        }
        out.append(replace(diag, results=results))
    return out


def tolerance(channel: str, measured: np.ndarray) -> float:
    """The Part 60 tolerance of a channel about the measured time history."""
    tol = TOLERANCES[channel]
    finite = measured[np.isfinite(measured)]
    if channel == "theta_deg" and finite.size:
        tol = max(tol, 0.2 * float(np.max(np.abs(finite - finite[0]))))
    return tol


def band(flown: np.ndarray, lo_pct: float = 2.5, hi_pct: float = 97.5) -> tuple[np.ndarray, np.ndarray]:
    """The band of replayed time histories (draws, samples): the percentiles at each sample."""
    return np.nanpercentile(flown, lo_pct, axis=0), np.nanpercentile(flown, hi_pct, axis=0)


def pass_probability(flown: dict[str, np.ndarray], measured: dict[str, np.ndarray]) -> float:
    """The share of draws whose replay stays within every Part 60 tolerance of the measurement.

    A draw that does not cover every measured sample (it did not trim, ended early or went
    non-finite) fails.

    Parameters
    ----------
    flown : dict
        Channel -> (draws, samples) replayed on the log's times.
    measured : dict
        Channel -> (samples,).
    """
    ok = None
    for ch in TOLERANCES:
        err = np.abs(flown[ch] - measured[ch])[:, np.isfinite(measured[ch])]
        inside = np.isfinite(err).all(axis=1) & (
            np.nan_to_num(err, nan=np.inf).max(axis=1, initial=0.0) <= tolerance(ch, measured[ch])
        )
        ok = inside if ok is None else ok & inside
    return float(np.mean(ok))
