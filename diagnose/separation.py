"""Rival explanations of a cause, and how far data separate them.

A cause the diagnosis names may have rivals: an instrument error that alone would make most of it
(its ``sensor_alternatives``), or another term nearly as strong when it entered
(``hardly_separated_from``). Each explanation is a hypothesis: columns over the stacked residuals of
CL, CD and Cm, each coefficient's rows weighted by one over its noise per effective sample, and, for
an instrument error the data compatibility measured, its estimate as one more observation. All
share an intercept per coefficient and the terms of the other causes on it.

The separation of a cause A from a rival B is the likelihood ratio of their fits in standard errors,
``sqrt(RSS_B - RSS_A)`` (negative when the rival fits better). The same algebra predicts data not
yet flown (:mod:`campaign.design.plan`): A's fit taken as the truth, B refitted to A's prediction leaves
``c - b' G^+ b`` with ``G = Z_B' Z_B``, ``b = Z_B' z_A``, ``c = z_A' z_A`` summed over old and new
rows (T-optimal discrimination, Atkinson and Fedorov 1975), less what A's fitted noise adds to it
(:func:`left`). The old rows enter through these sums, which ``diagnosis.json`` stores; a flight
adds its own.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from diagnose.config import current
from diagnose.noise_floor import design_matrix
from diagnose.residuals import COEFFS
from diagnose.state_twins import (
    in_alpha,
    in_alpha_and_mach,
    in_alpha_for_mach,
    in_flow_states,
    widened,
)
from diagnose.terms import Term, tail_twin
from diagnose.together import flown_together, in_partner, reversed_curve

#: Perturbation of an instrument error whose residual signature is taken (bias in the channel's
#: units, scale [-], delay [s]); the signature is linear in it (the model's answer is linearised).
UNIT = {"bias": 0.1, "scale": 0.01, "delay": 0.01}


def term_to_dict(t: Term) -> dict:
    """A :class:`Term` as JSON (infinite clipping ranges as null)."""
    return {
        "kind": t.kind,
        "variables": list(t.variables),
        "knots": list(t.knots),
        "centers": list(t.centers),
        "ranges": [[None if not np.isfinite(x) else float(x) for x in r] for r in t.ranges],
    }


def term_from_dict(d: dict) -> Term:
    """The inverse of :func:`term_to_dict`."""
    inf = {0: -np.inf, 1: np.inf}
    return Term(
        d["kind"],
        tuple(d["variables"]),
        tuple(float(k) for k in d["knots"]),
        tuple(float(c) for c in d["centers"]),
        tuple(tuple(inf[i] if x is None else float(x) for i, x in enumerate(r)) for r in d["ranges"]),
    )


@dataclass(frozen=True)
class Hypothesis:
    """One explanation of a discrepancy.

    Attributes
    ----------
    name : str
        ``"CL vs alpha_deg"`` or ``"alpha_deg scale"``.
    kind : {"aero", "sensor"}
    coefficient : str
        The coefficient an aero hypothesis acts on.
    terms : tuple of Term
        An aero hypothesis's terms.
    channel, error : str
        A sensor hypothesis's instrument error.
    prior : (float, float) or None
        What the data compatibility measured of that error in the data as corrected: estimate and
        standard error (channel units; scale [-], delay [s]); None if it could not measure it.
    """

    name: str
    kind: str
    coefficient: str = ""
    terms: tuple = ()
    channel: str = ""
    error: str = ""
    prior: tuple | None = None

    @property
    def key(self) -> tuple[str, str]:
        return self.channel, self.error

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "coefficient": self.coefficient,
            "terms": [term_to_dict(t) for t in self.terms],
            "channel": self.channel,
            "error": self.error,
            "prior": None if self.prior is None else [float(x) for x in self.prior],
        }

    @classmethod
    def from_dict(cls, d: dict) -> Hypothesis:
        return cls(
            d["name"],
            d["kind"],
            d.get("coefficient", ""),
            tuple(term_from_dict(t) for t in d["terms"]),
            d.get("channel", ""),
            d.get("error", ""),
            None if d.get("prior") is None else tuple(d["prior"]),
        )


class Stack:
    """One data set's rows, the three coefficients stacked and weighted.

    Parameters
    ----------
    frame : DataFrame
        Residual data: the variables the terms read, and ``r_CL``... if ``y`` is wanted.
    weights : sequence of 3 float
        One over the noise per effective sample of CL, CD and Cm.
    signatures : dict
        (channel, error) -> array (3, n): the residuals one unit of that error makes [per unit].
    context : dict
        Coefficient -> terms of the other causes on it (fitted with every hypothesis).
    """

    def __init__(self, frame: pd.DataFrame, weights, signatures: dict, context: dict) -> None:
        self.frame, self.w, self.sig, self.context = frame, np.asarray(weights, float), signatures, context
        self.n = len(frame)
        self._designs: dict[tuple, np.ndarray] = {}  # terms -> their design (n, widths), the last few kept
        self._triangles: dict[tuple, np.ndarray] = {}  # the blocks' QR triangles (:func:`_blocks`)

    def _design(self, terms) -> np.ndarray:
        key = tuple(terms)
        x = self._designs.pop(key, None)
        x = design_matrix(list(terms), self.frame)[:, 1:] if x is None else x
        self._designs[key] = x  # the newest last: a cause's own terms and its context come back every pair
        while len(self._designs) > 2 + len(self.context):
            del self._designs[next(iter(self._designs))]
        return x

    def nuisance(self, i: int) -> tuple[list[np.ndarray], np.ndarray]:
        """Coefficient ``COEFFS[i]``'s rows of the columns every hypothesis has (its intercept and its
        context terms; the others are zero there), unweighted: the column blocks (n, k each), and where
        their columns stand among all."""
        c = COEFFS[i]
        cols, at = [np.ones((self.n, 1))], [[i]]
        j = len(COEFFS)
        for o in COEFFS:
            terms = self.context.get(o, [])
            width = sum(t.width for t in terms)
            if terms and o == c:
                cols.append(self._design(terms))
                at.append(range(j, j + width))
            j += width
        return cols, np.concatenate([np.asarray(a, int) for a in at])

    def own(self, h: Hypothesis, i: int) -> np.ndarray | None:
        """Coefficient ``COEFFS[i]``'s rows of the hypothesis's own columns, unweighted (None if zero there)."""
        if h.kind == "aero":
            return self._design(h.terms) if h.coefficient == COEFFS[i] else None
        return self.sig[h.key][i][:, None]

    @staticmethod
    def own_width(h: Hypothesis, i: int) -> int:
        """The hypothesis's own columns not zero in coefficient ``COEFFS[i]``'s rows."""
        if h.kind == "aero":
            return sum(t.width for t in h.terms) if h.coefficient == COEFFS[i] else 0
        return 1

    def width(self, h: Hypothesis) -> int:
        """The hypothesis's columns, nuisance and own (the own last)."""
        own = sum(t.width for t in h.terms) if h.kind == "aero" else 1
        return len(COEFFS) + sum(t.width for ts in self.context.values() for t in ts) + own


