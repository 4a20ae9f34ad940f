"""Instrument errors against aerodynamic causes: the corrections the kinematics leave undecided
chosen by the aerodynamic residuals, the vanes' delays timed by them, a loosely measured air-data
error refined by them, and the corrections made named as sensor causes with their verdict. The
thresholds (``corroborated_gain``, ``refined_worse``, ``agree_*``, ``sensor_*``) are
:class:`diagnose.config.DiagnosisSettings`', read from :func:`diagnose.config.current`."""

from __future__ import annotations

from dataclasses import replace
from itertools import combinations
from typing import NamedTuple

import numpy as np
import pandas as pd

from diagnose.causes import Cause
from diagnose.config import current
from diagnose.corrected import Corrected
from diagnose.noise_floor import design_matrix
from diagnose.residuals import COEFFS
from diagnose.stepwise import fit_terms, stepwise
from diagnose.terms import Term, candidate_terms
from identify.compat import CompatResult, Parameter


def arbitrate(compat: CompatResult, data: Corrected, channels: set[str] | None = None) -> CompatResult:
    """Let the aerodynamic residuals decide the corrections the kinematics leave undecided.

    Two errors the kinematics cannot tell apart (an accelerometer bias and an attitude
    bias through gravity; a vane's bias and its scale when the trim alphas hardly differ)
    are each estimated with the other held at 0, and only one may be applied. An estimate
    3 to 5 standard errors from 0 may be real or a clustered standard error come out small.
    Each candidate is tried: the one that brings the model closest to the data is applied
    if the residuals get at least ``corroborated_gain`` times smaller (RMS) with it,
    on the fitted logs and on the held-out ones, as they are or beside the aerodynamic
    terms the stepwise search fits (:func:`_trial`), and no other coefficient's residual grows
    about its mean by more than ``refined_worse`` (:func:`_agrees`); the others keep what
    the residuals said.
    With ``channels``, only those channels' corrections are decided.
    """
    groups: list[list] = []
    for p in compat.undecided:
        if channels is not None and p.channel not in channels:
            continue
        g = next(
            (g for g in groups if p.confounded_with in {q.name for q in g} or p.name in {q.confounded_with for q in g}),
            None,
        )
        g.append(p) if g is not None else groups.append([p])
    for g in groups:
        tried = [(p, *_trial(compat, compat.choose(p.name, "trial"), data)) for p in g]
        best = max(tried, key=lambda t: _score(t[2]))
        for p, c, gains in tried:
            why = (
                f"the kinematics cannot tell it from {p.confounded_with}"
                if p.confounded_with
                else f"{p.z:.1f} standard errors from the kinematics"
            )
            way = _agrees(gains) if p is best[0] else ""
            if way:
                compat = compat.choose(
                    p.name, f"{why}; the {c} residual agrees: {_said(gains)}", beside_aero=way != "as is"
                )
            else:
                compat = compat.note(p.name, f"{why}; the {c} residual does not choose it ({_said(gains)})")
    return compat


#: :func:`_trial`'s entry for the other coefficients' residuals about their means.
OTHERS = "the others about their means"


