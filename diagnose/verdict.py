"""The verdict on each candidate cause: significant, beyond what instrument noise and errors make,
better on data it was not fitted on."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from diagnose.causes import Cause, along, held_constant, shape_of
from diagnose.config import current
from diagnose.noise_floor import RESOLUTION, design_matrix
from diagnose.stepwise import StepwiseResult, refit
from identify.lsq import solve_normal


def rank(verdict: dict) -> tuple[int, int, float]:
    """The order discrepancies are listed in, the first being the diagnosis's answer: those held-out
    conditions confirmed (each left out, predicted better with the cause) before those no other
    condition could test (a term in the one flap setting flown, which repeats of that condition
    confirm, stands for whatever else sets that condition apart: its Mach, its thrust), and those
    before the ones held-out conditions predict worse (the repeats passed them; a true effect in Mach
    can be so, its held-out Mach extrapolated, and so can a term that follows the trim beside the cause:
    a smooth(mach) 184 times its floor at x0.94 came before a stock-737 drag table in the elevator at
    x6.25); in each group those ``strong_over_floor`` times their floor first
    (:class:`diagnose.config.DiagnosisSettings`, read from :func:`diagnose.config.current`), the one that
    explains most of its coefficient's residual (``explains_pct``) first of them, and then the largest
    over its noise floor."""
    s = current()
    gain = verdict.get("holdout_gain")
    tested = gain is not None and np.isfinite(gain)
    size = verdict.get("size_over_floor", 0.0)
    strong = size >= s.strong_over_floor
    return (
        0 if tested and gain > 1.0 else 2 if tested else 1,
        0 if strong else 1,
        -(np.nan_to_num(verdict.get("explains_pct", 0.0)) if strong else size),
    )


def contribution(res: StepwiseResult, cause: Cause, data: pd.DataFrame) -> np.ndarray:
    """A cause's fitted contribution at the rows of ``data``, less a constant the intercept takes back
    (:func:`diagnose.causes.held_constant`): it departs from the model where it departs from zero."""
    c = sum((t.design(data) @ res.term_beta(t) for t in res.terms if t in cause.terms), np.zeros(len(data)))
    return c - held_constant(c)


def holdout_gain(
    res: StepwiseResult,
    cause: Cause,
    data: pd.DataFrame,
    strong: bool | None = None,
    group: str = "condition",
    where: float | None = None,
) -> tuple[float, list[int], dict]:
    """Leave-one-condition-out (or leave-one-log-out, ``group``) check of one cause on every
    condition flown.

    For each flight condition, the coefficient's selected terms are fitted on
    the others and predict it, and so are its terms without the cause's (refitted: two
    collinear causes that cancel each other are no better than neither); the gain is the
    residual RMS of the second prediction over that of the first, over the logs where the cause
    acts (where its contribution departs from the model by ``acting_share`` of its
    size): pooled, and per condition. Only conditions the others can predict count: a condition
    whose removal leaves the coefficient's terms not all estimable (the only condition at its
    flap angle, for a term in flap) cannot test the cause, and says nothing of it. For a strong
    cause (``strong``), rows outside the
    range the other conditions span in the cause's variables (:func:`_bracketed`) are predicted by
    extrapolation: they may confirm it, not refute it (a shape the fit has not seen there, a
    step in Mach between the conditions flown, is no evidence against it). The pooled gain is the
    larger of that over every testable row and that over the rows within range; a condition
    whose rows all lie beyond the others' range counts only if it gains. A weaker cause is tested on
    every row both ways: on the A320's nulls in 3 ft/s, causes twice their floor at x1.03 pooled were
    refuted by extrapolation alone (x0.88-0.93 at Mach 0.5), and named without it.

    A cause whose terms the stepwise search chose before others, if it gains less than
    ``strong_gain`` so, is also tested against the terms chosen before it alone (those after it
    left out of both fits), the search's own order; a gain of ``strong_gain`` or more that way
    stands, if the cause fitted so is ``alone_share`` of its size or more. A drag dip in alpha
    fitted by smooth(alpha) and then quadratic(CL), nearly the same variable, gained nothing against
    the other either way (x0.69, x0.90): two halves of one effect.
    A weaker gain that way does not count: on stock-737 nulls in 3 ft/s, drag against elevator
    gained x1.03 alone and x0.26 against the drag against alpha that followed it.

    Parameters
    ----------
    res : StepwiseResult
        The coefficient's stepwise fit (its terms).
    cause : Cause
    data : DataFrame
        Residual data of every log, train and held out, with ``condition`` and ``log`` columns.
    strong : bool, optional
        Whether extrapolated rows may only confirm the cause (default: an F of ``strong_f`` or
        more; :func:`judge` also counts a cause ``strong_over_floor`` times its floor strong).
    group : str
        The column whose values are left out in turn: ``"condition"``, or ``"log"`` for each log
        predicted from every other, its own condition's repeats included, on its rows within the
        others' range only (:func:`judge` records it as ``replicate_gain``).
    where : float, optional
        Count only the rows where the cause's contribution departs from the model by this share of
        its size, not every row of the logs where it acts.

    Returns
    -------
    gain : float
        Pooled; NaN if no log sees the cause, or it was flown at a single condition.
    acting : list of int
        The logs (``log`` values) where it acts.
    by_condition : dict
        Condition -> gain over its logs where the cause acts; NaN for a condition that cannot test it.
    """
    s = current()
    y = data[f"r_{cause.coefficient}"].to_numpy()
    own = [t for t in res.terms if t in cause.terms]
    first = min(res.terms.index(t) for t in own)
    full = contribution(res, cause, data)
    frame = pd.DataFrame({"log": data["log"].to_numpy(), "dev": np.abs(full)})
    acting = [int(i) for i, g in frame.groupby("log") if g["dev"].max() >= s.acting_share * max(cause.size, 1e-300)]
    code, names = pd.factorize(data[group], sort=True)  # hashed: sorting the strings took a third
    if not acting or len(names) < 2:
        return float("nan"), acting, {}
    order = np.argsort(code, kind="stable")  # rows by condition: one sort, no string compares
    rows = np.split(order, np.flatnonzero(np.diff(code[order])) + 1)
    acts = np.isin(data["log"].to_numpy(), acting)
    if where is not None:
        acts &= frame["dev"].to_numpy() >= where * max(cause.size, 1e-300)
    inside = np.zeros(len(y), bool)
    for out in rows:
        inside[out] = _bracketed(data, out, cause.variables)
    x_own = np.column_stack([t.design(data) for t in own])
    strong = cause.evidence.get("F", 0.0) >= s.strong_f if strong is None else strong

    def against(rest: list) -> tuple[float, dict]:
        x_rest = design_matrix(rest, data)
        x = np.hstack([x_rest, x_own])
        scale = np.sqrt(np.einsum("ij,ij->j", x, x))
        scale[scale == 0] = 1.0
        xs = x / scale
        gram, xty = xs.T @ xs, xs.T @ y
        rank = _rank(gram)
        before = np.zeros(len(y))
        after = np.zeros(len(y))
        testable = np.zeros(len(y), bool)
        k = x_rest.shape[1]
        for out in rows:
            xo = xs[out]
            left = gram - xo.T @ xo
            testable[out] = _rank(left) == rank
            rhs = xty - xo.T @ y[out]
            beta = solve_normal(left, rhs) / scale  # fitted without this condition
            beta_rest = solve_normal(left[:k, :k], rhs[:k]) / scale[:k]  # ... and without the cause
            before[out] = y[out] - x_rest[out] @ beta_rest
            after[out] = y[out] - x[out] @ beta
        sel = acts & testable

        def ratio(m: np.ndarray) -> float:
            if not m.any():
                return float("nan")
            ss = float(after[m] @ after[m])
            return float(np.sqrt(before[m] @ before[m] / ss)) if ss > 0 else float("inf")

        if group == "log":  # rows within the others' range only: extrapolation confirms no repeat
            sel &= inside
        if not strong or group == "log":
            by = {str(names[code[out[0]]]): ratio(out[sel[out]]) for out in rows if acts[out].any()}
            return ratio(sel), dict(sorted(by.items()))

        def one(out: np.ndarray) -> float:
            mine = out[sel[out] & inside[out]]
            if mine.size:
                return ratio(mine)
            g = ratio(out[sel[out]])  # beyond the others' range: it may confirm the cause, not refute it
            return g if g >= 1.0 else float("nan")

        by = {str(names[code[out[0]]]): one(out) for out in rows if acts[out].any()}
        pooled = [g for g in (ratio(sel), ratio(sel & inside)) if np.isfinite(g)]
        return max(pooled, default=float("nan")), dict(sorted(by.items()))

    gain, by = against([t for t in res.terms if t not in cause.terms])
    earlier = [t for t in res.terms[:first] if t not in cause.terms]
    if (
        len(earlier) + len(own) < len(res.terms)
        and not gain >= s.strong_gain
        and _alone(y, design_matrix(earlier, data), x_own) >= s.alone_share * cause.size
    ):
        g, b = against(earlier)
        if g >= s.strong_gain:
            gain, by = g, b
    return gain, acting, by


def _repeats(res: StepwiseResult, cause: Cause, data: pd.DataFrame, strong: bool) -> tuple[float, float]:
    """The held-out decision's two gains, each log left out in turn and predicted from every other
    (:func:`holdout_gain` by log): over the logs where the cause acts, and over their rows where it
    departs from the model by ``departs_share`` of its size."""
    s = current()
    return (
        holdout_gain(res, cause, data, strong, group="log")[0],
        holdout_gain(res, cause, data, strong, group="log", where=s.departs_share)[0],
    )


def _alone(y: np.ndarray, x_rest: np.ndarray, x_own: np.ndarray) -> float:
    """The size (range) of the ``x_own`` part of a least-squares fit of ``y`` on ``x_rest`` and ``x_own``."""
    beta = np.linalg.lstsq(np.hstack([x_rest, x_own]), y, rcond=None)[0]
    return float(np.ptp(x_own @ beta[x_rest.shape[1] :]))


def _bracketed(data: pd.DataFrame, out: np.ndarray, variables: list[str]) -> np.ndarray:
    """Which rows ``out`` (one condition) lie within the range the other rows span in each of the cause's
    variables: the others interpolate there. Outside it a fit extrapolates, and a shape it does not know
    (a step in Mach between the conditions flown, predicted at the highest Mach from the two below)
    would refute a cause it cannot test."""
    ok = np.ones(len(out), bool)
    rest = np.ones(len(data), bool)
    rest[out] = False
    for v in variables:
        if v not in data or not rest.any():
            continue
        x = data[v].to_numpy(float)
        ok &= (x[out] >= np.nanmin(x[rest])) & (x[out] <= np.nanmax(x[rest]))
    return ok


def _rank(gram: np.ndarray, rtol: float = 1e-9) -> int:
    """The numerical rank of a Gram matrix of unit-norm columns."""
    w = np.linalg.eigvalsh(gram)
    return int(np.sum(w > rtol * max(float(w.max()), 1e-300)))


def main_effect(cause: Cause, res: StepwiseResult, data: pd.DataFrame) -> tuple[Cause, StepwiseResult] | None:
    """The cause cut to its terms on its first variable alone, and its coefficient's fit refitted
    without the rest of it (on ``data``, the fitted logs); None if it has no such term or nothing else.

    The stepwise search adds terms while they pass on the fitted logs; beside a large effect of one
    variable that its basis does not follow exactly (a table of 4 knots against a smooth term's
    quantile knots), interactions can enter to mop up what is left, and the cause they form with it
    fails on held-out conditions where its main effect alone would not."""
    v = cause.variables[0]
    own = [t for t in cause.terms if t.variables == (v,)]
    if not own or len(own) == len(cause.terms):
        return None
    fit = refit(res, [t for t in res.terms if t not in cause.terms or t in own], data)
    part = sum(t.design(data) @ fit.term_beta(t) for t in own)
    cx, cy = along(own, fit, data, v)
    held = held_constant(part)
    part, cy = part - held, cy - held
    cut = replace(
        cause,
        variables=[v],
        terms=own,
        shape=shape_of(cx, cy),
        peak=float(np.max(np.abs(part))),
        size=float(np.ptp(part)),
        curve={v: cx.tolist(), f"d{cause.coefficient}": np.asarray(cy).tolist(), "others_at_median": {}},
        evidence={
            **cause.evidence,
            "cut_from": cause.label,
            "terms": {t.label: cause.evidence["terms"].get(t.label, {}) for t in own},
        },
    )
    return cut, fit


def judge(
    causes: list[Cause],
    results: dict[str, StepwiseResult],
    data_all: pd.DataFrame,
    floors: list[np.ndarray],
    eiv: list[float] | None = None,
    reach: list[dict] | None = None,
    data: pd.DataFrame | None = None,
) -> None:
    """Fill each cause's verdict: significant, beyond what noise and instrument errors make,
    better on held-out logs where it acts by ``replicate_gain``, each log left out in turn and
    predicted from the others, its own condition's repeats among them (or by ``departs_gain``
    on their rows where it departs from the model, ``replicate_gain_where_departs``). The conditions left out in
    turn (``holdout_gain``, ``holdout_gain_by_condition``) are reported beside it and do not
    decide: a shape in Mach between the Mach numbers flown cannot be predicted from the other
    conditions, and a term fitted to a few flights' turbulence can gain x1.05-1.15 by chance over
    four conditions. A cause that acts at a single condition, or at none that can be
    left out, and that its repeats do not confirm either (nor refute: ``refuted_gain``; its F at least
    ``one_condition_f``), is
    ``unconfirmed`` if it is ``strong_over_floor`` times its floor, or ``clear_over_floor`` times with an F of
    ``strong_f``: a discrepancy all the same, named with that caution, but not put into the
    extension; so is one ``clear_over_floor`` times its floor with an F of ``held_out_f``
    that only held-out data fail. So is a cause ``strong_over_floor`` times the floor that improves held-out
    conditions by ``strong_gain`` but that instrument errors within the data compatibility's
    reach could make whole: the data depart from the model, and only the cause is in doubt. Every
    threshold is a field of :class:`diagnose.config.DiagnosisSettings` (:func:`diagnose.config.current`),
    the significance level ``alpha_in`` among them.

    ``floors`` holds each cause's sizes fitted to noise alone; ``eiv`` the factor by which the
    simulation may underestimate the errors-in-variables of its variables (at most 2: fresh noise on
    logs that already hold noise; :meth:`diagnose.noise_floor.NoiseFloor.eiv_factors`), its floor
    being that factor times the largest size; ``reach`` what the instrument
    errors the data compatibility may have left can make of its shape
    (:meth:`diagnose.noise_floor.NoiseFloor.reach`). The part of the cause no plausible
    instrument error makes must be larger than the noise floor.

    With ``data`` (the fitted logs' residual data), a cause of several variables that fails on
    held-out data alone is judged again cut to its main effect (:func:`main_effect`; its floor
    and instrument-error reach kept, which a part of it can only lower); if that passes, the
    cause and its coefficient's fit are replaced by the cut ones (``evidence.cut_from`` says so).
    """
    s = current()
    alpha_in = s.alpha_in
    reach = reach or [{"made": 0.0, "left": c.size, "alternatives": []} for c in causes]
    eiv = eiv or [1.0] * len(causes)
    for i, (cause, null, factor, rc) in enumerate(zip(causes, floors, eiv, reach)):
        floor = max(factor * float(np.max(null)) if len(null) else 0.0, RESOLUTION)
        beyond = min(cause.size, rc["left"])
        sure = cause.evidence.get("F", 0.0) >= s.strong_f or beyond >= s.strong_over_floor * floor
        gain, acting, by_condition = holdout_gain(results[cause.coefficient], cause, data_all, sure)
        replicate, departs = _repeats(results[cause.coefficient], cause, data_all, sure)
        repeated = replicate >= s.replicate_gain or departs >= s.departs_gain
        if data is not None and not repeated and len(by_condition) > 1 and cause.kind == "aero":
            cut = main_effect(cause, results[cause.coefficient], data)
            if cut is not None:
                g2, a2, b2 = holdout_gain(cut[1], cut[0], data_all, sure)
                r2, d2 = _repeats(cut[1], cut[0], data_all, sure)
                if (r2 >= s.replicate_gain or d2 >= s.departs_gain) and min(cut[0].size, rc["left"]) > floor:
                    cause = causes[i] = cut[0]
                    results[cause.coefficient] = cut[1]
                    gain, acting, by_condition, replicate, departs, repeated = g2, a2, b2, r2, d2, True
        beyond = min(cause.size, rc["left"])
        reasons, made_by = [], None
        if not cause.evidence["p_value"] < alpha_in:
            reasons.append(f"not significant (p = {cause.evidence['p_value']:.2g}, needs < {alpha_in:g})")
        if not cause.size > floor:
            reasons.append(f"no larger than instrument noise makes it (size {cause.size:.3g}, noise floor {floor:.3g})")
        elif not beyond > floor:
            made_by = len(reasons)  # where the reach's reason stands
            reasons.append(
                f"instrument errors within {s.reach_se:g} standard errors of the data compatibility "
                f"make all but {beyond:.3g} of it (size {cause.size:.3g}, noise floor {floor:.3g})"
            )
        # an effect that departs from the model at one condition alone, or that no condition left out can
        # test, the other conditions cannot confirm or refute; that condition's repeats still can
        tested = {c: g for c, g in by_condition.items() if np.isfinite(g)}
        alone = (len(by_condition) == 1 or (bool(by_condition) and not tested)) and not repeated
        strong = beyond >= s.strong_over_floor * floor
        if not repeated:
            where_departs = (
                f", x{departs:.3f} where it departs, needs x{s.departs_gain}" if np.isfinite(departs) else ""
            )
            if len(by_condition) == 1:
                reasons.append(
                    f"acts at one condition only ({next(iter(by_condition))}): no other condition "
                    f"can confirm it, nor its repeats (x{replicate:.3f}, needs x{s.replicate_gain}"
                    f"{where_departs})"
                )
            elif not np.isfinite(replicate):
                reasons.append("no held-out data where it acts")
            else:
                by_conditions = (
                    f"x{gain:.3f} with each condition left out"
                    if np.isfinite(gain)
                    else "no condition it acts on can be left out with its terms still estimable"
                )
                reasons.append(
                    f"does not improve held-out logs (x{replicate:.3f} with each left out, needs "
                    f"x{s.replicate_gain}{where_departs}; {by_conditions})"
                )
        alts = [
            a
            for a in rc["alternatives"]
            if a["explains_pct"] >= s.sensor_alternative_pct
            and abs(a["needs_se"]) <= s.sensor_alternative_se
            and (not a.get("unmeasured") or abs(a["needs"]) <= s.unmeasured_plausible[a["error"]])
        ][:3]
        if alts:
            cause.evidence["sensor_alternatives"] = alts
        # a discrepancy many times the noise floor that improves held-out data is there, whatever
        # makes it: when instrument errors could make it all, it is named with them, not dismissed
        # ... unless the data compatibility measured the one error that makes it, at that size, and left it
        measured = [
            a
            for a in alts
            if a.get("left")
            and abs(a["needs_se"]) <= s.reach_se
            and a["explains_pct"] >= s.measured_pct
            and (
                (made_by is not None and abs(a["left"]) >= s.reach_se * a["se"])
                or a.get("channel_left_se", 0.0) >= s.measured_channel_se
            )
        ][:1]
        mimicked = (
            cause.size >= s.strong_over_floor * floor
            and not beyond > floor
            and len(reasons) == 1
            and cause.evidence["p_value"] < alpha_in
            and gain >= s.strong_gain
            and not alone
            and not measured
        )
        for a in measured:
            together = f"{a['channel']}'s errors together {a.get('channel_left_se', 0.0):.1f} standard errors from none"
            if made_by is None:
                reasons.append(
                    f"the data compatibility measured {together} and left them uncorrected, and its "
                    f"{a['error']} alone makes {a['explains_pct']:.0f} % of it (it needs {a['needs']:+.3g}, "
                    f"measured {a['left']:+.3g} +- {a['se']:.2g}): that error, not the model"
                )
            else:
                alone_se = abs(a["left"]) >= s.reach_se * a["se"]
                reasons[made_by] += (
                    f"; the data compatibility measured {a['channel']} {a['error']} at {a['left']:+.3g} "
                    f"+- {a['se']:.2g}{'' if alone_se else f' ({together})'} and left it uncorrected, "
                    f"and that makes it (it needs {a['needs']:+.3g})"
                )
        if mimicked:
            made = ", ".join(f"{a['channel']} {a['error']} {a['needs']:+.3g}" for a in alts)
            reasons[0] += (
                f"; a discrepancy all the same (x{gain:.2f} on held-out data): the model or an instrument "
                f"is wrong ({made or 'a combination of those errors'} would make it)"
            )
        clear = strong or (beyond >= s.clear_over_floor * floor and cause.evidence.get("F", 0.0) >= s.strong_f)
        refuted = (
            bool(np.isfinite(replicate))
            and max(replicate, departs if np.isfinite(departs) else -np.inf) < s.refuted_gain
        )
        weak = cause.evidence.get("F", 0.0) < s.one_condition_f
        if alone and clear and not refuted and weak and len(reasons) == 1:
            reasons[0] += (
                f"; F = {cause.evidence.get('F', 0.0):.3g}, below the {s.one_condition_f:g} a discrepancy "
                "at one condition needs"
            )
        unseen = (
            cause.kind == "aero"
            and beyond >= s.clear_over_floor * floor
            and cause.evidence.get("F", 0.0) >= s.held_out_f
            and not repeated
        )
        if unseen and len(reasons) == 1:
            reasons[0] += (
                f"; a discrepancy all the same (F = {cause.evidence['F']:.4g}, {beyond / floor:.1f} times its "
                f"noise floor beyond instrument errors), in a shape these data do not confirm"
            )
        cause.verdict = {
            "accepted": not reasons,
            "reason": "; ".join(reasons),
            "noise_floor": floor,
            "unconfirmed": ((alone and clear and not refuted and not weak) or unseen) and len(reasons) == 1 or mimicked,
            "instrument_errors_make": rc["made"],
            "beyond_instrument_errors": beyond,
            "noise_sizes": [float(v) for v in null],
            "errors_in_variables_factor": factor,
            "holdout_gain": gain,
            "holdout_gain_by_condition": by_condition,
            "holdout_logs": acting,
            "size_over_floor": beyond / floor,
            "explains_pct": cause.evidence.get("rss_reduction_pct", 0.0),
            "replicate_gain": replicate,
            "replicate_gain_where_departs": departs,
        }


def implausible(cause: Cause) -> str:
    """Why a sensor cause's estimate is beyond what an instrument of its kind can be off (the settings'
    ``finding_plausible``: a scale factor, a delay, a bias by its unit), or "" if it is within; the cause's
    verdict is then refused with that reason (a reading the data do not support, not a measurement)."""
    if cause.kind != "sensor" or cause.estimate is None or not np.isfinite(cause.estimate):
        return ""
    bounds = current().finding_plausible
    unit = cause.verdict.get("unit", "")
    key = cause.error if cause.error in ("scale", "delay") else unit
    bound = bounds.get(key)
    if bound is None or abs(cause.estimate) <= bound:
        return ""
    shown = f"{100 * cause.estimate:+.1f} %" if cause.error == "scale" else f"{cause.estimate:+.3g} {unit or 's'}"
    limit = f"+-{100 * bound:g} %" if cause.error == "scale" else f"+-{bound:g} {unit or 's'}"
    return (
        f"a {cause.channel} {cause.error} of {shown} is beyond what an instrument of its kind can be off "
        f"({limit}): a reading the data do not support, not a measurement"
    )