def _prior_rows(hs: tuple[Hypothesis, Hypothesis]) -> list[tuple[int, float, float]]:
    """(which hypothesis, 1 / se, estimate / se) of each measured instrument error among ``hs``."""
    return [
        (i, 1.0 / h.prior[1], h.prior[0] / h.prior[1])
        for i, h in enumerate(hs)
        if h.kind == "sensor" and h.prior is not None and h.prior[1] > 0
    ]


def left(stats: dict) -> float:
    """What a rival refitted to the truth's prediction leaves, in standard errors.

    ``c - b'G^+b`` is the squared distance; the prediction is the truth's fit to noisy data, whose
    noise the rival cannot follow either: ``tr((H - C'G^+C) V)`` of it (``V``, the fit's
    covariance in these units, from the data it was fitted on) is taken off, so that the
    expectation is the separation the data will show.
    """
    g, b = np.asarray(stats["G"], float), np.asarray(stats["b"], float)
    gi = np.linalg.pinv(g, rcond=1e-12)
    lam = float(stats["c"]) - float(b @ gi @ b)
    if "V" in stats:
        h, cr = np.asarray(stats["H"], float), np.asarray(stats["C"], float)
        lam -= float(np.trace((h - cr.T @ gi @ cr) @ np.asarray(stats["V"], float)))
    return float(np.sqrt(max(lam, 0.0)))