def _trial(compat: CompatResult, trial: CompatResult, data: Corrected) -> tuple[str, dict[str, tuple[float, float]]]:
    """How much closer a trial correction brings the model to the data.

    The coefficient whose residual the correction moves most is judged: its RMS before
    over after, on the fitted logs and on the held-out ones (nan without), taken two ways:
    ``as is``, and ``beside aero terms``, what is left after the terms the stepwise search
    fits to each version (aerodynamic, and the thrust-scale signature; the held-out logs
    predicted by the terms fitted on the others). An aerodynamic error in the same residual (a drag rise with Mach
    beside an accelerometer bias) hides a real correction's gain in the first but not in
    the second; an aerodynamic term that mimics the correction (a pitch-rate term for a
    late vane) hides it in the second but not in the first. A third entry, ``the others about their
    means``, is the smallest of the other coefficients' fitted-log RMS ratios, each about its mean.
    """
    # the workers evaluate the trial's logs, fitted and held out, together; the search beside the aero
    # terms on the fitted logs as they are runs here meanwhile
    pending = [data.residuals(trial, wait=False)]
    if data.held:
        pending += [data.residuals(compat, held=True, wait=False), data.residuals(trial, held=True, wait=False)]
    before = data.residuals(compat)
    after = pending[0]()
    c = max(COEFFS, key=lambda k: float(np.max(np.abs(after[f"r_{k}"].to_numpy() - before[f"r_{k}"].to_numpy()))))

    def ratio(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(np.mean(a**2)) / max(np.sqrt(np.mean(b**2)), 1e-300))

    def search(frame: pd.DataFrame):
        return stepwise(frame, c, candidate_terms(frame, c))

    def left(res, frame: pd.DataFrame) -> np.ndarray | None:
        return None if frame is None else frame[f"r_{c}"].to_numpy() - res.predict(frame)

    fit_before = data.once(
        ("search beside aero terms", compat.correction_key(), c), lambda: search(before)
    )  # every trial of one correction
    fit_after = search(after)
    held = (pending[1](), pending[2]()) if data.held else None
    lb, lbh = left(fit_before, before), left(fit_before, held[0] if held else None)
    la, lah = left(fit_after, after), left(fit_after, held[1] if held else None)
    nan = float("nan")

    def about_mean(k: str) -> float:
        b, a = before[f"r_{k}"].to_numpy(), after[f"r_{k}"].to_numpy()
        return ratio(b - b.mean(), a - a.mean())

    return c, {
        "as is": (
            ratio(before[f"r_{c}"].to_numpy(), after[f"r_{c}"].to_numpy()),
            ratio(held[0][f"r_{c}"].to_numpy(), held[1][f"r_{c}"].to_numpy()) if held else nan,
        ),
        "beside aero terms": (ratio(lb, la), ratio(lbh, lah) if held else nan),
        OTHERS: (min(about_mean(k) for k in COEFFS if k != c), nan),
    }


def _agrees(gains: dict[str, tuple[float, float]]) -> str:
    """The way the residuals agree with a correction ("" if neither). As is: at least
    ``corroborated_gain`` on the fitted logs and (if any) on the held-out ones. Beside aero
    terms the fitted logs say little (the terms were fitted to them, and can mimic the correction
    there): the held-out logs must gain ``corroborated_gain``, and the fitted ones not lose.
    Neither if another coefficient's residual grows about its mean by more than ``refined_worse``
    with it: an instrument error moves every coefficient along its own derivative, and its correction
    shrinks each one's shape or leaves it (an offset the stepwise search's intercept takes up says
    nothing). An A320 lift change in alpha times Mach, with no instrument error, had the CL residual
    take a -1.8 % vane scale beside the aerodynamic terms (x1.48, x1.92 held out) while Cm's residual
    grew 2.1-fold about its mean with it, and "Cm vs alpha" was named first."""
    s = current()
    if _others_worse(gains):
        return ""
    g, h = gains["as is"]
    gb, hb = gains["beside aero terms"]
    return (
        "as is"
        if g >= s.corroborated_gain and not h < s.corroborated_gain
        else "beside aero terms"
        if gb >= 1.0 and hb >= s.corroborated_gain
        else ""
    )


def _score(gains: dict[str, tuple[float, float]]) -> float:
    if _others_worse(gains):
        return 0.0
    g, h = gains["as is"]
    gb, hb = gains["beside aero terms"]
    return max(min(g, h) if np.isfinite(h) else g, min(gb, hb) if np.isfinite(hb) and gb >= 1.0 else 0.0)


def _said(gains: dict[str, tuple[float, float]]) -> str:
    return "; ".join(
        f"{k}: RMS x{g:.2f} smaller corrected" + (f", x{h:.2f} on held-out logs" if np.isfinite(h) else "")
        for k, (g, h) in gains.items()
        if k != OTHERS or _others_worse(gains)
    )


def _others_worse(gains: dict[str, tuple[float, float]]) -> bool:
    """Another coefficient's residual grows about its mean by more than ``refined_worse`` with the correction."""
    return gains[OTHERS][0] < 1.0 / current().refined_worse


#: Gauss-Newton iterations of a time shift timed by the residuals (each evaluates the model twice per log).
RESIDUAL_DELAY_ITERATIONS = 3


