"""The verdict on each candidate cause: significant, beyond what instrument noise and errors make,
better on data it was not fitted on."""
from __future__ import annotations

import numpy as np
import pandas as pd

from diagnose.causes import Cause
from diagnose.noise_floor import REACH_SE, RESOLUTION, design_matrix
from diagnose.stepwise import StepwiseResult
from identify.lsq import solve_normal
#: Fresh noise on logs that already hold noise doubles the regressors' noise, which can halve the
#: errors-in-variables effect the floor simulates (sigma^2/(V+sigma^2) <= 2 sigma^2/(V+2 sigma^2)):
#: a cause on a noisy variable must clear twice the largest simulated size.
FLOOR_FACTOR = 2.0
#: A cause must make residuals this much smaller (RMS ratio) on data it was not fitted on, where it acts.
MIN_HOLDOUT_GAIN = 1.02
#: A log "sees" a cause where its contribution departs this share of its size from its typical value.
ACTING_SHARE = 0.2


def contribution(res: StepwiseResult, cause: Cause, data: pd.DataFrame) -> np.ndarray:
    """A cause's fitted contribution at the rows of ``data``."""
    return sum((t.design(data) @ res.term_beta(t) for t in res.terms if t in cause.terms), np.zeros(len(data)))


def holdout_gain(res: StepwiseResult, cause: Cause, data: pd.DataFrame) -> tuple[float, list[int], dict]:
    """Leave-one-condition-out check of one cause on every condition flown.

    For each flight condition, the coefficient's selected terms are fitted on
    the others and predict it; the gain is the residual RMS without the cause's
    part of that prediction over the RMS with it, over the logs where the cause
    acts: pooled, and per condition.

    Parameters
    ----------
    res : StepwiseResult
        The coefficient's stepwise fit (its terms).
    cause : Cause
    data : DataFrame
        Residual data of every log, train and held out, with ``condition`` and ``log`` columns.

    Returns
    -------
    gain : float
        Pooled; NaN if no log sees the cause, or it was flown at a single condition.
    acting : list of int
        The logs (``log`` values) where it acts.
    by_condition : dict
        Condition -> gain over its logs where the cause acts.
    """
    y = data[f"r_{cause.coefficient}"].to_numpy()
    own = [t for t in res.terms if t in cause.terms]
    rest = [t for t in res.terms if t not in cause.terms]
    full = contribution(res, cause, data)
    typical = float(np.median(full))
    frame = pd.DataFrame({"log": data["log"].to_numpy(), "dev": np.abs(full - typical)})
    acting = [int(i) for i, g in frame.groupby("log") if g["dev"].max() >= ACTING_SHARE * max(cause.size, 1e-300)]
    code, names = pd.factorize(data["condition"], sort=True)  # hashed: sorting the strings took a third
    if not acting or len(names) < 2:
        return float("nan"), acting, {}
    x_own = np.column_stack([t.design(data) for t in own])
    x_rest = design_matrix(rest, data)
    x = np.hstack([x_rest, x_own])
    scale = np.sqrt(np.einsum("ij,ij->j", x, x))
    scale[scale == 0] = 1.0
    xs = x / scale
    gram, xty = xs.T @ xs, xs.T @ y
    before = np.zeros(len(y))
    after = np.zeros(len(y))
    order = np.argsort(code, kind="stable")  # rows by condition: one sort, no string compares
    rows = np.split(order, np.flatnonzero(np.diff(code[order])) + 1)
    for out in rows:
        xo = xs[out]
        beta = solve_normal(gram - xo.T @ xo, xty - xo.T @ y[out]) / scale  # fitted without this condition
        base = y[out] - x_rest[out] @ beta[:x_rest.shape[1]]
        before[out] = base
        after[out] = base - x_own[out] @ beta[x_rest.shape[1]:]
    sel = np.isin(data["log"].to_numpy(), acting)

    def ratio(m: np.ndarray) -> float:
        ss = float(after[m] @ after[m])
        return float(np.sqrt(before[m] @ before[m] / ss)) if ss > 0 else float("inf")

    by = {str(names[code[out[0]]]): ratio(out[sel[out]]) for out in rows if sel[out].any()}
    return ratio(sel), acting, dict(sorted(by.items()))