#: Rows factorized at a time (:func:`_blocks`): the triangles of row blocks are stacked and factorized again.
QR_ROWS = 16384


def _blocks(stack: Stack, hs, residuals: bool = True) -> list[tuple]:
    """Each coefficient's rows of the stacked designs of ``hs``, reduced to the triangle R of the QR
    factorization of their columns not zero there (the nuisance's, then each hypothesis's own, once if
    they are the same) and of the weighted residual last (with ``residuals``), rows where any of them
    is not finite left out: ``(R, [(R's columns, where they stand in the design) per hypothesis])``.
    ``R[:, cols]`` has the cross products of the design's rows and the part of the residual in their span:
    everything the least squares and the sums of :func:`left` need. The rows are factorized
    :data:`QR_ROWS` at a time and their triangles factorized together (the memory a block of rows needs);
    a block of the nuisance alone is factorized once per stack."""
    out = []
    for i, c in enumerate(COEFFS):
        at = stack.nuisance(i)[1]
        widths = [stack.own_width(h, i) for h in hs]
        same = len(hs) == 2 and (hs[0] == hs[1] or not any(widths))
        k, j, ends = len(at), len(at), []
        for width in widths:
            start = k if same else j
            ends.append(np.r_[np.arange(k), start : start + width])
            j = start + width

        def make(i: int = i, c: str = c) -> np.ndarray:
            cols = stack.nuisance(i)[0]
            own = [stack.own(h, i) for h in hs]
            cols += [o for o in (own[:1] if same else own) if o is not None]
            if residuals:
                cols.append(stack.frame[f"r_{c}"].to_numpy(float)[:, None])
            tri = []
            for lo in range(0, stack.n, QR_ROWS):
                m = np.hstack([x[lo : lo + QR_ROWS] for x in cols]) * stack.w[i]
                ok = np.isfinite(m).all(axis=1)
                m = m if ok.all() else m[ok]
                if len(m):
                    tri.append(np.linalg.qr(m, mode="r"))
            width = sum(x.shape[1] for x in cols)
            return np.linalg.qr(np.vstack(tri), mode="r") if tri else np.zeros((0, width))

        key = (i, residuals)  # the nuisance alone is the same in every pair of the stack
        r = make() if any(widths) else stack._triangles.get(key)
        r = stack._triangles.setdefault(key, make()) if r is None else r
        places = [np.r_[at, stack.width(h) - width + np.arange(width)] for h, width in zip(hs, widths)]
        out.append((r, list(zip(ends, places))))
    return out


def _min_norm(x: np.ndarray, y: np.ndarray, rows: int) -> tuple[np.ndarray, int]:
    """The minimum-norm least-squares solution of ``x theta = y`` and ``x``'s rank, singular values at or
    below ``eps * rows`` of the largest taken as zero (NumPy's ``lstsq`` and ``matrix_rank`` defaults for a
    design of ``rows`` rows, which ``x`` stands for)."""
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    keep = s > s.max(initial=0.0) * rows * np.finfo(float).eps
    return vt[keep].T @ ((u[:, keep].T @ y) / s[keep]), int(keep.sum())


def _design_of(blocks: list, k: int, width: int) -> list[np.ndarray]:
    """Hypothesis ``k``'s rows of each block's triangle, in the design's column order (zero elsewhere)."""
    out = []
    for r, parts in blocks:
        cols, places = parts[k]
        z = np.zeros((r.shape[0], width))
        z[:, places] = r[:, cols]
        out.append(z)
    return out