def _with_estimate(
    compat: CompatResult, name: str, estimate: float, se: float, chosen: str, beside_aero: bool = False
) -> CompatResult:
    """The same result with one parameter estimated by the residuals and applied."""
    return replace(
        compat,
        parameters=[
            replace(
                q,
                identifiable=True,
                estimate=estimate,
                se=se,
                sources={"residuals": (estimate, se)},
                chosen=chosen,
                beside_aero=beside_aero,
            )
            if q.name == name
            else q
            for q in compat.parameters
        ],
    )


def _time_shift(data: pd.DataFrame, head: str) -> tuple[float, float, float, str] | None:
    """Time shift [s] the signature columns ``<head>_<C>`` fit in the residuals: the estimate,
    its delete-one-log jackknife error, the share of the residual explained and the coefficient
    whose residual it explains best (each residual less its mean per log)."""
    logs = data["log"].to_numpy()
    ids, inv = np.unique(logs, return_inverse=True)
    if len(ids) < 3:
        return None
    per = {}
    for c in COEFFS:
        y, x = _demean_by(data[f"r_{c}"].to_numpy(), logs), _demean_by(data[f"{head}_{c}"].to_numpy(), logs)
        if not float(x @ x) > 0:
            continue
        tau = float(x @ y / (x @ x))
        sxy, sxx = np.bincount(inv, x * y), np.bincount(inv, x * x)  # each log's share of the sums
        with np.errstate(divide="ignore", invalid="ignore"):
            jack = (sxy.sum() - sxy) / (sxx.sum() - sxx)  # each log left out
        se = float(np.sqrt((len(ids) - 1) / len(ids) * np.sum((jack - jack.mean()) ** 2)))
        per[c] = (tau, se, 1.0 - float((y - tau * x) @ (y - tau * x)) / max(float(y @ y), 1e-300), c)
    return max(per.values(), key=lambda v: v[2]) if per else None


def _demean_by(x: np.ndarray, groups: np.ndarray) -> np.ndarray:
    _, inv = np.unique(groups, return_inverse=True)
    return x - (np.bincount(inv, x) / np.bincount(inv))[inv]


def _gauss_newton(compat: CompatResult, data: Corrected, name: str, tau: float) -> tuple | None:
    """A vane's time shift [s] timed by the residuals from ``tau`` on: the estimate, its standard error,
    and the first step's :func:`_time_shift` (None if the residuals cannot time it)."""
    ch = name.split(".")[0]
    first = found = None
    for _ in range(RESIDUAL_DELAY_ITERATIONS):  # Gauss-Newton: the signature again at the corrected reading
        cur = _with_estimate(compat, name, tau, float("nan"), "trial") if tau else compat
        found = _time_shift(data.residuals(cur, delays=(ch,)), ch.split("_")[0] + "delay")
        if found is None:
            return None
        first = first or found
        tau += found[0]
        if abs(found[0]) < 1e-3:
            break
    return tau, found[1], first


def residual_delays(compat: CompatResult, data: Corrected) -> CompatResult:
    """Time the vanes the kinematics could not (turbulence) from the aerodynamic residuals.

    A vane ``tau`` late leaves ``tau`` times the model's rate of change along the
    vane's own reading in every residual (:func:`diagnose.residuals.delay_signature`).
    The residual of each coefficient, less its mean per log, is fitted by that
    signature; the coefficient whose residual it explains best gives the delay, with
    a delete-one-log jackknife standard error, by Gauss-Newton from no delay and from the
    kinematics' own estimate (biased by the aircraft's answer to the gusts, but a better
    start: from none, an 82-ms alpha delay the kinematics put at 94 ms was timed at -371 ms
    beside a lift change with gear, and "CL vs adothat" was the first discrepancy, 68 times its
    floor). The timing the residuals agree with best is applied,
    only if they get at least ``corroborated_gain`` times smaller with it, on the fitted logs
    and on the held-out ones. A model whose own rate derivatives are wrong leaves a similar
    signature: then the delay and the derivative cannot be told apart, and the
    report says so beside the aerodynamic cause.
    """
    for ch, err in compat.unmeasured:
        if err != "delay" or not data.held:
            continue
        # what the first step from no delay asks for, then the held-out logs as corrected, which every
        # trial and the diagnosis after it ask for: the workers go from one to the other without a pause
        data.ahead(compat, delays=(ch,))
        data.ahead(compat, held=True)
        name = f"{ch}.{err}"
        kinematic = compat.get(name).estimate
        starts = [0.0] + ([kinematic] if np.isfinite(kinematic) and kinematic != 0.0 else [])
        timed = [t for t in (_gauss_newton(compat, data, name, s) for s in starts) if t is not None]
        if len(starts) > 1:  # the kinematics' estimate as it is, judged by the residuals too
            timed.append((kinematic, compat.get(name).se, (0.0, 0.0, float("nan"), "kinematics")))
        tried = []
        for tau, se, (_, _, r2, best) in timed:
            trial = _with_estimate(compat, name, tau, se, "trial")
            if trial.get(name).correctable:
                c, gains = _trial(compat, trial, data)
                tried.append((tau, se, r2, best, c, gains))
        if not tried:
            if timed:
                compat = compat.note(
                    name,
                    f"the residuals put it at {timed[0][0] * 1000:+.0f} +- "
                    f"{timed[0][1] * 1000:.0f} ms, not a correction to make",
                )
            continue
        tau, se, r2, best, c, gains = max(tried, key=lambda t: _score(t[5]))
        source = (
            "the kinematics' own estimate"
            if best == "kinematics"
            else f"from the {best} residual (explains {100 * r2:.0f} % of it)"
        )
        said = f"{tau * 1000:+.0f} +- {se * 1000:.1f} ms, {source}; the {c} residual {_said(gains)}"
        way = _agrees(gains)
        if way:
            compat = _with_estimate(
                compat, name, tau, se, f"timed by the aerodynamic residuals: {said}", beside_aero=way != "as is"
            )
        else:
            compat = compat.note(name, f"the residuals put it at {said}: not applied")
    return compat


