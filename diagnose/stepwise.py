"""Forward-backward stepwise regression of a coefficient's residual on candidate terms, with partial
F-tests on the effective number of independent samples (SIDPAC's stepwise regression)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from scipy import special, stats

from diagnose.config import current as settings_now
from diagnose.terms import Term, connected, tail_twin
from identify.lsq import solve_normal


class Lags:
    """Autocorrelation of a residual within each log, for lags 1..max_lag (cached per dataset).

    Each log's samples sit in one padded vector, ``max_lag`` zeros apart, so a
    single FFT gives every within-log lag product at once.
    """

    def __init__(self, log_id: np.ndarray, max_lag: int = 300) -> None:
        from scipy.fft import next_fast_len

        n = len(log_id)
        starts = np.flatnonzero(np.r_[True, log_id[1:] != log_id[:-1]]) if n else np.zeros(0, int)
        self.max_lag = max_lag
        self.pos = np.arange(n) + max_lag * np.searchsorted(starts, np.arange(n), side="right")
        self.nfft = next_fast_len(int(self.pos[-1]) + 1 + max_lag if n else 1, real=True)

    def n_eff(self, resid: np.ndarray) -> float:
        """Effective number of independent samples: N / (1 + 2 sum rho_k), rho up to its first zero."""
        from scipy import fft

        n = len(resid)
        e = resid - resid.mean()
        r0 = float(e @ e) / n
        if r0 <= 0:
            return float(n)
        z = np.zeros(self.nfft)
        z[self.pos] = e
        f = fft.rfft(z)
        rho = fft.irfft(f.real**2 + f.imag**2, self.nfft)[1 : self.max_lag + 1] / n / r0
        stop = np.flatnonzero(rho <= 0)
        tau = 1.0 + 2.0 * float(np.sum(rho[: stop[0] if stop.size else len(rho)]))
        return max(n / tau, 2.0)


@dataclass
class Fit:
    terms: list[Term]
    beta: np.ndarray
    resid: np.ndarray | None
    rss: float


def fit_terms(y: np.ndarray, cols: list[np.ndarray], terms: list[Term]) -> Fit:
    x = np.column_stack([np.ones(len(y))] + cols) if cols else np.ones((len(y), 1))
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    r = y - x @ beta
    return Fit(list(terms), beta, r, float(r @ r))


def _compact(x: np.ndarray):
    """A design matrix as it is cheapest to hold: sparse (CSR) if most of it is zero (the hat
    columns of a smooth term), else dense."""
    from scipy import sparse

    return sparse.csr_array(x) if np.count_nonzero(x) < 0.5 * x.size else x


def _dense(x) -> np.ndarray:
    return x.toarray() if hasattr(x, "toarray") else x


class Gram:
    """Least-squares fits of any target on any subset of candidate terms, from one cross-product matrix.

    The columns are scaled to unit norm before their cross products are taken; a
    subset's normal equations are solved through an eigendecomposition (directions
    below 1e-12 of the largest dropped, as a rank-revealing solver would), and the
    residual is computed from the data, so its sum of squares does not suffer the
    normal equations' cancellation. Stepwise tries hundreds of subsets; each costs
    one pass over the data instead of a full least-squares solve. The three
    coefficients' residuals share one matrix: their candidates are mostly the same.

    Parameters
    ----------
    ys : dict
        Target name (a coefficient) -> its values (n,).
    designs : dict
        Term -> its design (n, width), dense or sparse.
    """

    BLOCK = 8192

    def __init__(self, ys: dict[str, np.ndarray], designs: dict) -> None:
        self.ys, self.designs = ys, designs
        self.index, at = {}, 1
        for t, x in designs.items():
            self.index[t] = np.arange(at, at + x.shape[1])
            at += x.shape[1]
        self.target = {name: at + k for k, name in enumerate(ys)}
        size = at + len(ys)
        n = len(next(iter(ys.values())))
        gram = np.zeros((size, size))
        for lo in range(0, n, self.BLOCK):  # in row blocks: the full design would be large
            hi = min(lo + self.BLOCK, n)
            a = np.empty((hi - lo, size), order="F")
            a[:, 0] = 1.0
            for t, x in designs.items():
                a[:, self.index[t]] = _dense(x[lo:hi])
            for name, y in ys.items():
                a[:, self.target[name]] = y[lo:hi]
            gram += a.T @ a
        self.scale = np.sqrt(np.diag(gram))
        self.scale[self.scale == 0] = 1.0
        self.gram = gram / np.outer(self.scale, self.scale)

    def fit(self, terms: list[Term], target: str) -> Fit:
        idx = np.concatenate([[0]] + [self.index[t] for t in terms]).astype(int)
        j = self.target[target]
        b = solve_normal(self.gram[np.ix_(idx, idx)], self.gram[idx, j])
        beta = b * self.scale[j] / self.scale[idx]
        r = self.ys[target] - beta[0]
        at = 1
        for t in terms:
            k = self.designs[t].shape[1]
            r = r - self.designs[t] @ beta[at : at + k]
            at += k
        return Fit(list(terms), beta, r, float(r @ r))


def candidate_gram(data: pd.DataFrame, terms: dict[str, list[Term]]) -> Gram:
    """One :class:`Gram` of the residuals ``r_<coefficient>`` of ``data`` on the union of each
    coefficient's candidate ``terms`` (coefficient -> terms), for :func:`stepwise`'s ``gram``."""
    union = dict.fromkeys(t for ts in terms.values() for t in ts)
    union.update(dict.fromkeys(filter(None, (tail_twin(t, data) for t in list(union)))))
    return Gram({c: data[f"r_{c}"].to_numpy() for c in terms}, {t: _compact(t.design(data)) for t in union})


def f_test(small: Fit, big: Fit, k: int, n_eff: float, p_big: int) -> tuple[float, float]:
    dof = max(n_eff - p_big, 1.0)
    f = ((small.rss - big.rss) / k) / (big.rss / dof) if big.rss > 0 else np.inf
    return float(f), float(stats.f.sf(f, k, dof)) if np.isfinite(f) else 0.0


def f_logsf(f: float, d1: float, d2: float) -> float:
    """Natural log of the F(``d1``, ``d2``) distribution's survival function at ``f``.

    scipy's ``f.sf`` underflows to 0 below about 1e-308 and its ``logsf`` to -inf, while the strongest
    candidates of a stepwise step reach 1e-500 and lower (reported in the evidence as ``log10_p``). There
    the survival function is the regularized incomplete beta I_x(d2/2, d1/2) at x = d2 / (d2 + d1 f),
    whose prefactor x^a (1-x)^b / (a B(a, b)) is taken in logs and whose continued fraction (modified
    Lentz) converges fast in this far tail.
    """
    if not np.isfinite(f):
        return -np.inf
    p = float(stats.f.sf(f, d1, d2))
    if p > 1e-280:
        return float(np.log(p))
    a, b = d2 / 2.0, d1 / 2.0
    log_sum = np.logaddexp(np.log(d2), np.log(d1) + np.log(f))  # log(d2 + d1 f), safe where d1 f overflows
    log_x, log_1mx = np.log(d2) - log_sum, np.log(d1) + np.log(f) - log_sum
    x = float(np.exp(log_x))  # below (a + 1) / (a + b + 2) wherever p < 1e-280: the fraction's fast range
    pre = a * log_x + b * log_1mx - np.log(a) - special.betaln(a, b)
    tiny = 1e-300

    def clip(v: float) -> float:
        return v if abs(v) > tiny else tiny

    c, d = 1.0, 1.0 / clip(1.0 - (a + b) * x / (a + 1.0))
    h = d
    for m in range(1, 10000):
        for aa in (
            m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)),
        ):
            d = 1.0 / clip(1.0 + aa * d)
            c = clip(1.0 + aa / c)
            h *= d * c
        if abs(d * c - 1.0) < 1e-13:
            break
    return float(pre + np.log(h))


def rank_on(rows: list[dict], alpha_in: float) -> None:
    """Order a step's candidates (``rows``, each with its own partial F-test): by ``p_value``, then by ``F``;
    but of the candidates as wide as the first that pass (p < ``alpha_in``), the one that leaves the least
    residual comes first.

    Each candidate's own test counts the independent samples of the residual it leaves. The term that
    removes the effect leaves the slow errors beside it (a thrust error, the gusts' low frequencies), few
    independent samples, and ranked below a worse fit whose misfit follows the manoeuvres and looks
    white: an A320 drag in gear x Mach, 29 times its floor, left 1.1 % of the residual by gear x Mach and
    1.9 % by gear x CL, whose own test was 10^160 times stronger. With as many
    columns, on any one effective sample size the better fit is the stronger; the test a term must pass to
    enter is still its own. Between widths the own tests still decide: ranked on one sample size (the
    least of the passing candidates'), terms in alpha or Mach alone came before the interactions of the
    two that were the effects in two simulated cases.
    """
    rows.sort(key=lambda r: (r["p_value"], -r["F"]))
    if rows and rows[0]["p_value"] < alpha_in:
        width = rows[0]["term"].width
        best = min(
            (r for r in rows if r["p_value"] < alpha_in and r["term"].width == width), key=lambda r: r["fit"].rss
        )
        rows.sort(key=lambda r: r is not best)  # stable: the others keep their order


@dataclass
class StepwiseResult:
    """Stepwise regression of one coefficient's residual."""

    coefficient: str
    terms: list[Term]
    beta: np.ndarray  # intercept first, then each term's columns
    evidence: dict[str, dict]
    alternatives: list[dict]  # the first step's candidates in the order they were ranked (:func:`rank_on`)
    rms_before: float
    rms_after: float
    n_eff: float
    close: dict = field(default_factory=dict)  # term label -> rivals nearly as strong when it entered
    splits: list = field(default_factory=list)  # terms a replacement split into causes of their own

    def term_beta(self, term: Term) -> np.ndarray:
        i = 1
        for t in self.terms:
            if t == term:
                return self.beta[i : i + t.width]
            i += t.width
        raise KeyError(term.label)

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        out = np.full(len(frame), self.beta[0])
        for t in self.terms:
            out += t.design(frame) @ self.term_beta(t)
        return out


def stepwise(  # noqa: C901
    data: pd.DataFrame,
    coefficient: str,
    terms: list[Term],
    alpha_in: float | None = None,
    min_reduction: float | None = None,
    max_terms: int | None = None,
    lags: Lags | None = None,
    gram: Gram | None = None,
    split: bool = True,
) -> StepwiseResult:
    """Forward-backward stepwise regression of ``r_<coefficient>`` on candidate terms.

    A term enters if its partial F-test (on the effective sample size of the
    residual after it enters) has p < ``alpha_in`` and it removes at least
    ``min_reduction`` of the initial residual sum of squares (about its mean);
    a term leaves when its removal test no longer passes. ``alpha_in``, ``min_reduction`` and
    ``max_terms`` default to the settings' (:func:`diagnose.config.current`), and so does the share of
    the entering term's F statistic a rival needs (``rival_f_ratio``). ``gram`` (:func:`candidate_gram`),
    if given, holds ``terms`` and this coefficient's residual, and may be shared with the others.
    With ``split`` false, no replacement may name more causes than it replaces (the whole reading,
    :func:`diagnose.diagnosis.diagnose` asks for it when a split's parts do not all pass).
    """
    s = settings_now()
    alpha_in = s.alpha_in if alpha_in is None else alpha_in
    min_reduction = s.min_reduction if min_reduction is None else min_reduction
    max_terms = s.max_terms if max_terms is None else max_terms
    y = data[f"r_{coefficient}"].to_numpy()
    lags = lags or Lags(data["log"].to_numpy())
    if gram is None:
        gram = candidate_gram(data, {coefficient: terms})
    designs = gram.designs
    chosen: list[Term] = []
    close: dict[str, list] = {}
    splits: list[Term] = []
    current = gram.fit([], coefficient)
    rss0 = current.rss
    rms_before = float(np.sqrt(np.mean((y - y.mean()) ** 2)))

    def step(chosen: list[Term], current: Fit):
        """The candidate to enter beside ``chosen`` (leaner if as good, refined with the tails' knots if
        they fit better), the row it entered as (unrefined), and every candidate's row."""
        p_now = 1 + sum(t.width for t in chosen)
        rows = []
        for t in terms:
            if t in chosen or any(
                c.variables == t.variables
                and (
                    c.kind == "smooth"
                    and t.kind in ("linear", "quadratic", "smooth")
                    or c.kind == "quadratic"
                    and t.kind == "linear"
                )
                for c in chosen
            ):
                continue
            big = gram.fit(chosen + [t], coefficient)
            n_eff = lags.n_eff(big.resid)
            f, p = f_test(current, big, t.width, n_eff, p_now + t.width)
            big.resid = None  # a round holds every candidate's fit; the chosen one's residual is recomputed
            rows.append(
                {
                    "term": t,
                    "F": f,
                    "p_value": p,
                    "rss_reduction": (current.rss - big.rss) / rss0,
                    "n_eff": n_eff,
                    "fit": big,
                    "dof": max(n_eff - p_now - t.width, 1.0),
                }
            )
        if not rows:
            return None, None, rows
        rank_on(rows, alpha_in)
        best = rows[0]
        # prefer a leaner term on a subset of the same variables if it does as well
        leaner = sorted(
            (
                r
                for r in rows
                if set(r["term"].variables) <= set(best["term"].variables)
                and r["term"].width < best["term"].width
                and r["p_value"] < alpha_in
            ),
            key=lambda r: r["term"].width,
        )
        for lean in leaner:
            if (
                f_test(
                    lean["fit"],
                    best["fit"],
                    best["term"].width - lean["term"].width,
                    best["n_eff"],
                    p_now + best["term"].width,
                )[1]
                > alpha_in
            ):
                best = lean
                break
        entered = best  # its rivals are those nearly as strong as it, unrefined
        twin = tail_twin(best["term"], data)
        if twin is not None and twin in gram.index:  # refined with the tails' knots if they fit better
            big = gram.fit(chosen + [twin], coefficient)
            n_eff = lags.n_eff(big.resid)
            big.resid = None
            if f_test(best["fit"], big, twin.width - best["term"].width, n_eff, p_now + twin.width)[1] < alpha_in:
                f, p = f_test(current, big, twin.width, n_eff, p_now + twin.width)
                best = {
                    "term": twin,
                    "F": f,
                    "p_value": p,
                    "rss_reduction": (current.rss - big.rss) / rss0,
                    "n_eff": n_eff,
                    "fit": big,
                    "dof": max(n_eff - p_now - twin.width, 1.0),
                }
        return best, entered, rows

    def rivals(best: dict, entered: dict, rows: list[dict]) -> list[dict]:
        mine = set(best["term"].variables)
        return [
            {"term": r["term"].label, "F": r["F"], "F_ratio": r["F"] / entered["F"]}
            for r in rows
            if r is not entered
            and r["p_value"] < alpha_in
            and r["F"] >= s.rival_f_ratio * entered["F"]
            and not set(r["term"].variables) <= mine
            and not mine <= set(r["term"].variables)
        ][:3]

    def replace() -> bool:
        """Sequential replacement: each chosen term taken out in turn and the search's choice put in
        its place, if that fits better with no more columns, or as well with fewer (a term chosen
        early can stand in for two causes that later terms explain better)."""
        nonlocal current
        causes = len(connected(chosen))
        for t in list(chosen):
            rest = [c for c in chosen if c != t]
            best, entered, rows = step(rest, gram.fit(rest, coefficient))
            if best is None or best["term"] == t or best["p_value"] >= alpha_in:
                continue
            u = best["term"]
            better = best["fit"].rss < current.rss * (1 - 1e-9) and u.width <= t.width
            leaner = (
                set(u.variables) <= set(t.variables)
                and u.width < t.width
                and f_test(
                    best["fit"], current, t.width - u.width, lags.n_eff(current.resid), 1 + sum(c.width for c in chosen)
                )[1]
                > alpha_in
            )
            parts = len(connected(rest + [u])) > causes
            if (better or leaner) and (split or not parts):
                if parts:
                    splits.append(t)
                chosen[chosen.index(t)] = u
                close.pop(t.label, None)
                close[u.label] = rivals(best, entered, rows)
                current = gram.fit(chosen, coefficient)
                return True
        return False

    alternatives = []
    for _ in range(2 * max_terms):  # forward-backward, then a replacement; again while one is made
        for _ in range(max_terms - len(chosen)):
            best, entered, rows = step(chosen, current)
            if best is None:
                break
            if not alternatives:
                alternatives = [
                    {
                        "term": r["term"].label,
                        "F": r["F"],
                        "p_value": r["p_value"],
                        "log10_p": f_logsf(r["F"], r["term"].width, r["dof"]) / np.log(10.0),
                        "rss_reduction_pct": 100 * r["rss_reduction"],
                    }
                    for r in rows[:8]
                ]
            if best["p_value"] >= alpha_in or best["rss_reduction"] < min_reduction:
                break
            close[best["term"].label] = rivals(best, entered, rows)
            chosen.append(best["term"])
            current = gram.fit(chosen, coefficient)
            for t in list(chosen[:-1]):  # backward step
                rest = [c for c in chosen if c != t]
                small = gram.fit(rest, coefficient)
                _, p = f_test(small, current, t.width, lags.n_eff(current.resid), 1 + sum(c.width for c in chosen))
                if p >= alpha_in or (small.rss - current.rss) / rss0 < min_reduction / 2:
                    chosen.remove(t)
                    current = small
        if len(chosen) < 2 or not replace():
            break
    current = fit_terms(y, [_dense(designs[c]) for c in chosen], chosen)  # the answer itself by a rank-revealing solver
    n_eff = lags.n_eff(current.resid)
    evidence = _evidence(current, chosen, lambda rest: gram.fit(rest, coefficient), n_eff)
    rms_after = float(np.sqrt(np.mean(current.resid**2)))
    return StepwiseResult(
        coefficient,
        chosen,
        current.beta,
        evidence,
        alternatives,
        rms_before,
        rms_after,
        n_eff,
        {t.label: close.get(t.label, []) for t in chosen},
        splits,
    )


def _evidence(current: Fit, chosen: list[Term], without, n_eff: float, which: list[Term] | None = None) -> dict:
    """Each term's partial F-test in the fit ``current`` of ``chosen`` (``without(rest)``: the fit of the
    others; ``n_eff``: the effective sample size of its residual), for the terms ``which`` (all by default)."""
    p_all = 1 + sum(t.width for t in chosen)
    evidence = {}
    for t in chosen if which is None else which:
        small = without([c for c in chosen if c != t])
        f, p = f_test(small, current, t.width, n_eff, p_all)
        evidence[t.label] = {
            "F": f,
            "p_value": p,
            "dof": [t.width, max(n_eff - p_all, 1.0)],
            "rss_reduction_pct": 100.0 * (1.0 - current.rss / small.rss),
        }
    return evidence


def refit(res: StepwiseResult, keep: list[Term], data: pd.DataFrame) -> StepwiseResult:
    """The same stepwise result with only ``keep`` terms, refitted; a term it did not have (a rival
    swapped in) gets its own partial F-test."""
    y = data[f"r_{res.coefficient}"].to_numpy()
    fit = fit_terms(y, [t.design(data) for t in keep], keep)
    new = [t for t in keep if t.label not in res.evidence]
    evidence = {k: v for k, v in res.evidence.items() if k in {t.label for t in keep}}
    if new:
        evidence.update(
            _evidence(
                fit,
                list(keep),
                lambda rest: fit_terms(y, [t.design(data) for t in rest], rest),
                Lags(data["log"].to_numpy()).n_eff(fit.resid),
                new,
            )
        )
    return StepwiseResult(
        res.coefficient,
        list(keep),
        fit.beta,
        evidence,
        res.alternatives,
        res.rms_before,
        float(np.sqrt(np.mean(fit.resid**2))),
        res.n_eff,
        {k: v for k, v in res.close.items() if k in {t.label for t in keep}},
        res.splits,
    )