def pair(stack: Stack, a: Hypothesis, b: Hypothesis) -> dict:
    """A cause ``a`` and its rival ``b`` fitted to ``stack``'s residuals.

    Each coefficient's rows are reduced to the triangle of their QR factorization (:func:`_blocks`), and
    the triangles and the data compatibility's rows solved together: the same least squares as the whole
    stacked design (a minimum-norm solution, its rank at NumPy's ``lstsq`` and ``matrix_rank`` tolerance
    for that design's shape), at a small part of its cost and memory.

    Returns
    -------
    dict
        ``separation_se`` (the likelihood ratio in standard errors, less what the cause's extra
        columns fit of noise alone; negative if the rival fits better), ``by_coefficient`` (that
        likelihood ratio's share from each coefficient's rows and from the data compatibility's
        measurement, in squared standard errors), ``predicted_se`` (what the fits, taken as the
        truth each way, separate on these rows; the smaller way), ``theta`` (each fit's nuisance
        and own coefficients) and ``stats`` (the sums of :func:`left` each way: a as the truth,
        then b), as JSON.
    """
    hs = (a, b)
    priors = _prior_rows(hs)
    widths = [stack.width(h) for h in hs]
    blocks = _blocks(stack, hs)
    y = [r[:, -1] for r, _ in blocks] + [np.array([t]) for _, _, t in priors]
    zs = []
    for k in range(2):
        rows = _design_of(blocks, k, widths[k])
        for i, w, _ in priors:
            rows.append(np.zeros((1, widths[k])))
            rows[-1][0, -1] = w if i == k else 0.0
        zs.append(rows)
    fits = [
        _min_norm(np.vstack(z), np.concatenate(y), max(3 * stack.n + len(priors), widths[k])) for k, z in enumerate(zs)
    ]
    thetas = [th for th, _ in fits]
    fitted = [[zb @ th for zb in z] for z, th in zip(zs, thetas)]  # each block's part of the residual's span
    # RSS within each block's span (what lies outside it, the same for both, cancels in every difference)
    rss = [[float(np.sum((yb - f) ** 2)) for yb, f in zip(y, fk)] for fk in fitted]
    # a hypothesis with more columns fits more noise: E[RSS_B - RSS_A] = lambda + p_A - p_B
    d = sum(rss[1]) - sum(rss[0]) - (fits[0][1] - fits[1][1])
    by = {c: rss[1][i] - rss[0][i] for i, c in enumerate(COEFFS)}
    by["data compatibility"] = float(sum(rss[1][3:]) - sum(rss[0][3:]))
    stats = [_sums(zs[1], zs[0], fitted[0]), _sums(zs[0], zs[1], fitted[1])]
    for st in stats:
        st["V"] = np.linalg.pinv(st["H"], rcond=1e-12, hermitian=True)
    return {
        "cause": a.name,
        "rival": b.name,
        "kind": b.kind,
        "hypotheses": [a.to_dict(), b.to_dict()],
        "separation_se": float(np.sign(d) * np.sqrt(abs(d))),
        "predicted_se": min(left(s) for s in stats),
        "by_coefficient": by,
        "theta": [t.tolist() for t in thetas],
        "weights": stack.w.tolist(),
        "stats": [{k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in st.items()} for st in stats],
    }


def _sums(zb: list[np.ndarray], za: list[np.ndarray], za_hat: list[np.ndarray]) -> dict:
    """The sums of one way over some rows, block by block: the rival's design ``zb``, the truth's ``za``
    and its prediction ``za_hat`` make ``G = zb'zb``, ``b = zb'za_hat``, ``c = za_hat'za_hat``,
    ``H = za'za`` and ``C = zb'za``."""
    return {
        "G": sum(x.T @ x for x in zb),
        "b": sum(x.T @ f for x, f in zip(zb, za_hat)),
        "c": float(sum(f @ f for f in za_hat)),
        "H": sum(x.T @ x for x in za),
        "C": sum(u.T @ v for u, v in zip(zb, za)),
    }


def unclipped(t: Term) -> Term:
    """The term with its linear factors no longer clipped to the old data's range: new flights go
    beyond it, and a diagnosis of old and new data together sets its ranges on both."""
    return replace(t, ranges=tuple((-np.inf, np.inf) for _ in t.ranges))


def predicted(stack: Stack, doc: dict) -> list[dict]:
    """The sums of a :func:`pair` document's two ways over ``stack``'s rows (new data: the fits of
    the old ones taken as the truth, their terms :func:`unclipped`; no instrument-error
    observation), to add to the old sums."""
    hs = [
        replace(h, terms=tuple(unclipped(t) for t in h.terms))
        for h in (Hypothesis.from_dict(d) for d in doc["hypotheses"])
    ]
    blocks = _blocks(stack, hs, residuals=False)
    zs = [_design_of(blocks, k, stack.width(h)) for k, h in enumerate(hs)]
    out = []
    for truth, rival in ((0, 1), (1, 0)):
        theta = np.asarray(doc["theta"][truth], float)
        out.append(_sums(zs[rival], zs[truth], [z @ theta for z in zs[truth]]))
    return out