class Refinement(NamedTuple):
    """A correction the aerodynamic residuals refined (:func:`residual_refinement`)."""

    compat: CompatResult
    name: str  # the parameter refined
    coefficients: tuple[str, ...]  # those whose causes needed it


def _held_out_refutes(cause: Cause) -> bool:
    """The cause's own held-out logs refute it: tested there, it gained less than the verdict needs
    (:func:`diagnose.verdict.judge`: neither ``replicate_gain`` nor ``replicate_gain_where_departs``)."""
    s, v = current(), cause.verdict
    return bool(
        np.isfinite(v.get("replicate_gain", np.nan))
        and not v["replicate_gain"] >= s.replicate_gain
        and not v.get("replicate_gain_where_departs", np.nan) >= s.departs_gain
    )


def _subsets(by: dict[str, float]) -> list[dict[str, float]]:
    """The coefficients' needs that may refine together: when they all need the same sign, all of them and
    every two or more (a lone one: itself); none when their signs differ. One coefficient that needs more
    or less of the same correction than the others (its cause partly another) does not veto what they
    agree on; one that needs the opposite still does. An A320 null's 7.2 % vane scale, corrected as
    5.7 +- 2.2 %: CL and Cm each needed 1.7 % more, CD 2.8 % (its cause a drag change with elevator), 1.7
    times as much, and no refinement was made."""
    v = np.array(list(by.values()))
    if not (np.all(v > 0) or np.all(v < 0)):
        return []
    keys = list(by)
    sizes = (1,) if len(keys) == 1 else range(len(keys), 1, -1)
    return [{k: by[k] for k in ks} for n in sizes for ks in combinations(keys, n)]


