"""What the held-out logs leave beside what the fitted logs leave: a discrepancy the causes named do not carry.

The verdict confirms each cause on its conditions left out in turn, the held-out ones among them, but only
where the cause departs from the model: where no named cause does, what the held-out logs hold is never
looked at. They can hold what the fitted logs cannot show: an effect that the fitted conditions fly as a
function of another variable (an A320 drag step in the elevator, on at Mach 0.5
and off at Mach 0.3 and 0.4 over the fitted logs, named "CD vs mach" while the held-out Mach 0.4 logs,
flown where the step is on, kept all of it), or one that acts at the held-out condition alone. Each
coefficient's residual, less what the fit predicts there, is compared log by log with the most any fitted
log leaves (``held_out_ratio`` of :class:`diagnose.config.DiagnosisSettings`). It decides nothing: the
report says where the held-out data disagree.
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from diagnose.config import current
from diagnose.stepwise import StepwiseResult


def left_per_log(frame: pd.DataFrame, res: StepwiseResult) -> pd.Series:
    """RMS [-] of ``res``'s coefficient residual less the fit's prediction (its offset included), per ``log``."""
    # StepwiseResult.predict keeps the offset where Diagnosis.predict, for a coefficient with no term, gives 0
    left = frame[f"r_{res.coefficient}"].to_numpy() - res.predict(frame)
    return pd.Series(left**2).groupby(frame["log"].to_numpy()).mean() ** 0.5


def held_out_check(
    data: pd.DataFrame,
    held: pd.DataFrame | None,
    results: dict[str, StepwiseResult],
    fitted_names: list[str],
    held_names: list[str],
    ratio: float | None = None,
) -> dict:
    """Per coefficient: the residual RMS each held-out log leaves once the fit's prediction is taken off,
    against the most any fitted log leaves.

    Parameters
    ----------
    data, held : DataFrame
        Residual data of the fitted and of the held-out logs (``log``: an index into ``fitted_names``, into
        ``held_names``); ``held`` None or empty: nothing to check.
    results : dict
        Coefficient -> the stepwise fit of the causes named (:class:`diagnose.stepwise.StepwiseResult`).
    fitted_names, held_names : list of str
        The files of the fitted and of the held-out logs.
    ratio : float, optional
        The ratio that tells (None: the settings' ``held_out_ratio``, :func:`diagnose.config.current`).

    Returns
    -------
    dict
        Coefficient -> ``fitted_worst_rms`` [-] and its log ``fitted_worst_log``, ``held_out_rms`` (held-out log
        file -> RMS [-]), ``ratio`` (the largest held-out RMS over ``fitted_worst_rms``) and its log
        ``worst_log``, and ``told`` (``ratio`` of the ``ratio`` given or more). Empty without held-out data.
    """
    if held is None or not len(held):
        return {}
    told = current().held_out_ratio if ratio is None else ratio
    out = {}
    for c, res in results.items():
        fit, out_ = left_per_log(data, res), left_per_log(held, res)
        worst = int(out_.idxmax())
        worse = float(out_.max() / fit.max()) if fit.max() > 0 else float("inf")
        out[c] = {
            "fitted_worst_rms": float(fit.max()),
            "fitted_worst_log": Path(fitted_names[int(fit.idxmax())]).name,
            "held_out_rms": {Path(held_names[int(i)]).name: float(v) for i, v in out_.items()},
            "ratio": worse,
            "worst_log": Path(held_names[worst]).name,
            "told": bool(worse >= told),
        }
    return out


def told_text(check: dict) -> list[str]:
    """One sentence per coefficient :func:`held_out_check` tells of (none if it tells of none)."""
    return [
        f"the held-out data disagree in {c}: {v['worst_log']} leaves a residual RMS of {v['held_out_rms'][v['worst_log']]:.3g} "
        f"once the fit is taken off, {v['ratio']:.1f} times the most a fitted log leaves ({v['fitted_worst_rms']:.3g}, "
        f"{v['fitted_worst_log']}): a discrepancy the causes named do not carry acts there (the fitted conditions may "
        f"fly it as a function of another variable, or it acts at the held-out condition alone)"
        for c, v in check.items()
        if v["told"]
    ]


def as_extension_reads(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with its variables as a JSBSim extension reads them where the model is evaluated at measured
    states: the lift coefficient from ``aero/cl-squared``, which the evaluation sets from the measured lift
    (:class:`diagnose.evaluate.ModelEvaluator`) where the regressor ``CL`` is the model's. The same frame if it
    has no measured lift."""
    if "meas_CL" not in frame or "CL" not in frame:
        return frame
    out = frame.copy()
    out["CL"] = frame["meas_CL"]
    return out


def held_out_gain(cause, res: StepwiseResult, data: pd.DataFrame, held: pd.DataFrame) -> float:
    """The held-out logs' residual RMS of the cause's coefficient against the model extended without the
    cause's terms (the coefficient's other terms refitted on ``data``; the model alone if it has none) over
    the RMS against the model extended with them [-]: below 1, the cause makes the held-out data worse.

    The smaller of two readings: the terms at the model's lift coefficient (the regressor), and as the
    extension reads them at the held-out logs' measured states (:func:`as_extension_reads`). They part where
    the model's lift is off and a term in CL is steep at fixed alpha: an ATTAS pitching-moment term in alpha x CL,
    fitted on aileron and rudder records, gained x4.4 on the held-out record at the model's lift and lost
    (x0.79) as its JSBSim extension evaluated it."""
    import numpy as np

    from diagnose.stepwise import refit

    y = held[f"r_{res.coefficient}"].to_numpy()
    ok = np.isfinite(y)
    rest = [t for t in res.terms if t not in cause.terms]
    other = refit(res, rest, data) if rest else None
    gains = []
    for frame in (held, as_extension_reads(held)):
        without = other.predict(frame) if other is not None else np.zeros(len(frame))  # as the extension has it
        with_ = res.predict(frame)
        rows = ok & np.isfinite(without) & np.isfinite(with_)
        if not rows.any():
            continue
        before = float(np.sqrt(np.mean((y - without)[rows] ** 2)))
        after = float(np.sqrt(np.mean((y - with_)[rows] ** 2)))
        gains.append(before / after if after > 0 else float("inf"))
    return min(gains, default=float("nan"))


def worse_on_held_out(
    causes: list, results: dict[str, StepwiseResult], data: pd.DataFrame, held: pd.DataFrame | None
) -> list:
    """The accepted aerodynamic causes whose terms make their coefficient's held-out residual worse by the
    settings' ``held_out_worse`` (:func:`held_out_gain`): each is left unconfirmed (``accepted`` false,
    ``unconfirmed`` and ``held_out_worse`` true, the reason in its verdict), which keeps it out of the
    extension, and is returned. ``results`` must hold the accepted causes' fits.

    Unconfirmed rather than rejected: where the held-out logs do not fly where the cause acts (a drag step
    at elevator angles the held-out condition never reaches), what they test is the extension's level
    there, set by the fitted logs' offsets, not the cause."""
    if held is None or not len(held):
        return []
    s = current()
    out = []
    for c in causes:
        if c.kind != "aero" or not c.verdict.get("accepted") or not set(c.terms) <= set(results[c.coefficient].terms):
            continue
        gain = held_out_gain(c, results[c.coefficient], data, held)
        c.verdict["held_out_logs_gain"] = gain
        if gain < s.held_out_worse:
            c.verdict.update(
                accepted=False,
                unconfirmed=True,
                held_out_worse=True,
                reason=f"not confirmed by the held-out logs: its terms make their {c.coefficient} "
                f"residual worse (RMS x{gain:.3f} with it, needs x{s.held_out_worse:g} at "
                f"least); kept out of the extension",
            )
            out.append(c)
    return out