def add(a: list[dict], b: list[dict]) -> list[dict]:
    """Sums of two data sets, each way (the fit's covariance ``V`` stays the first's: the fit
    was made on it)."""
    out = []
    for x, y in zip(a, b):
        z = {k: np.asarray(x[k], float) + np.asarray(y[k], float) for k in ("G", "b", "H", "C")}
        z["c"] = float(x["c"]) + float(y["c"])
        if "V" in x:
            z["V"] = np.asarray(x["V"], float)
        out.append(z)
    return out


def separation(stats: list[dict]) -> float:
    """The smaller of the two ways' :func:`left`: the separation whichever hypothesis is true."""
    return min(left(s) for s in stats)


def noise_weights(data: pd.DataFrame, results: dict, lags) -> np.ndarray:
    """One over each coefficient's residual noise per effective sample, after its fitted terms:
    ``sqrt(n_eff / n) / rms`` (an autocorrelated residual counts fewer independent samples)."""
    w = []
    for c in COEFFS:
        e = data[f"r_{c}"].to_numpy(float) - results[c].predict(data)
        ok = np.isfinite(e)
        rms = float(np.sqrt(np.mean(e[ok] ** 2))) if ok.any() else 0.0
        n_eff = lags.n_eff(np.where(ok, e, 0.0)) * ok.mean()
        w.append(np.sqrt(n_eff / max(int(ok.sum()), 1)) / rms if rms > 0 else 0.0)
    return np.array(w)


def compat_prior(compat, channel: str, error: str) -> tuple[float, float] | None:
    """What the data compatibility measured of an instrument error in the logs as corrected."""
    if compat is None:
        return None
    try:
        p = compat.get(f"{channel}.{error}")
    except (KeyError, StopIteration):
        return None
    if not p.identifiable or not np.isfinite(p.se) or p.se <= 0:
        return None
    return (0.0 if p.applied else float(p.estimate), float(p.se))


def signatures(floor, keys) -> dict:
    """(channel, error) -> the residuals (3, n) one unit of each error makes in ``floor``'s logs."""
    keys = sorted(set(keys))
    frames = (
        floor.realization_batch(
            set(), [{"k": 0, "noise": False, "errors": np.array([UNIT[e]]), "names": [(ch, e)]} for ch, e in keys]
        )
        if keys
        else []
    )
    return {k: np.stack([f[f"r_{c}"].to_numpy(float) for c in COEFFS]) / UNIT[k[1]] for k, f in zip(keys, frames)}


def refined_alike(rival: Term, term: Term, pool: list[Term], data: pd.DataFrame | None) -> Term:
    """``rival`` refined with the tails' knots on ``data`` if ``term`` was (it is then not in the
    candidate ``pool``), and if it can be."""
    return (tail_twin(rival, data) or rival) if data is not None and term not in pool else rival


