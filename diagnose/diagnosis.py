"""Diagnosis: what the model gets wrong, which variables explain it, and how; the stages in order.

0. Data compatibility (:mod:`identify.compat`), arbitrated by the aerodynamic residuals
   (:mod:`diagnose.arbitration`); the logs corrected in one place (:mod:`diagnose.corrected`).

1. Residuals. Measured eq. (1) coefficients minus the model's own prediction
   at the measured states (JSBSim computes it: :mod:`diagnose.evaluate`, :mod:`diagnose.residuals`). Cm
   is taken about the aerodynamic reference point, where JSBSim applies the aero
   forces, so a lift or drag discrepancy does not leak into Cm.
2. Model structure. Forward-backward stepwise regression of each residual on
   a pool of candidate terms: every logged variable, linear and smooth (a
   piecewise-linear basis), and pairwise interactions. A term enters by a
   partial F-test whose degrees of freedom count the effective number of
   independent samples (residuals are autocorrelated), and only if it
   removes a meaningful share of the residual; a term leaves when it no
   longer passes (SIDPAC's stepwise regression, with those two corrections;
   :mod:`diagnose.terms`, :mod:`diagnose.stepwise`). Where the sequential replacement split one
   cause in two, each part must pass the verdict (stage 4); if one falls, the coefficient is searched
   again without splitting and read whole, if that names a discrepancy there.
3. Causes. Selected terms that share a variable form one cause (a gear effect
   and its gear x alpha interaction: one gear effect that depends on alpha).
   Causes are ranked by the F statistic of removing them (:mod:`diagnose.causes`).
4. Verdict. Each cause against the noise floor, the instrument errors' reach and held-out
   data (:mod:`diagnose.noise_floor`, :mod:`diagnose.verdict`).
5. Extension. The fitted terms, written as JSBSim functions (tables on the
   variables' properties), to merge into a copy of the model (:mod:`diagnose.extension`);
   the gain measured on held-out logs (:mod:`diagnose.gain`).
"""

from __future__ import annotations

from functools import cache
from types import SimpleNamespace

import numpy as np
import pandas as pd

from diagnose.accuracy import Instrumentation, instrumentation
from diagnose.arbitration import (
    arbitrate,
    compat_causes,
    rearbitrate,
    refinement_stands,
    residual_delays,
    residual_refinement,
)
from diagnose.causes import merge_sensors, name_causes
from diagnose.config import DiagnosisSettings, using
from diagnose.corrected import Corrected
from diagnose.noise_floor import NoiseFloor, channel_noise, model_sensitivities
from diagnose.residuals import COEFFS
from diagnose.result import Diagnosis
from diagnose.sensor_rivals import instrument_verdict
from diagnose.separation import (
    cause_rivals,
    compose_swaps,
    noise_weights,
    preferred_aero_rivals,
)
from diagnose.stepwise import Lags, candidate_gram, refit, stepwise
from diagnose.terms import candidate_terms, sensor_of
from diagnose.held_out import worse_on_held_out
from diagnose.together import confounded_note, flown_together
from diagnose.verdict import contribution, implausible, judge, rank
from identify.compat import estimate
from identify.logs import Log
from infra.pool import trim_memory

#: The stages :func:`diagnose` reports through ``progress``, and those that follow it, in order.
STAGES = (
    "data compatibility",
    "instrument delays",
    "residuals",
    "stepwise",
    "noise floor",
    "instrument reach",
    "verdict",
    "extension",
    "replays",
    "refine",
    "bands",
    "plots",
)


def _conditions(frame: pd.DataFrame, logs: list[Log], offset: int = 0) -> pd.DataFrame:
    frame = frame.copy()
    frame["log"] = frame["log"] + offset
    keys = {i + offset: "/".join(f"{x:g}" for x in lg.condition) for i, lg in enumerate(logs)}
    frame["condition"] = frame["log"].map(keys)
    return frame


def _parts(causes, coefficient: str, split: list) -> list:
    """The aero causes of ``coefficient`` that share a variable with a term a replacement split."""
    variables = {v for t in split for v in t.variables}
    return [c for c in causes if c.kind == "aero" and c.coefficient == coefficient and set(c.variables) & variables]


def _passes(cause) -> bool:
    return bool(cause.verdict.get("accepted") or cause.verdict.get("unconfirmed"))


def _split_stands(causes, coefficient: str, split: list, dropped: dict) -> bool:
    """A split stands if every part it left is a discrepancy (or it left one cause there after all), none
    of them dropped for falling (:func:`_dropped`)."""
    parts = _parts(causes, coefficient, split)
    fell = {v for t in dropped.get(coefficient, ()) for v in t.variables} & {v for t in split for v in t.variables}
    return not fell and (len(parts) < 2 or all(map(_passes, parts)))