def residual_refinement(compat: CompatResult, causes: list[Cause], reach: list[dict]) -> Refinement | None:
    """An air-data error the kinematics measured loosely and the aerodynamic residuals pin down.

    A vane's scale or bias error moves the model's CL, CD and Cm together, each along its
    own derivative; an aerodynamic error moves one coefficient. When one instrument
    error explains the causes of two coefficients or more (each at least ``agree_pct``
    % of its variance; significant and above the noise floor, whether or not the held-out
    checks accepted them), at consistent sizes (those of two or more, if a third needs the same
    sign at another size: :func:`_subsets`), and the correction it
    adds lands within ``agree_se`` standard errors of the kinematics' own estimate
    (``agree_all_se`` when all three coefficients agree; for a correction the data carry,
    from anywhere between the estimate and none: :func:`_gap`), the two independent
    measurements agree: the correction is refined to what the residuals need (the median over
    the coefficients), and the diagnosis runs again on the refined data. The causes of one coefficient
    alone may only adjust a correction the kinematics made, never add one, and the refinement then
    needs another coefficient's whole residual as its second witness (:func:`refinement_stands`).
    A cause that would need a correction further than ``agree_all_se`` from the kinematics'
    estimate neither supports nor refutes it (an A320 null's "CD vs CL" that a 48-standard-error
    vane scale of the opposite sign would make kept the CL and Cm residuals' 3.7 % from refining it).
    Nor does a cause its own held-out logs refute veto what the others agree on (:func:`_held_out_refutes`;
    it may still support them): on a null of our 737, a "CD vs qhat" 3 times its floor,
    x1.012 on held-out logs, needed -1.75 % of vane scale, and kept CL's and Cm's +4.9 and +4.5 % (the truth
    +4.8 %) from refining it; "CL vs alpha" and "Cm vs alpha" were named.

    Returns
    -------
    Refinement or None
        The refined data compatibility, the parameter refined and the coefficients that needed it;
        None if no instrument error qualifies.
    """
    s = current()
    needs: dict[tuple[str, str], dict[str, float]] = {}
    refuted: dict[tuple[str, str], set[str]] = {}
    for cause, rc in zip(causes, reach):
        if (
            cause.kind != "aero"
            or not cause.evidence["p_value"] < s.alpha_in
            or not cause.size > cause.verdict["noise_floor"]
        ):
            continue
        for a in rc["alternatives"]:
            if a.get("unmeasured") or a.get("declared") or a["explains_pct"] < s.agree_pct:
                continue
            p = compat.get(f"{a['channel']}.{a['error']}")
            # a cause that would need a correction the kinematics rule out is some other cause's
            if p.se > 0 and _gap(p, (p.estimate if p.applied else 0.0) + a["needs"]) <= s.agree_all_se:
                key = (a["channel"], a["error"])
                if cause.coefficient not in needs.setdefault(key, {}):
                    needs[key][cause.coefficient] = a["needs"]
                    if _held_out_refutes(cause):
                        refuted.setdefault(key, set()).add(cause.coefficient)
    best = None
    for (ch, err), every in needs.items():
        p = compat.get(f"{ch}.{err}")
        firm = np.sign([v for c, v in every.items() if c not in refuted.get((ch, err), ())])
        if len(firm) and np.all(firm == firm[0]):  # a cause its held-out logs refute does not veto the others
            every = {c: v for c, v in every.items() if c not in refuted.get((ch, err), ()) or np.sign(v) == firm[0]}
        for by in _subsets(every):
            v = np.array(list(by.values()))
            if (len(v) < 2 and not p.applied) or np.max(np.abs(v)) > s.agree_ratio * np.min(np.abs(v)):
                continue
            total = (p.estimate if p.applied else 0.0) + float(np.median(v))
            gap = _gap(p, total) if p.se > 0 else np.inf
            if gap <= (s.agree_all_se if len(v) == len(COEFFS) else s.agree_se) and (
                best is None or (-len(v), gap) < (-len(best[3]), best[0])
            ):
                best = (gap, p, total, by)
    if best is None:
        return None
    gap, p, total, by = best
    said = ", ".join(f"{c} {x:+.4g}" for c, x in by.items())
    where = (
        f"between the kinematics' {p.estimate:+.4g} +- {p.se:.2g} and none"
        if gap == 0 and p.applied
        else f"{gap:.1f} standard errors from the kinematics' {p.estimate:+.4g} +- {p.se:.2g}"
    )
    why = (
        f"the residuals of {', '.join(by)} {'each ' if len(by) > 1 else ''}need it (a further {said}); "
        f"{total:+.4g} in all, {where}"
    )
    moved = _follow(compat, p, total)
    return Refinement(
        replace(
            compat,
            parameters=[
                replace(
                    q,
                    estimate=total,
                    sources={**(q.sources or {"kinematics": (q.estimate, q.se)}), "residuals": (total, q.se)},
                    chosen=why,
                )
                if q is p
                else replace(
                    q,
                    estimate=moved[q.name],
                    sources={
                        **(q.sources or {"kinematics": (q.estimate, q.se)}),
                        f"given {p.name}": (moved[q.name], q.se),
                    },
                )
                if q.name in moved
                else q
                for q in compat.parameters
            ],
        ),
        p.name,
        tuple(by),
    )