def rival_hypotheses(
    cause, result, pool: list[Term], alternatives: list[dict], compat, data: pd.DataFrame | None = None
) -> list[Hypothesis]:
    """A cause's rivals: the instrument errors the verdict names beside it (``sensor_alternatives``:
    they alone make most of it at a plausible size), and each term nearly as strong as one of its
    terms when that entered (the cause with that term swapped), and, for a term in CL, the same term in
    alpha (:func:`diagnose.state_twins.in_alpha`), and for a term in CL alone every candidate in alpha and Mach together
    (:func:`diagnose.state_twins.in_alpha_and_mach`: an A320 Cm table in alpha growing with Mach, 14 times its floor, was
    named "Cm vs CL" when only quadratic(alpha), 12.5 standard errors behind, was its rival), and for a term
    in Mach, the same in alpha (:func:`diagnose.state_twins.in_alpha_for_mach`).
    In place of a smooth term the search refined with the tails' knots (:func:`diagnose.terms.tail_twin`),
    a rival is refined alike if it can be, on ``data``: a Cm table in alpha on the stock 737, 25.8 times
    its floor, was named "Cm vs CL" when smooth(CL), refined, met smooth(alpha) unrefined."""
    out = []
    pairs = flown_together(data) if data is not None else []  # a variable flown with another: that one too
    for a in alternatives:
        out.append(
            Hypothesis(
                f"{a['channel']} {a['error']}",
                "sensor",
                channel=a["channel"],
                error=a["error"],
                prior=compat_prior(compat, a["channel"], a["error"]),
            )
        )
    by_label = {t.label: t for t in pool}
    for t in cause.terms:
        close = [by_label.get(a["term"]) for a in result.close.get(t.label, [])]
        twin = in_alpha(t, pool)  # always rivals: they fit alike (``state_se``)
        states = (
            ([twin] if twin is not None else [])
            + in_alpha_and_mach(t, pool)
            + in_flow_states(t, pool)
            + in_alpha_for_mach(t, pool)
            + (in_partner(t, pool, pairs) if pairs else [])
        )
        states = list(dict.fromkeys(states))
        for r in close + [u for u in states if u not in close]:
            if r is None:
                continue
            r = refined_alike(r, t, pool, data)
            terms = tuple(r if u == t else u for u in cause.terms)
            out.append(
                Hypothesis(
                    f"{cause.coefficient}: {' + '.join(u.label for u in terms)}", "aero", cause.coefficient, terms
                )
            )
    return out


def finer(term: Term, pool: list[Term]) -> Term:
    """``term`` in its variable with twice the knots (a knot between each two): for a term that is not
    smooth, the pool's smooth term in the same variable so refined (``term`` itself if there is none)."""
    base = (
        term
        if term.kind == "smooth"
        else next((t for t in pool if t.kind == "smooth" and t.variables == term.variables), None)
    )
    if base is None:
        return term
    k = np.asarray(base.knots, float)
    return replace(base, knots=tuple(np.sort(np.concatenate([k, (k[1:] + k[:-1]) / 2]))))


def wider_hypotheses(cause, pool: list[Term], data: pd.DataFrame | None = None) -> list[tuple[Hypothesis, Hypothesis]]:
    """The cause with one of its terms in alpha alone or Mach alone put in both
    (:func:`diagnose.state_twins.widened`, refined alike), each beside the cause with that term
    :func:`finer` instead. They are kept apart from its rivals: each holds the cause, so no flight
    separates them the other way (`campaign plan`), and they replace a term only when the data prefer
    them by ``wider_se`` to both. A smooth term times the other variable adds knots' worth of columns
    in the term's own variable too (trimmed alpha falls as Mach rises, and within one knot interval each
    condition visits its own part): a synthetic Cm dead band in alpha alone, fitted by smooth(alpha),
    preferred smooth(alpha) x Mach by 6-9 standard errors, and smooth(alpha) with twice the knots by about
    30 to it (``tests/test_plan.py``)."""
    out = []
    for t in cause.terms:
        fine = Hypothesis(
            f"{cause.coefficient}: finer",
            "aero",
            cause.coefficient,
            tuple(finer(t, pool) if u == t else u for u in cause.terms),
        )
        for w in widened(t, pool):
            w = refined_alike(w, t, pool, data)
            if w in cause.terms:
                continue
            terms = tuple(w if u == t else u for u in cause.terms)
            out.append(
                (
                    Hypothesis(
                        f"{cause.coefficient}: {' + '.join(u.label for u in terms)}", "aero", cause.coefficient, terms
                    ),
                    fine,
                )
            )
    return out