def _whole_stands(causes, coefficient: str, split: list) -> bool:
    """The whole reading (no replacement split) stands if it names a discrepancy where the split was."""
    return any(map(_passes, _parts(causes, coefficient, split)))


def _dropped(causes, dropped: dict) -> tuple[dict, list]:
    """``dropped`` and the terms of each aero cause that fell where a cause of its coefficient stands
    (coefficient -> frozenset of terms), and those causes. The report fits each coefficient with the terms
    of the causes named only, so each is judged on that fit: two terms alike share a residual between them
    with contributions of either sign, each larger than the residual itself. An A320 null with a 0.23 deg
    vane bias in 3 ft/s turbulence named "CD vs alpha_deg" at 0.0076, 15 times its
    floor and past the instrument errors' reach, beside a "CD vs CL, flap_deg" that fell on held-out data;
    the CD residual spans 0.0014, which the bias makes."""
    out, fell = dict(dropped), []
    for coefficient in {c.coefficient for c in causes if c.kind == "aero" and _passes(c)}:
        here = [c for c in causes if c.kind == "aero" and c.coefficient == coefficient and not _passes(c)]
        if here:
            out[coefficient] = out.get(coefficient, frozenset()) | frozenset(t for c in here for t in c.terms)
            fell += here
    return out, fell


def _with_reach(fell: list, causes: list, reach: list) -> list[tuple]:
    """Each cause of ``fell`` with its instrument reach (``reach`` in the order of ``causes``)."""
    return [(f, next(r for c, r in zip(causes, reach) if c is f)) for f in fell]


def diagnose(
    logs: list[Log],
    evaluator,
    held: list[Log] = (),
    step: int | None = None,
    compatibility: bool = True,
    jobs: int = 1,
    progress=None,
    settings: DiagnosisSettings | None = None,
) -> Diagnosis:
    """Residuals against the model, stepwise structure per coefficient, causes and their verdict.

    Parameters
    ----------
    logs : list of Log
        Logs to fit on.
    evaluator : ModelEvaluator
    held : list of Log
        Logs not fitted on; the verdict's leave-one-condition-out check uses them too.
    step : int or None
        Thinning of the residual data (default: about 60 samples per second).
    compatibility : bool
        Estimate the instrument errors first and correct the logs (:mod:`identify.compat`,
        :class:`diagnose.corrected.Corrected`).
    jobs : int
        Worker processes for the residuals and the noise floor's realizations (sets ``evaluator.jobs``).
    progress : callable, optional
        Called with the name of each stage as it starts (:data:`STAGES`).
    settings : DiagnosisSettings, optional
        Every decision threshold (None: the defaults), the data compatibility's among them
        (``settings.compat``); :func:`diagnose.config.current` while the diagnosis runs, and kept in
        the result (``Diagnosis.settings``).

    Raises
    ------
    TypeError
        If ``settings`` is not a :class:`diagnose.config.DiagnosisSettings`.
    """
    with using(settings) as s:
        return _diagnose(logs, evaluator, held, step, compatibility, jobs, progress, s)


def _reach_of(compat, instruments: Instrumentation, logs: list[Log], reach_se: float):
    """The instrument errors the reach and the floor's instrument realizations draw: those the data
    compatibility left uncertain, and (measured data) the specified errors it did not measure
    (:meth:`diagnose.accuracy.Instrumentation.unmeasured`); what the logs hold of each as measured; and the
    errors it could not measure that no specification bounds. Returns ``(uncertain, left, unmeasured,
    declared)``, the last those of ``uncertain`` the specification bounds."""
    names, cov = compat.uncertainty(reach_se) if compat else ([], np.zeros((0, 0)))
    left = list(compat.left_in_logs(names)) if compat else []
    present = set().union(*(set(lg.data.columns) for lg in logs)) if logs else set()
    extra, extra_cov = instruments.unmeasured(list(names), present, reach_se)
    unmeasured = [u for u in (compat.unmeasured if compat else ()) if u not in extra]
    if not names and not extra:
        return None, None, unmeasured, []
    total = np.zeros((len(names) + len(extra),) * 2)
    total[: len(names), : len(names)] = cov
    total[len(names) :, len(names) :] = extra_cov
    return (list(names) + extra, total), np.array(left + [0.0] * len(extra)), unmeasured, extra


