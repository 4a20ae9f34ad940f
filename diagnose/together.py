"""Candidate variables the fitted logs move together: a cause in one of them is confounded with the other.

In a slow deceleration alpha rises as Mach falls; over such data a lift effect in alpha fits as one in Mach,
and the search names whichever its terms happen to favour. Two candidate variables whose correlation over
the fitted samples reaches ``flown_together_corr`` (:class:`diagnose.config.DiagnosisSettings`), and within the
logs ``flown_together_within``, are flown together: each cause in one of them gets its reading in the other as a rival
(:func:`diagnose.separation.rival_hypotheses`), which ``campaign plan`` designs the flights to separate, and
is marked confounded in the report. The flap angle and Mach, set per condition, have their own test
(:mod:`diagnose.flap_mach`).
"""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pandas as pd

from diagnose.config import current
from diagnose.terms import Term

#: The continuous variables tested: the flow states, the pitch controls and the pitch rate.
TESTED = ("alpha_deg", "mach", "elevator_deg", "stabilizer_deg", "qhat_rad")


def _corr(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 or np.std(x[ok]) == 0 or np.std(y[ok]) == 0:
        return 0.0
    return float(np.corrcoef(x[ok], y[ok])[0, 1])


def flown_together(data: pd.DataFrame, corr: float | None = None, within_corr: float | None = None) -> list[dict]:
    """The pairs of candidate variables the fitted samples move together: over all the samples by ``corr``
    or more in magnitude, and within the logs (each log's mean taken off) by ``within_corr``. A pair that moves together
    across the logs only (a trimmed control and the flow state that sets it) is separated by the manoeuvres
    within them; one that moves together within the logs only is separated by the conditions.

    Parameters
    ----------
    data : DataFrame
        The fitted logs' residual data (the variables as columns, ``log`` the log of each sample).
    corr, within_corr : float, optional
        The correlations that make a pair (None: the settings' ``flown_together_corr`` and
        ``flown_together_within``).

    Returns
    -------
    list of dict
        ``variables`` (the pair), ``corr`` (their correlation over the samples [-]) and ``corr_within_logs``;
        strongest first. A variable that varies less than its ``min_std`` within the logs is no candidate
        and makes no pair.
    """
    s = current()
    corr = s.flown_together_corr if corr is None else corr
    within_corr = s.flown_together_within if within_corr is None else within_corr
    live = [v for v in TESTED if v in data]
    within = (
        {v: data[v].to_numpy(float) - data.groupby("log")[v].transform("mean").to_numpy(float) for v in live}
        if "log" in data
        else {}
    )
    live = [v for v in live if v in within and float(np.nanstd(within[v])) >= s.min_std.get(v, 0.0)]
    out = []
    for a, b in combinations(live, 2):
        r, rw = _corr(data[a].to_numpy(float), data[b].to_numpy(float)), _corr(within[a], within[b])
        if abs(r) >= corr and abs(rw) >= within_corr:
            out.append({"variables": [a, b], "corr": r, "corr_within_logs": rw})
    return sorted(out, key=lambda p: -abs(p["corr"]))


def partners(variable: str, pairs: list[dict]) -> list[str]:
    """The variables flown together with ``variable``."""
    return [v for p in pairs if variable in p["variables"] for v in p["variables"] if v != variable]


def in_partner(term: Term, pool: list[Term], pairs: list[dict]) -> list[Term]:
    """The candidates of ``pool`` that are ``term`` with one of its variables replaced by a variable flown
    together with it (the same kind of term), none if no variable of the term has a partner. A curve in one
    variable scaled by its partner (``smooth(mach) x alpha_deg``) has the curve in the partner scaled by it
    (``smooth(alpha_deg) x mach``) as its reading: over a deceleration either may carry a lift lost in alpha."""
    out = []
    if term.kind == "smooth_x_linear" and term.variables[1] in partners(term.variables[0], pairs):
        # a curve in one of the two scaled by the other: its reading is the curve in the other
        out += [t for t in pool if t.kind == term.kind and t.variables == term.variables[::-1]][:1]
    for v in term.variables:
        for u in partners(v, pairs):
            if u in term.variables:
                continue
            want = tuple(u if w == v else w for w in term.variables)
            same = [
                t
                for t in pool
                if t.kind == term.kind
                and (t.variables == want or (t.kind == "product" and sorted(t.variables) == sorted(want)))
            ]
            out += [t for t in same[:1] if t not in out]
    return out


def confounded_note(cause, pairs: list[dict], settled_se: float) -> dict | None:
    """What ``diagnosis.json`` says of a cause in a variable flown together with another: the pairs, and
    its readings in the partner (rivals whose terms are the cause's variables with one swapped for a
    variable flown with it) with their separation [standard errors]; None if no variable of the cause has
    a partner."""
    mine = [p for p in pairs if set(p["variables"]) & set(cause.variables)]
    if not mine:
        return None
    own = set(cause.variables)
    rivals = []
    for r in cause.evidence.get("rivals", []):
        if r.get("kind") != "aero" or not r.get("term"):
            continue
        used = {v for p in mine for v in p["variables"] if v in r["term"]}
        swapped = any(
            u not in own and v in own and v not in r["term"]
            for p in mine
            for u, v in (p["variables"], p["variables"][::-1])
            if u in used
        ) or reversed_curve(r, cause.terms, mine)
        if swapped:
            width = sum(v in r["term"] for v in (*TESTED, "CL", "flap_deg", "gear_norm", "adothat_rad"))
            rivals.append({"rival": r["rival"], "separation_se": r["separation_se"], "variables": width})
    rivals.sort(key=lambda r: (r["variables"], r["separation_se"]))  # the plainest reading first
    for r in rivals:
        r["settled"] = r["separation_se"] >= settled_se
    return {"pairs": mine, "rivals": rivals, "settled": bool(rivals) and all(r["settled"] for r in rivals)}


def reversed_curve(rival: dict, terms, pairs: list[dict]) -> bool:
    """The rival replaces a curve in one variable scaled by another, the two flown together, by the curve
    in the other scaled by the first (``smooth(mach) x alpha_deg`` by ``smooth(alpha_deg) x mach``)."""
    old = next((t for t in terms if t.label == rival.get("replaces")), None)
    return (
        old is not None
        and old.kind == "smooth_x_linear"
        and any(set(p["variables"]) == set(old.variables) for p in pairs)
        and rival["term"] == Term(old.kind, old.variables[::-1]).label
    )


def clusters(pairs: list[dict]) -> list[list[str]]:
    """The variables of ``pairs`` in groups that move together (pairs sharing a variable joined)."""
    out: list[set[str]] = []
    for p in pairs:
        joined = [g for g in out if g & set(p["variables"])]
        out = [g for g in out if g not in joined] + [set(p["variables"]).union(*joined)]
    return [sorted(g, key=TESTED.index) for g in out]


def confounded_text(note: dict) -> str:
    """The report's caution for a confounded cause."""
    pairs = "; ".join(f"{' and '.join(p['variables'])} (correlation {p['corr']:+.2f})" for p in note["pairs"])
    pairs = pairs.replace("; ", ", and ") if len(note["pairs"]) == 2 else pairs
    if note["rivals"]:
        best = note["rivals"][0]
        how = f"its reading {best['rival']} is {best['separation_se']:+.1f} standard errors behind" + (
            ", which these data settle"
            if best["settled"]
            else " (`campaign plan` designs the flight that separates them)"
        )
    else:
        how = "no reading in the other variable could be fitted in its place"
    return f"   confounded: the fitted logs fly {pairs} together: {how}"