def _follow(compat: CompatResult, p: Parameter, total: float) -> dict[str, float]:
    """The other errors the kinematics estimated with ``p``, given ``p`` at ``total``: each moves by its
    regression on ``p`` in their joint estimate (the conditional mean), its standard error kept. A vane's
    bias and scale estimated together trade at the trim alphas: on a null of our 737 the kinematics
    measured +3.0 +- 0.54 % of scale and -0.090 +- 0.015 deg of bias in 1.5 ft/s turbulence, the residuals
    of CL and Cm refined the scale to none, and the bias left alone made a "CD vs flap, alpha" 3.4 times
    its floor (x0.20 on held-out logs with the bias)."""
    for names, cov in compat.covariance:
        if p.name not in names or not cov[names.index(p.name), names.index(p.name)] > 0:
            continue
        j = names.index(p.name)
        out = {}
        for i, n in enumerate(names):
            q = compat.get(n)
            if i != j and q.identifiable and not q.chosen and "residuals" not in (q.sources or {}):
                out[n] = q.estimate + cov[i, j] / cov[j, j] * (total - p.estimate)
        return out
    return {}


def refinement_stands(refinement: Refinement, before: pd.DataFrame, after: pd.DataFrame) -> CompatResult | None:
    """The refined data compatibility if the residuals over all the data agree with it, else None.

    No coefficient's residual RMS may grow by more than ``refined_worse``: about its mean when two
    coefficients or more needed the refinement, its mean included when one did (its offset is then
    evidence: below). A refinement only one coefficient's causes needed also needs a second witness:
    another coefficient's residual RMS at least ``corroborated_gain`` times smaller. A vane bias moves
    CL by its slope, an offset the stepwise search takes up in its intercept and names nothing for:
    a stock-737 null's vane bias, corrected 0.079 deg too far (2.5 standard errors), left a "CD vs
    alpha" 5.7 times its floor that only CD's causes showed, and CL's residual RMS 4.8 times larger
    than with the correction the CD residual needed. A drag change with
    alpha that a vane bias would mimic in CD grows CL's residual instead.
    """

    def rms(data: pd.DataFrame, c: str, about_mean: bool = False) -> float:
        r = data[f"r_{c}"].to_numpy()
        return float(np.sqrt(np.mean((r - np.mean(r) if about_mean else r) ** 2)))

    s = current()
    agreed = len(refinement.coefficients) > 1
    if any(rms(after, c, agreed) > s.refined_worse * rms(before, c, agreed) for c in COEFFS):
        return None
    gain = {c: rms(before, c) / max(rms(after, c), 1e-300) for c in COEFFS}
    compat = refinement.compat
    if agreed:
        return compat
    witness = max((c for c in COEFFS if c not in refinement.coefficients), key=gain.get)
    if not gain[witness] >= s.corroborated_gain:
        return None
    return replace(
        compat,
        parameters=[
            replace(q, chosen=f"{q.chosen}; {witness}'s residual RMS x{gain[witness]:.2f} smaller with it")
            if q.name == refinement.name
            else q
            for q in compat.parameters
        ],
    )


def rearbitrate(before: CompatResult, refined: CompatResult, data: Corrected) -> CompatResult:
    """The corrections the residuals chose (:func:`arbitrate`) on a channel whose correction a refinement
    changed, chosen again: they were chosen beside another one. A vane bias chosen beside a spurious vane
    scale undid the scale at the trim alphas; a +0.21 deg vane bias, chosen by the CL residual where a
    +4.8 % scale was measured at -0.16 +- 2.7 %, stood in for the scale at the trim alphas, and beside the
    scale refined to +4.7 % doubled it there (CD's residual RMS grew 1.5-fold about its mean, and "CL vs
    alpha" and "Cm vs alpha" were named on a null of our 737). Chosen again, it is not."""
    changed = {
        q.channel
        for p, q in zip(before.parameters, refined.parameters)
        if (p.applied != q.applied or q.estimate != p.estimate) and "residuals" in q.sources
    }
    again = [q.name for q in refined.parameters if q.channel in changed and q.chosen and "residuals" not in q.sources]
    if not again:
        return refined
    return arbitrate(
        replace(refined, parameters=[replace(q, chosen="") if q.name in again else q for q in refined.parameters]),
        data,
        changed,
    )