def _diagnose(  # noqa: C901
    logs: list[Log],
    evaluator,
    held: list[Log],
    step: int | None,
    compatibility: bool,
    jobs: int,
    progress,
    s: DiagnosisSettings,
) -> Diagnosis:
    """:func:`diagnose` within its settings ``s``."""

    def stage(name: str) -> None:
        trim_memory()  # each stage starts from what the diagnosis holds, not from the last one's peak
        if progress is not None:
            progress(name)

    evaluator.jobs = jobs
    corrected = Corrected(logs, held, evaluator, step)
    instruments = instrumentation(list(logs) + list(held))
    stage("data compatibility")
    compat = estimate(corrected.train, jobs=jobs, settings=s.compat) if compatibility else None
    if compat is not None:
        compat = arbitrate(compat, corrected)
        stage("instrument delays")
        compat = residual_delays(compat, corrected)
        corrected.keep(compat)

    def one_pass(compat, swaps=None, whole=frozenset(), dropped=None, fallen=()):
        logs, held = corrected.logs(compat), corrected.logs(compat, held=True)
        stage("residuals")
        data = corrected.residuals(compat)
        held_data = corrected.residuals(compat, held=True, wait=jobs <= 1) if held else None
        noise = instruments.noise(channel_noise(logs + held))
        # the workers compute the held-out residuals and then the sensitivities beside the stepwise search
        # (once per correction: a later pass of the same one reads them)
        sensitivities = corrected.once(
            ("model sensitivities", compat.correction_key() if compat else None),
            lambda: cache(model_sensitivities(logs, evaluator, noise, jobs)),
        )
        stage("stepwise")
        lags = Lags(data["log"].to_numpy())
        terms = {c: candidate_terms(data, c) for c in COEFFS}
        shared = candidate_gram(data, terms)
        results = {c: stepwise(data, c, terms[c], lags=lags, gram=shared, split=c not in whole) for c in COEFFS}
        del shared
        for c, swap in (swaps or {}).items():
            if not set(swap.values()) & set(results[c].terms):
                results[c] = refit(results[c], [swap.get(t, t) for t in results[c].terms], data)
        dropped, fallen, floor = dict(dropped or {}), list(fallen), None  # fallen: (cause, its reach) as it fell
        for round_ in range(s.drop_rounds + 1):  # each cause judged on the fit it is reported with
            for c, gone in dropped.items():
                if gone & set(results[c].terms):
                    results[c] = refit(results[c], [t for t in results[c].terms if t not in gone], data)
            causes = name_causes(results, data, lags)
            if not round_:
                stage("noise floor")
                held_data = held_data() if callable(held_data) else held_data
                if jobs > 1:
                    sensitivities()  # wanted or not: the workers are then free for what comes next
                uncertain, left, unmeasured, declared = _reach_of(compat, instruments, logs, s.reach_se)
                floor = (
                    NoiseFloor(
                        logs,
                        evaluator,
                        noise,
                        step,
                        s.noise_realizations,
                        uncertain=uncertain,
                        left=left,
                        unmeasured=unmeasured,
                        jobs=jobs,
                        declared=declared,
                        sensitivities=sensitivities,
                    )
                    if causes
                    else None
                )
                data_all = pd.concat(
                    [_conditions(data, logs)] + ([_conditions(held_data, held, len(logs))] if held else []),
                    ignore_index=True,
                )
            groups = [(c.coefficient, c.terms) for c in causes]
            floors = floor.sizes(groups) if causes else []
            stage("instrument reach")
            aero = [c for c in causes if c.kind == "aero"]  # a sensor signature is itself an instrument error
            by_aero = (
                dict(
                    zip(
                        map(id, aero),
                        floor.reach(
                            [(c.coefficient, c.terms, contribution(results[c.coefficient], c, data)) for c in aero],
                            data,
                            weights=noise_weights(data, results, lags),
                            beside={o: r.terms for o, r in results.items()},
                        ),
                    )
                )
                if aero
                else {}
            )
            reach = [by_aero.get(id(c), {"made": 0.0, "left": c.size, "alternatives": []}) for c in causes]
            factors = floor.eiv_factors({v for c in causes for v in c.variables}) if causes else {}
            eiv = [max((factors[v] for v in c.variables), default=1.0) for c in causes]
            stage("verdict")
            judge(causes, results, data_all, floors, eiv, reach, data)
            more, fell = _dropped(causes, dropped)
            if more == dropped or round_ == s.drop_rounds:
                break
            dropped, fallen = more, fallen + _with_reach(fell, causes, reach)
        return SimpleNamespace(
            whole=whole,
            compat=compat,
            logs=logs,
            held=held,
            data=data,
            held_data=held_data,
            noise=noise,
            lags=lags,
            terms=terms,
            results=results,
            causes=causes,
            floor=floor,
            reach=reach,
            dropped=dropped,
            fallen=fallen,
        )

    p = one_pass(compat)
    # the refinement reads every cause, accepted or not: those dropped for falling too, as they fell
    refined = (
        None
        if compat is None
        else residual_refinement(compat, p.causes + [c for c, _ in p.fallen], p.reach + [r for _, r in p.fallen])
    )
    if refined is not None:
        refined = refined._replace(compat=rearbitrate(compat, refined.compat, corrected))
        q = one_pass(refined.compat)
        stands = refinement_stands(refined, p.data, q.data)
        if stands is not None:
            q.compat = stands
            p = q
    split = {c: r.splits for c, r in p.results.items() if r.splits}
    whole = {c for c in split if not _split_stands(p.causes, c, split[c], p.dropped)}
    kept_whole = {}
    while whole:  # a split is two claims, each to stand on its own; if one falls, the whole reading
        w = one_pass(p.compat, whole=frozenset(whole))
        stands = {c for c in whole if _whole_stands(w.causes, c, split[c])}
        if stands == whole:
            p = w
            kept_whole = {c: [t.label for t in split[c]] for c in sorted(whole)}
        whole = stands if stands != whole else set()
    rivals = cause_rivals(p.causes, p.results, p.terms, p.data, p.floor, p.compat, p.lags) if p.causes else []
    swaps, rounds = {}, []
    for _ in range(s.swap_rounds):  # the search's term at entry, with the others in, fits worse than a rival:
        rounds.append(preferred_aero_rivals(p.causes, p.terms, p.data))  # the rival is the cause
        more = compose_swaps(rounds)
        if more == swaps:
            break
        swaps = more
        p = one_pass(p.compat, swaps, p.whole)
        rivals = cause_rivals(p.causes, p.results, p.terms, p.data, p.floor, p.compat, p.lags) if p.causes else []
    for c in p.causes:
        instrument_verdict(c)
    for _ in range(s.drop_rounds):  # ... and the instrument errors that fit better than a cause drop it too
        more, fell = _dropped(p.causes, p.dropped)
        if more == p.dropped:
            break
        p = one_pass(p.compat, swaps, p.whole, more, p.fallen + _with_reach(fell, p.causes, p.reach))
        rivals = cause_rivals(p.causes, p.results, p.terms, p.data, p.floor, p.compat, p.lags) if p.causes else []
        for c in p.causes:
            instrument_verdict(c)
    compat, logs, held, data, held_data, noise = p.compat, p.logs, p.held, p.data, p.held_data, p.noise
    results, causes = p.results, p.causes
    aero_terms = {c: [t for t in r.terms if sensor_of(t.variables[0]) is None] for c, r in results.items()}
    sensors = compat_causes(compat, corrected, data, held_data, aero_terms) if compat else []
    sensors.sort(key=lambda c: -c.evidence["z"])
    # confirmed on held-out conditions first, then the largest: an error in lift shows in drag through
    # the polar too, smaller than in lift
    causes.sort(key=lambda c: rank(c.verdict))
    for c in sensors + causes:  # a sensor error no instrument of its kind makes is no finding
        why = implausible(c) if c.verdict["accepted"] else ""
        if why:
            c.verdict.update(accepted=False, reason=why, implausible=True)
    accepted = merge_sensors([c for c in sensors + causes if c.verdict["accepted"]])
    rejected = [c for c in sensors + causes if not c.verdict["accepted"]] + [c for c, _ in p.fallen]
    while True:  # the accepted causes' fits; a cause that worsens held-out data goes (each pass drops one or more)
        for c in COEFFS:
            keep = [t for cause in accepted if cause.coefficient == c and cause.terms for t in cause.terms]
            if len(keep) != len(results[c].terms):
                results[c] = refit(results[c], [t for t in results[c].terms if t in keep], data)
        worse = worse_on_held_out(accepted, results, data, held_data)
        if not worse:
            break
        accepted = [c for c in accepted if c not in worse]
        rejected += worse
    pairs = flown_together(data)
    for c in accepted + rejected:
        note = confounded_note(c, pairs, s.settled_se) if c.kind == "aero" else None
        if note:
            c.evidence["confounded"] = note
    first = {c: r.alternatives[0] for c, r in results.items() if r.alternatives}
    corrected.forget()
    return Diagnosis(
        data,
        results,
        accepted,
        rejected,
        held_data,
        noise,
        list(evaluator.unset),
        first,
        compat,
        logs,
        held,
        rivals,
        kept_whole,
        s,
        instruments,
        pairs,
    )