def judge(causes: list[Cause], results: dict[str, StepwiseResult], data_all: pd.DataFrame,
          floors: list[np.ndarray], noisy: list[bool], reach: list[dict] | None = None,
          alpha_in: float = 1e-6) -> None:
    """Fill each cause's verdict: significant, beyond what noise and instrument errors make,
    better on held-out data.

    ``floors`` holds each cause's sizes fitted to noise alone; ``noisy`` whether any of
    its variables carries noise (then errors-in-variables may be underestimated by the
    simulation, up to a factor :data:`FLOOR_FACTOR`); ``reach`` what the instrument
    errors the data compatibility may have left can make of its shape
    (:meth:`diagnose.noise_floor.NoiseFloor.reach`). The part of the cause no plausible
    instrument error makes must be larger than the noise floor.
    """
    reach = reach or [{"made": 0.0, "left": c.size, "alternatives": []} for c in causes]
    for cause, null, eiv, rc in zip(causes, floors, noisy, reach):
        floor = max((FLOOR_FACTOR if eiv else 1.0) * float(np.max(null)) if len(null) else 0.0, RESOLUTION)
        beyond = min(cause.size, rc["left"])
        gain, acting, by_condition = holdout_gain(results[cause.coefficient], cause, data_all)
        worst = min(by_condition.values(), default=float("nan"))
        reasons = []
        if not cause.evidence["p_value"] < alpha_in:
            reasons.append(f"not significant (p = {cause.evidence['p_value']:.2g}, needs < {alpha_in:g})")
        if not cause.size > floor:
            reasons.append(f"no larger than instrument noise makes it (size {cause.size:.3g}, noise floor "
                           f"{floor:.3g})")
        elif not beyond > floor:
            reasons.append(f"instrument errors within {REACH_SE:g} standard errors of the data compatibility "
                           f"make all but {beyond:.3g} of it (size {cause.size:.3g}, noise floor {floor:.3g})")
        if not gain >= MIN_HOLDOUT_GAIN:
            reasons.append("no held-out data where it acts" if not np.isfinite(gain) else
                           f"does not improve held-out data (gain x{gain:.3f}, needs x{MIN_HOLDOUT_GAIN})")
        elif not worst >= MIN_HOLDOUT_GAIN:
            c_worst = min(by_condition, key=by_condition.get)
            reasons.append(f"does not improve every condition it acts on when that condition is left out "
                           f"(x{worst:.3f} at {c_worst}, needs x{MIN_HOLDOUT_GAIN})")
        alts = [a for a in rc["alternatives"] if a["explains_pct"] >= SENSOR_ALTERNATIVE_PCT
                and abs(a["needs_se"]) <= SENSOR_ALTERNATIVE_SE
                and (not a.get("unmeasured") or abs(a["needs"]) <= UNMEASURED_PLAUSIBLE[a["error"]])][:3]
        if alts:
            cause.evidence["sensor_alternatives"] = alts
        cause.verdict = {"accepted": not reasons, "reason": "; ".join(reasons), "noise_floor": floor,
                         "instrument_errors_make": rc["made"], "beyond_instrument_errors": beyond,
                         "noise_sizes": [float(v) for v in null], "holdout_gain": gain,
                         "holdout_gain_by_condition": by_condition,
                         "holdout_logs": acting, "size_over_floor": beyond / floor}


#: An instrument error that alone explains this share of a cause's variance is named beside it [%].
SENSOR_ALTERNATIVE_PCT = 50.0
#: ... if the size it needs is within this many of the data compatibility's standard errors
#: (or, for an error the compatibility could not measure, within these sizes: delay [s], scale [-]).
SENSOR_ALTERNATIVE_SE = 5.0
UNMEASURED_PLAUSIBLE = {"delay": 0.2, "scale": 0.1, "bias": 1.0}