def cause_rivals(causes, results: dict, pools: dict, data: pd.DataFrame, floor, compat, lags) -> list[dict]:
    """:func:`pair` of every named (or unconfirmed) aero cause with each of its rivals.

    Parameters
    ----------
    causes : list of Cause
        After the verdict.
    results : dict
        Coefficient -> StepwiseResult.
    pools : dict
        Coefficient -> candidate terms.
    data : DataFrame
        The residual data fitted on.
    floor : NoiseFloor
        Of the same logs (the instrument errors' signatures).
    compat : CompatResult or None
    lags : Lags
    """
    aero = [c for c in causes if c.kind == "aero" and (c.verdict.get("accepted") or c.verdict.get("unconfirmed"))]
    rivals = {
        id(c): rival_hypotheses(
            c, results[c.coefficient], pools[c.coefficient], c.evidence.get("sensor_alternatives", []), compat, data
        )
        for c in aero
    }
    wider = {id(c): wider_hypotheses(c, pools[c.coefficient], data) for c in aero}
    if not any(rivals.values()) and not any(wider.values()):
        return []
    weights = noise_weights(data, results, lags)
    sig = signatures(floor, [h.key for hs in rivals.values() for h in hs if h.kind == "sensor"])
    out = []
    for c in aero:
        if not rivals[id(c)] and not wider[id(c)]:
            continue
        context = {k: [t for o in aero if o is not c and o.coefficient == k for t in o.terms] for k in COEFFS}
        stack = Stack(data, weights, sig, context)
        mine = Hypothesis(c.label, "aero", c.coefficient, tuple(c.terms))
        for h, fine in wider[id(c)]:
            c.evidence.setdefault("wider_rivals", []).append(
                {
                    "rival": h.name,
                    "kind": "aero",
                    "term": next(t.label for t in h.terms if t not in c.terms),
                    "replaces": next(t.label for t in c.terms if t not in h.terms),
                    "separation_se": pair(stack, mine, h)["separation_se"],
                    "finer_separation_se": pair(stack, fine, h)["separation_se"],
                }
            )
        for h in rivals[id(c)]:
            doc = pair(stack, mine, h)
            doc["context"] = {k: [term_to_dict(t) for t in v] for k, v in context.items()}
            out.append(doc)
            swapped = [t.label for t in h.terms if t not in c.terms]
            replaced = [t.label for t in c.terms if t not in h.terms] if h.kind == "aero" else []
            c.evidence.setdefault("rivals", []).append(
                {
                    "rival": h.name,
                    "kind": h.kind,
                    "term": swapped[0] if swapped else None,
                    "replaces": replaced[0] if replaced else None,
                    "channel": h.channel or None,
                    "error": h.error or None,
                    "separation_se": doc["separation_se"],
                    "predicted_se": doc["predicted_se"],
                    "by_coefficient": doc["by_coefficient"],
                }
            )
    return out