def _gap(p: Parameter, total: float) -> float:
    """How far [standard errors] a correction of ``total`` lies from what the kinematics measured: from
    their estimate, or, for a correction the data already carry, from anywhere between it and none. The
    residuals may shrink a correction made toward none, a smaller claim on the instrument (a stock-737
    null's +2.9 +- 0.52 % vane scale, applied at 5.6 standard errors on the kinematics' word alone, that
    CL, CD and Cm each needed undone), but not grow it past the kinematics' estimate."""
    lo, hi = sorted((0.0, p.estimate)) if p.applied else (p.estimate, p.estimate)
    return max(lo - total, total - hi, 0.0) / p.se


def compat_causes(
    compat: CompatResult,
    corrected: Corrected,
    data: pd.DataFrame,
    held_data: pd.DataFrame | None,
    aero: dict[str, list[Term]] | None = None,
) -> list[Cause]:
    """The instrument errors the data compatibility corrected, as causes with their verdict.

    Each correction is undone in turn and JSBSim evaluates the model again: its
    effect on the fitted logs' residuals is its size, and the held-out residual
    RMS without it over the RMS with it is its held-out gain. A correction the residuals
    chose only beside the aerodynamic terms (:func:`_trial`) is judged the same way: where
    the stepwise search found aerodynamic terms in its coefficient (``aero``: coefficient
    -> terms), the gain is also taken beside them (the terms fitted to each version, the
    held-out logs predicted), and the larger counts. A correction the kinematics made on
    their own word is not: with few conditions, fitted terms leave offsets between them
    that any correction shaped like 1/qbar can seem to explain.
    """
    s = current()
    causes = []
    aero = aero or {}

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x**2)))

    def beside(frame: pd.DataFrame, held: pd.DataFrame, c: str) -> np.ndarray:
        y = frame[f"r_{c}"].to_numpy()
        fit = fit_terms(y, [t.design(frame) for t in aero[c]], aero[c])
        x = design_matrix(aero[c], held)
        return held[f"r_{c}"].to_numpy() - x @ fit.beta

    for p in compat.applied:
        undone = compat.without(p.name)
        r = corrected.residuals(undone)
        effect = {c: float(np.max(np.abs(r[f"r_{c}"].to_numpy() - data[f"r_{c}"].to_numpy()))) for c in COEFFS}
        c = max(effect, key=effect.get)
        gain = float("nan")
        if corrected.held and held_data is not None:
            h = corrected.residuals(undone, held=True)
            after = rms(held_data[f"r_{c}"].to_numpy())
            gain = rms(h[f"r_{c}"].to_numpy()) / after if after > 0 else float("inf")
            if aero.get(c) and p.beside_aero:
                gain = max(gain, rms(beside(r, h, c)) / max(rms(beside(data, held_data, c)), 1e-300))
        reasons = []
        if p.z < s.compat.apply_z and not p.chosen:
            reasons.append(f"only {p.z:.1f} standard errors (needs {s.compat.apply_z:g}, or the residuals to agree)")
        if effect[c] < s.sensor_effect:
            reasons.append(f"moves {c} by {effect[c]:.2g} at most (needs {s.sensor_effect:g})")
        if not gain >= s.sensor_min_gain:
            reasons.append(
                "no held-out data"
                if not np.isfinite(gain)
                else f"does not improve held-out data (gain x{gain:.3f}, needs x{s.sensor_min_gain})"
            )
        cause = Cause(
            c,
            [p.channel],
            [],
            p.error,
            {
                "z": p.z,
                "F": p.z**2,
                "p_value": 0.0,
                "dof": [1, 0],
                "rss_reduction_pct": float("nan"),
                "method": "data compatibility",
                "methods": {k: {"estimate": e, "se": se} for k, (e, se) in p.sources.items()},
                "effect_by_coefficient": effect,
                **({"confounded_with": p.confounded_with or None, "chosen_because": p.chosen} if p.chosen else {}),
            },
            effect[c],
            size=effect[c],
            kind="sensor",
            channel=p.channel,
            error=p.error,
            estimate=p.estimate,
            se=p.se,
        )
        cause.verdict = {
            "accepted": not reasons,
            "reason": "; ".join(reasons),
            "holdout_gain": gain,
            "noise_floor": s.sensor_effect,
            "size_over_floor": effect[c] / s.sensor_effect,
            "unit": p.unit,
        }
        causes.append(cause)
    return causes