def preferred_aero_rivals(causes, pools: dict, data: pd.DataFrame | None = None) -> dict[str, dict[Term, Term]]:
    """The terms to swap: for each named cause, the aerodynamic rival (one of its terms swapped for one
    nearly as strong when it entered) that the data prefer by ``swap_se`` or more, as coefficient ->
    {the cause's term: the rival's}. The stepwise search takes the strongest term at each step; with the
    others in, another can fit better (sequential replacement). A Cm rise in alpha that saturates, on the
    A320, entered as "Cm vs CL" (quadratic in CL); alpha x Mach then fitted Cm 9.6 standard errors better.
    A term in CL gives way to the same term in alpha, or in the model's own variables in place of CL (its
    other variables kept), unless the data prefer CL by ``state_se``; every term of the cause in CL that
    has such a rival gives way with the first (a stock-737 drag dip in gear times alpha, 14 times its floor,
    entered as linear(CL) and smooth(gear) x CL; only the first gave way, to quadratic(alpha), and the cause
    fell apart into "CD vs alpha" and "CD vs gear_norm, CL", with gear x alpha 0.3 standard errors behind
    the second), to the variable the first took in place of CL where it has such a
    rival (one lift stood for one state: gear x elevator fitted 0.95 better than gear x CL there). In
    place of a term refined with the tails' knots, the rival goes in refined alike (on ``data``), as it
    was judged (:func:`rival_hypotheses`). A term in CL alone gives way to one in alpha and Mach together
    only if no other rival will do: with the more columns it fits better, and a stock-737 drag in alpha
    times a dip in gear was named in Mach too. A term in the elevator (or the
    stabilizer) times another variable gives way to the same term in alpha or Mach as a term in CL does
    (:func:`diagnose.state_twins.in_flow_states`). A curve in one of two variables flown together, scaled by
    the other, never gives way to the curve in the other (:func:`diagnose.together.reversed_curve`): that
    reading is reported and planned for, not taken. The two differ most where they extrapolate: on the
    ATTAS's stall records the pitching moment as a curve in alpha (beside alpha x stabilizer) fitted the
    fitted record 4.3 standard errors better than the search's curve in Mach, and taken, flew the held-out
    stall, which reaches 0.7 deg more alpha, to 16.9 deg of pitch error; the search's own flies it to 4.5."""
    s = current()
    out: dict[str, dict[Term, Term]] = {}
    taken: dict[str, set[str]] = {}  # each rival goes in once
    pairs = flown_together(data) if data is not None else []
    for c in causes:
        if c.kind != "aero" or not c.verdict.get("accepted"):
            continue
        pool = pools[c.coefficient]
        by_label = {t.label: t for t in pool}
        own = {t.label: t for t in c.terms}

        def in_states(r: dict, own: dict = own, by_label: dict = by_label, pool: list = pool) -> bool:
            # the term in CL or a trimmed control, the rival in the model's own states
            old, new = own.get(r.get("replaces")), by_label.get(r["term"])
            return (
                old is not None
                and new is not None
                and (
                    "CL" in old.variables
                    and "CL" not in new.variables
                    and set(old.variables) - {"CL"} <= set(new.variables)
                    or new in in_flow_states(old, pool)
                )
            )

        def and_mach(r: dict, own: dict = own, by_label: dict = by_label, pool: list = pool) -> bool:
            # a rival in alpha and Mach together for a term in CL alone
            old, new = own.get(r.get("replaces")), by_label.get(r["term"])
            return old is not None and new is not None and new in in_alpha_and_mach(old, pool)

        better = [
            r
            for r in c.evidence.get("rivals", [])
            if r["kind"] == "aero"
            and r["term"]
            and not reversed_curve(r, c.terms, pairs)
            and (r["separation_se"] <= -s.swap_se or in_states(r) and r["separation_se"] < s.state_se)
        ]
        better += [
            r
            for r in c.evidence.get("wider_rivals", [])
            if max(r["separation_se"], r["finer_separation_se"]) <= -s.wider_se
        ]
        plain = {r.get("replaces") for r in better if not and_mach(r)}
        better = [r for r in better if not and_mach(r) or r.get("replaces") not in plain]  # Mach if alpha will not do
        if not better:
            continue
        r = min(better, key=lambda r: r["separation_se"])
        chosen = [r]

        def put(x: dict, own: dict = own, by_label: dict = by_label) -> set[str]:
            # the variables a rival puts in place of the term's
            return (
                set(by_label[x["term"]].variables) - set(own[x["replaces"]].variables)
                if x["term"] in by_label and x.get("replaces") in own
                else set()
            )

        for label in own:  # the cause's other terms in CL give way alike: to the same state as the first if they can
            alike = [x for x in better if x.get("replaces") == label != r.get("replaces") and in_states(x)]
            if alike:
                chosen.append(min(alike, key=lambda x: (not put(x) & put(r), x["separation_se"])))
        for x in chosen:
            old = [t for t in c.terms if t.label == x.get("replaces")]
            if old and x["term"] in by_label and x["term"] not in taken.setdefault(c.coefficient, set()) | set(own):
                taken[c.coefficient].add(x["term"])
                out.setdefault(c.coefficient, {})[old[0]] = refined_alike(
                    by_label[x["term"]], old[0], pools[c.coefficient], data
                )
    return out


def compose_swaps(rounds: list[dict[str, dict[Term, Term]]]) -> dict[str, dict[Term, Term]]:
    """The swaps of successive rounds of :func:`preferred_aero_rivals` as one (coefficient -> {the
    search's term: the term in its place}): a later swap of a term that is itself in the place of one
    of the search's replaces that one. A term that gave way in an earlier round never comes back."""
    out: dict[str, dict[Term, Term]] = {}
    gone: dict[str, set[Term]] = {}
    for new in rounds:
        for c, m in new.items():
            cur, away = out.setdefault(c, {}), gone.setdefault(c, set())
            for a, b in m.items():
                if b in away or b in cur:
                    continue
                firsts = [k for k, v in cur.items() if v == a]
                for k in firsts or [a]:
                    cur[k] = b
                away.add(a)
    return {c: m for c, m in out.items() if m}
