"""Diagnosis: what the model gets wrong, which variables explain it, and how.

1. Residuals. Measured eq. (1) coefficients minus the model's own prediction
   at the measured states (JSBSim computes it: :mod:`identify.evaluate`). Cm
   is taken about the aerodynamic reference point, where JSBSim applies the aero
   forces, so a lift or drag discrepancy does not leak into Cm.
2. Model structure. Forward-backward stepwise regression of each residual on
   a pool of candidate terms: every logged variable, linear and smooth (a
   piecewise-linear basis), and pairwise interactions. A term enters by a
   partial F-test whose degrees of freedom count the effective number of
   independent samples (residuals are autocorrelated), and only if it
   removes a meaningful share of the residual; a term leaves when it no
   longer passes (SIDPAC's stepwise regression, with those two corrections).
3. Causes. Selected terms that share a variable form one cause (a gear effect
   and its gear x alpha interaction: one gear effect that depends on alpha).
   Causes are ranked by the F statistic of removing them.
4. Extension. The fitted terms, written as JSBSim functions (tables on the
   variables' properties), to merge into a copy of the model.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from itertools import combinations

import numpy as np
import pandas as pd
from scipy import stats

from identify.compat import APPLY_Z, CompatResult, estimate
from identify.logs import Log
from identify.lsq import solve_normal
from identify.noise_floor import (REACH_SE, RESOLUTION, NoiseFloor, channel_noise, design_matrix,
                                  model_sensitivities)
from identify.residuals import COEFFS, SIGNATURES, VARIABLES, residual_data

#: Rates normalised by cbar/2V: exported as linear terms (products of properties), never as tables.
RATES = {"qhat_rad": "velocities/q-aero-rad_sec", "adothat_rad": "aero/alphadot-rad_sec"}
#: Variables a coefficient's residual may not be regressed on (they contain that residual).
EXCLUDED = {"CL": ("CL",)}
#: A variable must vary at least this much (std) to be a candidate.
MIN_STD = {"gear_norm": 0.05, "alpha_deg": 0.1, "mach": 0.002, "flap_deg": 0.5, "elevator_deg": 0.1,
           "stabilizer_deg": 0.1, "qhat_rad": 1e-5, "adothat_rad": 1e-5, "CL": 0.01}
GEAR_KNOTS = tuple(np.round(np.linspace(0.0, 1.0, 11), 10))


def _hats(x: np.ndarray, knots: tuple[float, ...], out: np.ndarray | None = None) -> np.ndarray:
    """Piecewise-linear basis without the first knot's column (the reference): column j is 1 at
    knots[j + 1], 0 at the other knots (flat outside); written into ``out`` (n, len(knots) - 1) if given."""
    k = np.asarray(knots, dtype=float)
    out = np.empty((len(x), len(k) - 1)) if out is None else out
    out[:] = 0.0
    # each sample in one interval [k[j], k[j + 1]]: np.interp's arithmetic for its two hats, slope
    # times the distance from the left knot plus the left value, one pass instead of one per knot
    j = np.clip(np.searchsorted(k, x, side="right") - 1, 0, len(k) - 2)
    lo, width = k[j], k[j + 1] - k[j]
    inside = (x >= k[0]) & (x < k[-1])
    rows = np.flatnonzero(inside)
    out[rows, j[rows]] = (1.0 / width[rows]) * (x[rows] - lo[rows])
    rows = rows[j[rows] >= 1]
    out[rows, j[rows] - 1] = (-1.0 / width[rows]) * (x[rows] - lo[rows]) + 1.0
    out[x >= k[-1], -1] = 1.0
    out[np.isnan(x)] = np.nan
    return out


@dataclass(frozen=True)
class Term:
    """A candidate group of regressors.

    kind : "linear" | "quadratic" | "smooth" | "product" | "smooth_x_linear"
        Higher terms carry the lower ones (hierarchy): ``quadratic`` is a and
        a^2 (an induced-drag law in CL), ``product`` is a, b and a*b,
        ``smooth_x_linear`` is smooth(a) and smooth(a)*b.
    variables : the log columns it uses (first is the smooth one for smooth_x_linear)
    knots : knots of the smooth variable (the first knot is the reference: dropped)
    centers, ranges : centring and clipping of the linear factors
    """

    kind: str
    variables: tuple[str, ...]
    knots: tuple[float, ...] = ()
    centers: tuple[float, ...] = ()
    ranges: tuple[tuple[float, float], ...] = ()

    @property
    def label(self) -> str:
        v = " x ".join(self.variables)
        if self.kind == "smooth_x_linear":
            return f"smooth({self.variables[0]}) x {self.variables[1]}"
        return {"linear": f"linear({v})", "quadratic": f"quadratic({v})", "smooth": f"smooth({v})",
                "product": v}[self.kind]

    def _lin(self, frame: pd.DataFrame, i: int) -> np.ndarray:
        v = self.variables[i]
        lo, hi = self.ranges[i]
        return np.clip(frame[v].to_numpy(), lo, hi) - self.centers[i]

    def design(self, frame: pd.DataFrame, out: np.ndarray | None = None) -> np.ndarray:
        """The term's columns over ``frame`` (n, :attr:`width`), written into ``out`` if given."""
        out = np.empty((len(frame), self.width)) if out is None else out
        if self.kind in ("smooth", "smooth_x_linear"):
            k = len(self.knots) - 1
            h = _hats(frame[self.variables[0]].to_numpy(), self.knots, out[:, :k])
            if self.kind == "smooth_x_linear":
                np.multiply(h, self._lin(frame, 1)[:, None], out=out[:, k:])
            return out
        a = self._lin(frame, 0)
        out[:, 0] = a
        if self.kind == "quadratic":
            out[:, 1] = a * a
        elif self.kind == "product":
            b = self._lin(frame, 1)
            out[:, 1] = b
            out[:, 2] = a * b
        return out

    @property
    def width(self) -> int:
        return {"linear": 1, "quadratic": 2, "product": 3, "smooth": len(self.knots) - 1,
                "smooth_x_linear": 2 * (len(self.knots) - 1)}[self.kind]


#: Smooth terms' knots are at least this share of the variable's range apart: a narrow interval
#: inside a cluster of trimmed values is excited by sensor noise alone (errors-in-variables).
MIN_KNOT_SPACING = 0.1


def _spread(knots: np.ndarray) -> tuple[float, ...]:
    """Quantile knots thinned so that neighbours are at least :data:`MIN_KNOT_SPACING` of the range apart."""
    gap = MIN_KNOT_SPACING * float(knots[-1] - knots[0])
    out = [float(knots[0])]
    for k in knots[1:-1]:
        if k - out[-1] >= gap and knots[-1] - k >= gap:
            out.append(float(k))
    out.append(float(knots[-1]))
    return tuple(out)


def candidate_terms(data: pd.DataFrame, coefficient: str | None = None) -> list[Term]:
    """The candidate pool of one coefficient's residual: every excited variable,
    linear and smooth, and pairs (interactions carry their main effects).

    Rates normalised by cbar/2V enter linearly only. A coefficient is never
    regressed on itself (the measured CL holds the CL residual).
    """
    banned = EXCLUDED.get(coefficient, ())
    excited = [v for v in VARIABLES if v in data and v not in banned and float(data[v].std()) >= MIN_STD[v]]
    if "CL" in excited and float(data["CL"].min()) <= 0.05:
        excited.remove("CL")  # exported through CL^2: needs a lift coefficient that stays positive
    center = {v: float(np.median(data[v])) for v in excited}
    rng = {v: (-np.inf, np.inf) if v in RATES else (float(data[v].min()), float(data[v].max())) for v in excited}
    shaped = [v for v in excited if v not in RATES]
    terms = []
    for v in excited:
        terms.append(Term("linear", (v,), (), (center[v],), (rng[v],)))
        if v in shaped and v not in ("gear_norm", "flap_deg"):
            terms.append(Term("quadratic", (v,), (), (center[v],), (rng[v],)))
        if v == "gear_norm":
            terms.append(Term("smooth", (v,), GEAR_KNOTS))
        elif v in shaped:
            if v == "flap_deg":
                knots = tuple(float(x) for x in np.unique(np.round(data[v].to_numpy(), 6)))
            else:
                knots = _spread(np.unique(np.round(np.quantile(data[v], np.linspace(0, 1, 6)), 6)))
            if len(knots) >= 3:
                terms.append(Term("smooth", (v,), knots))
    for a, b in combinations(shaped, 2):
        terms.append(Term("product", (a, b), (), (center[a], center[b]), (rng[a], rng[b])))
    if "gear_norm" in shaped:
        for b in shaped:
            if b != "gear_norm":
                terms.append(Term("smooth_x_linear", ("gear_norm", b), GEAR_KNOTS, (0.0, center[b]),
                                  ((0.0, 1.0), rng[b])))
    for sig in SIGNATURES:  # sensor errors the kinematics cannot see compete with the aero terms
        v = f"{sig}_{coefficient}"
        if coefficient and v in data and float(data[v].std()) > 1e-6:
            terms.append(Term("linear", (v,), (), (0.0,), ((-np.inf, np.inf),)))
    return terms


def sensor_of(variable: str) -> tuple[str, str] | None:
    """(channel, error) if a variable is a sensor error's signature, else None."""
    head = variable.rsplit("_", 1)[0]
    return SIGNATURES.get(head) if variable.rsplit("_", 1)[-1] in COEFFS else None


class _Lags:
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
        rho = fft.irfft(f.real ** 2 + f.imag ** 2, self.nfft)[1:self.max_lag + 1] / n / r0
        stop = np.flatnonzero(rho <= 0)
        tau = 1.0 + 2.0 * float(np.sum(rho[:stop[0] if stop.size else len(rho)]))
        return max(n / tau, 2.0)


@dataclass
class _Fit:
    terms: list[Term]
    beta: np.ndarray
    resid: np.ndarray | None
    rss: float


def _fit(y: np.ndarray, cols: list[np.ndarray], terms: list[Term]) -> _Fit:
    x = np.column_stack([np.ones(len(y))] + cols) if cols else np.ones((len(y), 1))
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    r = y - x @ beta
    return _Fit(list(terms), beta, r, float(r @ r))


def _compact(x: np.ndarray):
    """A design matrix as it is cheapest to hold: sparse (CSR) if most of it is zero (the hat
    columns of a smooth term), else dense."""
    from scipy import sparse
    return sparse.csr_array(x) if np.count_nonzero(x) < 0.5 * x.size else x


def _dense(x) -> np.ndarray:
    return x.toarray() if hasattr(x, "toarray") else x


class _Gram:
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

    def fit(self, terms: list[Term], target: str) -> _Fit:
        idx = np.concatenate([[0]] + [self.index[t] for t in terms]).astype(int)
        j = self.target[target]
        b = solve_normal(self.gram[np.ix_(idx, idx)], self.gram[idx, j])
        beta = b * self.scale[j] / self.scale[idx]
        r = self.ys[target] - beta[0]
        at = 1
        for t in terms:
            k = self.designs[t].shape[1]
            r = r - self.designs[t] @ beta[at:at + k]
            at += k
        return _Fit(list(terms), beta, r, float(r @ r))


def candidate_gram(data: pd.DataFrame, terms: dict[str, list[Term]]) -> _Gram:
    """One :class:`_Gram` of the residuals ``r_<coefficient>`` of ``data`` on the union of each
    coefficient's candidate ``terms`` (coefficient -> terms), for :func:`stepwise`'s ``gram``."""
    union = dict.fromkeys(t for ts in terms.values() for t in ts)
    return _Gram({c: data[f"r_{c}"].to_numpy() for c in terms}, {t: _compact(t.design(data)) for t in union})


def _f_test(small: _Fit, big: _Fit, k: int, n_eff: float, p_big: int) -> tuple[float, float]:
    dof = max(n_eff - p_big, 1.0)
    f = ((small.rss - big.rss) / k) / (big.rss / dof) if big.rss > 0 else np.inf
    return float(f), float(stats.f.sf(f, k, dof)) if np.isfinite(f) else 0.0


@dataclass
class StepwiseResult:
    """Stepwise regression of one coefficient's residual."""

    coefficient: str
    terms: list[Term]
    beta: np.ndarray  # intercept first, then each term's columns
    evidence: dict[str, dict]
    alternatives: list[dict]
    rms_before: float
    rms_after: float
    n_eff: float
    close: dict = field(default_factory=dict)  # term label -> rivals nearly as strong when it entered

    def term_beta(self, term: Term) -> np.ndarray:
        i = 1
        for t in self.terms:
            if t == term:
                return self.beta[i:i + t.width]
            i += t.width
        raise KeyError(term.label)

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        out = np.full(len(frame), self.beta[0])
        for t in self.terms:
            out += t.design(frame) @ self.term_beta(t)
        return out


def stepwise(data: pd.DataFrame, coefficient: str, terms: list[Term], alpha_in: float = 1e-6,
             min_reduction: float = 0.01, max_terms: int = 6, lags: _Lags | None = None,
             gram: _Gram | None = None) -> StepwiseResult:
    """Forward-backward stepwise regression of ``r_<coefficient>`` on candidate terms.

    A term enters if its partial F-test (on the effective sample size of the
    residual after it enters) has p < ``alpha_in`` and it removes at least
    ``min_reduction`` of the initial residual sum of squares (about its mean);
    a term leaves when its removal test no longer passes. ``gram`` (:func:`candidate_gram`),
    if given, holds ``terms`` and this coefficient's residual, and may be shared with the others.
    """
    y = data[f"r_{coefficient}"].to_numpy()
    lags = lags or _Lags(data["log"].to_numpy())
    if gram is None:
        gram = candidate_gram(data, {coefficient: terms})
    designs = gram.designs
    chosen: list[Term] = []
    close: dict[str, list] = {}
    current = gram.fit([], coefficient)
    rss0 = current.rss
    rms_before = float(np.sqrt(np.mean((y - y.mean()) ** 2)))
    alternatives = []
    for _ in range(max_terms):
        p_now = 1 + sum(t.width for t in chosen)
        rows = []
        for t in terms:
            if t in chosen or (t.kind in ("linear", "quadratic") and any(
                    c.kind in ("smooth", "quadratic") and c.variables == t.variables for c in chosen)):
                continue
            big = gram.fit(chosen + [t], coefficient)
            n_eff = lags.n_eff(big.resid)
            f, p = _f_test(current, big, t.width, n_eff, p_now + t.width)
            big.resid = None  # a round holds every candidate's fit; the chosen one's residual is recomputed
            rows.append({"term": t, "F": f, "p_value": p, "rss_reduction": (current.rss - big.rss) / rss0,
                         "n_eff": n_eff, "fit": big})
        if not rows:
            break
        rows.sort(key=lambda r: (r["p_value"], -r["F"]))
        if not alternatives:
            alternatives = [{"term": r["term"].label, "F": r["F"], "p_value": r["p_value"],
                             "rss_reduction_pct": 100 * r["rss_reduction"]} for r in rows[:8]]
        best = rows[0]
        # prefer a leaner term on a subset of the same variables if it does as well
        leaner = sorted((r for r in rows if set(r["term"].variables) <= set(best["term"].variables)
                         and r["term"].width < best["term"].width and r["p_value"] < alpha_in),
                        key=lambda r: r["term"].width)
        for lean in leaner:
            if _f_test(lean["fit"], best["fit"], best["term"].width - lean["term"].width,
                       best["n_eff"], p_now + best["term"].width)[1] > alpha_in:
                best = lean
                break
        if best["p_value"] >= alpha_in or best["rss_reduction"] < min_reduction:
            break
        mine = set(best["term"].variables)
        close[best["term"].label] = [
            {"term": r["term"].label, "F": r["F"], "F_ratio": r["F"] / best["F"]} for r in rows
            if r is not best and r["p_value"] < alpha_in and r["F"] >= 0.5 * best["F"]
            and not set(r["term"].variables) <= mine and not mine <= set(r["term"].variables)][:3]
        chosen.append(best["term"])
        current = gram.fit(chosen, coefficient)
        for t in list(chosen[:-1]):  # backward step
            rest = [c for c in chosen if c != t]
            small = gram.fit(rest, coefficient)
            f, p = _f_test(small, current, t.width, lags.n_eff(current.resid),
                           1 + sum(c.width for c in chosen))
            if p >= alpha_in or (small.rss - current.rss) / rss0 < min_reduction / 2:
                chosen.remove(t)
                current = small
    evidence = {}
    current = _fit(y, [_dense(designs[c]) for c in chosen], chosen)  # the answer itself by a rank-revealing solver
    n_eff = lags.n_eff(current.resid)
    p_all = 1 + sum(t.width for t in chosen)
    for t in chosen:
        rest = [c for c in chosen if c != t]
        small = gram.fit(rest, coefficient)
        f, p = _f_test(small, current, t.width, n_eff, p_all)
        evidence[t.label] = {"F": f, "p_value": p, "dof": [t.width, max(n_eff - p_all, 1.0)],
                             "rss_reduction_pct": 100.0 * (1.0 - current.rss / small.rss)}
    rms_after = float(np.sqrt(np.mean(current.resid ** 2)))
    return StepwiseResult(coefficient, chosen, current.beta, evidence, alternatives, rms_before, rms_after, n_eff,
                          {t.label: close.get(t.label, []) for t in chosen})


@dataclass
class Cause:
    """One candidate cause: a coefficient, the variables, a shape, the evidence, the verdict.

    Attributes
    ----------
    size : float
        Range (max - min) of its contribution over the data [-].
    verdict : dict
        ``accepted``, ``reason``, ``noise_floor`` (the size instrument noise
        alone reaches), ``holdout_gain`` (residual RMS without / with it on data
        it was not fitted on, where it acts) and ``holdout_logs``.
    """

    coefficient: str
    variables: list[str]
    terms: list[Term]
    shape: str
    evidence: dict
    peak: float
    curve: dict = field(default_factory=dict)
    size: float = 0.0
    verdict: dict = field(default_factory=dict)
    kind: str = "aero"
    channel: str = ""
    error: str = ""
    estimate: float = float("nan")
    se: float = float("nan")

    @property
    def label(self) -> str:
        if self.kind == "sensor":
            return f"sensor {self.channel} {self.error}"
        return f"{self.coefficient} vs {', '.join(self.variables)}"

    def to_dict(self) -> dict:
        common = {"kind": self.kind, "shape": self.shape, "evidence": self.evidence, "peak": self.peak,
                  "size": self.size, "verdict": self.verdict, "terms": [t.label for t in self.terms],
                  "curve": self.curve}
        if self.kind == "sensor":
            return {**common, "channel": self.channel, "error": self.error, "estimate": self.estimate,
                    "se": self.se, "coefficient": self.coefficient}
        return {**common, "coefficient": self.coefficient, "variables": self.variables}


def _shape(x: np.ndarray, y: np.ndarray) -> str:
    """Describe a curve y(x) sampled on increasing x."""
    span = float(np.ptp(y))
    if span == 0:
        return "constant"
    d = np.diff(y)
    lin = np.polyval(np.polyfit(x, y, 1), x)
    if np.max(np.abs(y - lin)) < 0.05 * span:
        return "linear"
    up, down = np.sum(d[d > 0]), -np.sum(d[d < 0])
    if min(up, down) > 0.1 * span:
        return "non-monotonic (rises and falls)" if np.argmax(np.abs(y - y[0])) < len(y) - 2 else "non-monotonic"
    n = len(y) // 3 or 1
    first, last = abs(y[n] - y[0]), abs(y[-1] - y[-1 - n])
    if last < 0.25 * first:
        knee = x[int(np.argmax(np.abs(y - y[0]) >= 0.95 * np.max(np.abs(y - y[0]))))]
        return f"saturating (flat beyond {x.dtype.type(knee):.2f})"
    if first < 0.25 * last:
        return "increasing slope (grows late)"
    return "monotonic, curved"


def _share(y: np.ndarray, x: np.ndarray) -> float:
    """R^2 of ``y`` explained by a piecewise-linear function of ``x`` alone."""
    knots = np.linspace(float(x.min()), float(x.max()), 6)
    if knots[-1] <= knots[0]:
        return 0.0
    design = np.column_stack([np.ones(len(x)), _hats(x, tuple(knots))])
    beta, *_ = np.linalg.lstsq(design, y, rcond=None)
    e = y - design @ beta
    ss = float(((y - y.mean()) ** 2).sum())
    return 1.0 - float(e @ e) / ss if ss > 0 else 0.0


def _along(group: list[Term], res: StepwiseResult, data: pd.DataFrame, variable: str,
           n: int = 41) -> tuple[np.ndarray, np.ndarray]:
    """A group's contribution along one of its variables, the others at their median."""
    names = {v for t in group for v in t.variables}
    grid = pd.DataFrame({v: np.full(n, float(np.median(data[v]))) for v in names})
    grid[variable] = np.linspace(float(data[variable].min()), float(data[variable].max()), n)
    return grid[variable].to_numpy(), sum(t.design(grid) @ res.term_beta(t) for t in group)


def name_causes(results: dict[str, StepwiseResult], data: pd.DataFrame, lags: _Lags) -> list[Cause]:
    """Group selected terms into causes (terms sharing a variable), rank by F."""
    causes = []
    for c, res in results.items():
        groups: list[list[Term]] = []
        for t in res.terms:
            hit = [g for g in groups if set(t.variables) & {v for u in g for v in u.variables}]
            merged = [t] + [u for g in hit for u in g]
            groups = [g for g in groups if g not in hit] + [merged]
        y = data[f"r_{c}"].to_numpy()
        designs = {t: t.design(data) for t in res.terms}
        full = _fit(y, [designs[t] for t in res.terms], res.terms)
        n_eff = lags.n_eff(full.resid)
        p_all = 1 + sum(t.width for t in res.terms)
        for g in groups:
            rest = [t for t in res.terms if t not in g]
            small = _fit(y, [designs[t] for t in rest], rest)
            k = sum(t.width for t in g)
            f, p = _f_test(small, full, k, n_eff, p_all)
            contrib = sum(t.design(data) @ res.term_beta(t) for t in g)
            variables = []
            for t in sorted(g, key=lambda t: t.kind not in ("smooth", "linear", "quadratic")):
                ordered = t.variables
                if t.kind == "product":  # the variable that alone explains more of the cause comes first
                    ordered = tuple(sorted(t.variables, key=lambda v: -_share(contrib, data[v].to_numpy())))
                variables += [v for v in ordered if v not in variables]
            primary = variables[0]
            cx, cy = _along(g, res, data, primary)
            shape = _shape(cx, cy)
            if len(variables) > 1:
                shape += f", depends on {', '.join(variables[1:])}"
            sensor = sensor_of(variables[0]) if len(g) == 1 else None
            if sensor:
                # the signature is per unit of the logged value: beta = e / (1 + e) for logged = (1 + e) true
                beta = float(res.term_beta(g[0])[0])
                se = _se(full, [designs[t] for t in res.terms], sum(t.width for t in res.terms[:res.terms.index(g[0])]),
                         n_eff)
                cause_kw = {"kind": "sensor", "channel": sensor[0], "error": sensor[1],
                            "estimate": beta / (1.0 - beta), "se": se / (1.0 - beta) ** 2, "shape": "scale factor"}
            else:
                cause_kw = {}
            causes.append(Cause(c, variables, g, shape,
                                {"F": f, "p_value": p, "dof": [k, max(n_eff - p_all, 1.0)],
                                 "rss_reduction_pct": 100.0 * (1.0 - full.rss / small.rss),
                                 "terms": {t.label: res.evidence.get(t.label, {}) for t in g},
                                 "hardly_separated_from": [a for t in g for a in res.close.get(t.label, [])]},
                                float(np.max(np.abs(contrib))),
                                {primary: cx.tolist(), f"d{c}": np.asarray(cy).tolist(),
                                 "others_at_median": {v: float(np.median(data[v])) for v in variables[1:]}},
                                float(np.ptp(contrib))))
            for k, v in cause_kw.items():
                setattr(causes[-1], k, v)
    causes.sort(key=lambda c: -c.evidence["F"])
    return causes


def _se(fit: _Fit, cols: list[np.ndarray], column: int, n_eff: float) -> float:
    """Standard error of one design column's coefficient (0 is the first after the intercept),
    inflated by N / N_eff for the residual's autocorrelation."""
    x = np.column_stack([np.ones(len(fit.resid))] + cols)
    n, p = x.shape
    var = np.linalg.pinv(x.T @ x)[1 + column, 1 + column] * fit.rss / max(n - p, 1) * n / max(n_eff, 1.0)
    return float(np.sqrt(var))


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
    (:meth:`identify.noise_floor.NoiseFloor.reach`). The part of the cause no plausible
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


@dataclass
class Diagnosis:
    """The result: residuals, stepwise fits, the causes named and those rejected.

    Attributes
    ----------
    data : DataFrame
        Residual data of the logs fitted on.
    held : DataFrame or None
        Residual data of the held-out logs (``log`` counts on after the fitted ones).
    results : dict
        Coefficient -> :class:`StepwiseResult`, refitted on the accepted causes' terms.
    causes : list of Cause
        Accepted causes, best first.
    rejected : list of Cause
        Candidates that failed the verdict, with the reason.
    noise : dict
        Channel noise levels estimated from the logs.
    unset : list
        Inputs of the model's aerodynamics that no log channel sets.
    compat : CompatResult or None
        The data compatibility (instrument errors estimated and corrected first).
    logs, held_logs : list of Log
        The logs fitted on and held out, as corrected.
    """

    data: pd.DataFrame
    results: dict[str, StepwiseResult]
    causes: list[Cause]
    rejected: list[Cause] = field(default_factory=list)
    held: pd.DataFrame | None = None
    noise: dict = field(default_factory=dict)
    unset: list = field(default_factory=list)
    first_step: dict = field(default_factory=dict)
    compat: CompatResult | None = None
    logs: list = field(default_factory=list)
    held_logs: list = field(default_factory=list)

    @property
    def discrepancy(self) -> bool:
        return bool(self.causes)

    @property
    def aero_causes(self) -> list[Cause]:
        """The accepted causes in the aerodynamics (the extension holds these)."""
        return [c for c in self.causes if c.kind == "aero"]

    def predict(self, coefficient: str, frame: pd.DataFrame) -> np.ndarray:
        """The fitted discrepancy of one coefficient at the states of ``frame``."""
        res = self.results[coefficient]
        return res.predict(frame) if res.terms else np.zeros(len(frame))

    def largest_rejected(self) -> dict:
        """The strongest candidate that was not named, and why."""
        if self.rejected:
            c = max(self.rejected, key=lambda c: c.verdict["size_over_floor"])
            return {"candidate": c.label, "size": c.size, "peak": c.peak, "reason": c.verdict["reason"],
                    "evidence": {k: c.evidence[k] for k in ("F", "p_value", "rss_reduction_pct")},
                    "noise_floor": c.verdict["noise_floor"], "holdout_gain": c.verdict["holdout_gain"]}
        best = min(self.first_step.items(), key=lambda kv: (kv[1]["p_value"], -kv[1]["F"]), default=None)
        if best is None:
            return {}
        c, a = best
        why = (f"not significant (p = {a['p_value']:.2g}, needs < 1e-06)" if a["p_value"] >= 1e-6 else
               f"removes only {a['rss_reduction_pct']:.2f} % of the residual (needs 1 %)")
        return {"candidate": f"{c} vs {a['term']}", "reason": why,
                "evidence": {k: a[k] for k in ("F", "p_value", "rss_reduction_pct")}}

    def summary(self) -> str:
        lines = []
        if self.compat is not None and self.compat.applied:
            lines.append("Data corrected for instrument errors (data compatibility): " + ", ".join(
                f"{p.name} {p.estimate:+.4g} +- {p.se:.2g} {p.unit}" for p in self.compat.applied))
        if self.unset:
            lines.append("Not set from the logs (held, as in level flight): " + ", ".join(map(str, self.unset)))
        if not self.causes:
            lines.append("No significant discrepancy.")
            big = self.largest_rejected()
            if big:
                lines.append(f"   largest candidate: {big['candidate']}: {big['reason']}")
        for i, c in enumerate(self.causes, 1):
            e, v = c.evidence, c.verdict
            if c.kind == "sensor" and not c.terms:
                lines.append(f"{i}. {c.label}: {c.estimate:+.4g} +- {c.se:.2g} {v.get('unit', '')} "
                             f"({e['z']:.1f} standard errors, data compatibility); moves {c.coefficient} by up to "
                             f"{c.size:.3g}; held-out gain x{v['holdout_gain']:.2f} once corrected")
                if e.get("chosen_because"):
                    lines.append(f"   {e['chosen_because']}")
                continue
            if c.kind == "sensor":
                lines.append(f"{i}. {c.label}: {c.estimate:+.4g} +- {c.se:.2g} (its signature in the {c.coefficient} "
                             f"residual: F = {e['F']:.4g}, removes {e['rss_reduction_pct']:.1f} %); size {c.size:.3g} "
                             f"against a noise floor of {v['noise_floor']:.3g}; held-out gain x{v['holdout_gain']:.2f}")
                for a in e.get("hardly_separated_from", []):
                    lines.append(f"   caution: the data hardly separate it from {a['term']} "
                                 f"(F = {a['F']:.4g}, {100 * a['F_ratio']:.0f} % of the chosen term's)")
                continue
            p = f"p = {e['p_value']:.2g}" if e["p_value"] > 0 else "p < 1e-300"
            made = (f", instrument errors could make {v['instrument_errors_make']:.3g} of it"
                    if v.get("instrument_errors_make") else "")
            lines.append(f"{i}. {c.label}: {c.shape}; peak {c.peak:.4g}; "
                         f"F = {e['F']:.4g} on {e['dof'][0]} and {e['dof'][1]:.0f} dof, {p}, "
                         f"removes {e['rss_reduction_pct']:.1f} % of the residual; size {c.size:.3g} against a "
                         f"noise floor of {v['noise_floor']:.3g}{made}; held-out gain x{v['holdout_gain']:.2f}")
            for a in e.get("hardly_separated_from", []):
                lines.append(f"   caution: the data hardly separate it from {a['term']} "
                             f"(F = {a['F']:.4g}, {100 * a['F_ratio']:.0f} % of the chosen term's)")
            for a in e.get("sensor_alternatives", []):
                if a.get("unmeasured"):
                    lines.append(f"   or a sensor: {a['channel']} {a['error']} {a['needs']:+.3g} would make "
                                 f"{a['explains_pct']:.0f} % of it; the data compatibility could not measure that "
                                 f"error in these data, so they cannot tell the two apart")
                    continue
                lines.append(f"   or a sensor: {a['channel']} {a['error']} {a['needs']:+.3g} would make "
                             f"{a['explains_pct']:.0f} % of it; the data compatibility puts that error at "
                             f"0 +- {a['se']:.2g} after correction ({abs(a['needs_se']):.1f} standard errors away)")
        if self.causes and self.rejected:
            lines.append("Rejected: " + "; ".join(f"{c.label} ({c.verdict['reason']})" for c in self.rejected))
        lines.append("")
        for c, res in self.results.items():
            lines.append(f"{c}: residual RMS {res.rms_before:.3g} -> {res.rms_after:.3g} with "
                         f"{', '.join(t.label for t in res.terms) or 'no term'} (N_eff {res.n_eff:.0f})")
            lines.append("   alternatives at the first step: " + "; ".join(
                f"{a['term']} F={a['F']:.3g}" for a in res.alternatives[:5]))
        return "\n".join(lines)


#: A corrected instrument error is named when it moves a coefficient at least this much.
SENSOR_EFFECT = 1e-4
#: ... and its estimate is this many standard errors from 0 (the kinematics alone say so), or the
#: aerodynamic residuals chose it (:func:`arbitrate`: two independent lines of evidence).
SENSOR_Z = APPLY_Z
#: A correction the kinematics leave undecided is applied if the residuals get this much smaller
#: (RMS ratio) with it, on the fitted and on the held-out logs.
CORROBORATED_GAIN = 1.1


def corrected_residuals(compat: CompatResult, raw: list[Log], evaluator, step: int | None = None,
                        delays: tuple = (), wait: bool = True):
    """:func:`identify.residuals.residual_data` of the ``raw`` logs corrected by ``compat``.

    Within :func:`diagnose` each is computed once (``evaluator.residual_memo``): the
    arbitration, the delays, the residuals and the sensor causes ask for the same
    corrections again. A frame with delay signatures serves a request without them.
    With ``wait=False`` a callable that returns the frame comes back, the workers
    computing it meanwhile (:func:`identify.residuals.residual_data`).
    """
    memo = getattr(evaluator, "residual_memo", None)
    if memo is None:
        return residual_data(raw, evaluator, step, delays, wait=wait, correct=compat.correct)
    done = memo.setdefault((compat.correction_key(), tuple(map(id, raw)), step), {})
    for have, frame in done.items():
        if set(delays) <= set(have):
            extra = [f"{ch.split('_')[0]}delay_{c}" for ch in set(have) - set(delays) for c in COEFFS]
            return frame.drop(columns=extra) if wait else (lambda frame=frame: frame.drop(columns=extra))
    pending = residual_data(raw, evaluator, step, delays, wait=False, correct=compat.correct)  # corrected there

    def finished() -> pd.DataFrame:
        done[tuple(delays)] = pending()
        return done[tuple(delays)].copy()
    return finished() if wait else finished


def arbitrate(compat: CompatResult, raw: list[Log], raw_held: list[Log], evaluator,
              step: int | None = None) -> CompatResult:
    """Let the aerodynamic residuals decide the corrections the kinematics leave undecided.

    Two errors the kinematics cannot tell apart (an accelerometer bias and an attitude
    bias through gravity; a vane's bias and its scale when the trim alphas hardly differ)
    are each estimated with the other held at 0, and only one may be applied. An estimate
    3 to 5 standard errors from 0 may be real or a clustered standard error come out small.
    Each candidate is tried: the one that brings the model closest to the data is applied
    if the residuals get at least :data:`CORROBORATED_GAIN` times smaller (RMS) with it,
    on the fitted logs and on the held-out ones, as they are or beside the aerodynamic
    terms the stepwise search fits (:func:`_trial`); the others keep what the residuals said.
    """
    groups: list[list] = []
    for p in compat.undecided:
        g = next((g for g in groups if p.confounded_with in {q.name for q in g}
                  or p.name in {q.confounded_with for q in g}), None)
        g.append(p) if g is not None else groups.append([p])
    for g in groups:
        tried = [(p, *_trial(compat, compat.choose(p.name, "trial"), raw, raw_held, evaluator, step)) for p in g]
        best = max(tried, key=lambda t: _score(t[2]))
        for p, c, gains in tried:
            why = (f"the kinematics cannot tell it from {p.confounded_with}" if p.confounded_with else
                   f"{p.z:.1f} standard errors from the kinematics")
            way = _agrees(gains) if p is best[0] else ""
            if way:
                compat = compat.choose(p.name, f"{why}; the {c} residual agrees: {_said(gains)}",
                                       beside_aero=way != "as is")
            else:
                compat = compat.note(p.name, f"{why}; the {c} residual does not choose it ({_said(gains)})")
    return compat


def _trial(compat: CompatResult, trial: CompatResult, raw: list[Log], raw_held: list[Log], evaluator,
           step: int | None) -> tuple[str, dict[str, tuple[float, float]]]:
    """How much closer a trial correction brings the model to the data.

    The coefficient whose residual the correction moves most is judged: its RMS before
    over after, on the fitted logs and on the held-out ones (nan without), taken two ways:
    ``as is``, and ``beside aero terms``, what is left after the terms the stepwise search
    fits to each version (aerodynamic, and the thrust-scale signature; the held-out logs
    predicted by the terms fitted on the others). An aerodynamic error in the same residual (a drag rise with Mach
    beside an accelerometer bias) hides a real correction's gain in the first but not in
    the second; an aerodynamic term that mimics the correction (a pitch-rate term for a
    late vane) hides it in the second but not in the first.
    """
    before = corrected_residuals(compat, raw, evaluator, step)
    after = corrected_residuals(trial, raw, evaluator, step)
    c = max(COEFFS, key=lambda k: float(np.max(np.abs(after[f"r_{k}"].to_numpy() - before[f"r_{k}"].to_numpy()))))
    held = ((corrected_residuals(compat, raw_held, evaluator, step),
             corrected_residuals(trial, raw_held, evaluator, step)) if raw_held else None)

    def ratio(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.sqrt(np.mean(a ** 2)) / max(np.sqrt(np.mean(b ** 2)), 1e-300))

    def left(frame: pd.DataFrame, other: pd.DataFrame | None) -> tuple[np.ndarray, np.ndarray | None]:
        res = stepwise(frame, c, candidate_terms(frame, c))
        return (frame[f"r_{c}"].to_numpy() - res.predict(frame),
                None if other is None else other[f"r_{c}"].to_numpy() - res.predict(other))

    (lb, lbh), (la, lah) = left(before, held[0] if held else None), left(after, held[1] if held else None)
    nan = float("nan")
    return c, {"as is": (ratio(before[f"r_{c}"].to_numpy(), after[f"r_{c}"].to_numpy()),
                         ratio(held[0][f"r_{c}"].to_numpy(), held[1][f"r_{c}"].to_numpy()) if held else nan),
               "beside aero terms": (ratio(lb, la), ratio(lbh, lah) if held else nan)}


def _agrees(gains: dict[str, tuple[float, float]]) -> str:
    """The way the residuals agree with a correction ("" if neither). As is: at least
    :data:`CORROBORATED_GAIN` on the fitted logs and (if any) on the held-out ones. Beside aero
    terms the fitted logs say little (the terms were fitted to them, and can mimic the correction
    there): the held-out logs must gain :data:`CORROBORATED_GAIN`, and the fitted ones not lose."""
    g, h = gains["as is"]
    gb, hb = gains["beside aero terms"]
    return ("as is" if g >= CORROBORATED_GAIN and not h < CORROBORATED_GAIN else
            "beside aero terms" if gb >= 1.0 and hb >= CORROBORATED_GAIN else "")


def _score(gains: dict[str, tuple[float, float]]) -> float:
    g, h = gains["as is"]
    gb, hb = gains["beside aero terms"]
    return max(min(g, h) if np.isfinite(h) else g, min(gb, hb) if np.isfinite(hb) and gb >= 1.0 else 0.0)


def _said(gains: dict[str, tuple[float, float]]) -> str:
    return "; ".join(f"{k}: RMS x{g:.2f} smaller corrected" + (f", x{h:.2f} on held-out logs" if np.isfinite(h)
                                                                else "") for k, (g, h) in gains.items())


#: Gauss-Newton iterations of a time shift timed by the residuals (each evaluates the model twice per log).
RESIDUAL_DELAY_ITERATIONS = 3


def _with_estimate(compat: CompatResult, name: str, estimate: float, se: float, chosen: str,
                   beside_aero: bool = False) -> CompatResult:
    """The same result with one parameter estimated by the residuals and applied."""
    return replace(compat, parameters=[
        replace(q, identifiable=True, estimate=estimate, se=se, sources={"residuals": (estimate, se)}, chosen=chosen,
                beside_aero=beside_aero)
        if q.name == name else q for q in compat.parameters])


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


def residual_delays(compat: CompatResult, raw: list[Log], raw_held: list[Log], evaluator,
                    step: int | None = None) -> CompatResult:
    """Time the vanes the kinematics could not (turbulence) from the aerodynamic residuals.

    A vane ``tau`` late leaves ``tau`` times the model's rate of change along the
    vane's own reading in every residual (:func:`identify.residuals.delay_signature`).
    The residual of each coefficient, less its mean per log, is fitted by that
    signature; the coefficient whose residual it explains best gives the delay, with
    a delete-one-log jackknife standard error. The delay is applied only if the residuals get at least
    :data:`CORROBORATED_GAIN` times smaller with it, on the fitted logs and on the
    held-out ones. A model whose own rate derivatives are wrong leaves a similar
    signature: then the delay and the derivative cannot be told apart, and the
    report says so beside the aerodynamic cause.
    """
    for ch, err in compat.unmeasured:
        if err != "delay" or not raw_held:
            continue
        name, head = f"{ch}.{err}", ch.split("_")[0] + "delay"
        tau, first, found = 0.0, None, None
        for _ in range(RESIDUAL_DELAY_ITERATIONS):  # Gauss-Newton: the signature again at the corrected reading
            cur = _with_estimate(compat, name, tau, float("nan"), "trial") if tau else compat
            found = _time_shift(corrected_residuals(cur, raw, evaluator, step, delays=(ch,)), head)
            if found is None:
                break
            first = first or found
            tau += found[0]
            if abs(found[0]) < 1e-3:
                break
        if found is None:
            continue
        se, (_, _, r2, best) = found[1], first
        trial = _with_estimate(compat, name, tau, se, "trial")
        if not trial.get(name).correctable:
            compat = compat.note(name, f"the residuals put it at {tau * 1000:+.0f} +- {se * 1000:.0f} ms, not a "
                                       f"correction to make")
            continue
        c, gains = _trial(compat, trial, raw, raw_held, evaluator, step)
        said = (f"{tau * 1000:+.0f} +- {se * 1000:.1f} ms from the {best} residual (explains {100 * r2:.0f} % of "
                f"it); the {c} residual {_said(gains)}")
        way = _agrees(gains)
        if way:
            compat = _with_estimate(compat, name, tau, se, f"timed by the aerodynamic residuals: {said}",
                                    beside_aero=way != "as is")
        else:
            compat = compat.note(name, f"the residuals put it at {said}: not applied")
    return compat


#: An instrument error the significant aero causes of at least two coefficients each owe this
#: share of their variance to [%] ...
AGREE_PCT = 80.0
#: ... at sizes this close (largest over smallest, same sign) ...
AGREE_RATIO = 1.5
#: ... and within this many of the data compatibility's standard errors of its own estimate, is
#: an instrument error: the residuals refine the correction instead of naming aero causes.
AGREE_SE = 2.5


def residual_refinement(compat: CompatResult, causes: list[Cause], reach: list[dict],
                        alpha_in: float = 1e-6) -> CompatResult | None:
    """An air-data error the kinematics measured loosely and the aerodynamic residuals pin down.

    A vane's scale or bias error moves the model's CL, CD and Cm together, each along its
    own derivative; an aerodynamic error moves one coefficient. When one instrument
    error explains the causes of two coefficients or more (each at least :data:`AGREE_PCT`
    % of its variance; significant and above the noise floor, whether or not the held-out
    checks accepted them), at consistent sizes, and the correction it
    adds lands within :data:`AGREE_SE` standard errors of the kinematics' own estimate,
    the two independent measurements agree: the correction is refined to what the
    residuals need (the median over the coefficients), and the diagnosis runs again
    on the refined data. One aerodynamic error alone (one coefficient) never triggers it.

    Returns
    -------
    CompatResult or None
        The refined data compatibility, or None if no instrument error qualifies.
    """
    needs: dict[tuple[str, str], dict[str, float]] = {}
    for cause, rc in zip(causes, reach):
        if (cause.kind != "aero" or not cause.evidence["p_value"] < alpha_in
                or not cause.size > cause.verdict["noise_floor"]):
            continue
        for a in rc["alternatives"]:
            if not a.get("unmeasured") and a["explains_pct"] >= AGREE_PCT:
                needs.setdefault((a["channel"], a["error"]), {}).setdefault(cause.coefficient, a["needs"])
    best = None
    for (ch, err), by in needs.items():
        v = np.array(list(by.values()))
        if len(v) < 2 or not (np.all(v > 0) or np.all(v < 0)) or np.max(np.abs(v)) > AGREE_RATIO * np.min(np.abs(v)):
            continue
        p = compat.get(f"{ch}.{err}")
        total = (p.estimate if p.applied else 0.0) + float(np.median(v))
        gap = abs(total - p.estimate) / p.se if p.se > 0 else np.inf
        if gap <= AGREE_SE and (best is None or gap < best[0]):
            best = (gap, p, total, by)
    if best is None:
        return None
    gap, p, total, by = best
    said = ", ".join(f"{c} {x:+.4g}" for c, x in by.items())
    why = (f"the residuals of {', '.join(by)} each need it (a further {said}); {total:+.4g} in all, "
           f"{gap:.1f} standard errors from the kinematics' {p.estimate:+.4g} +- {p.se:.2g}")
    return replace(compat, parameters=[
        replace(q, estimate=total, sources={**(q.sources or {"kinematics": (q.estimate, q.se)}),
                                            "residuals": (total, q.se)}, chosen=why)
        if q is p else q for q in compat.parameters])


def compat_causes(compat: CompatResult, raw: list[Log], raw_held: list[Log], evaluator, data: pd.DataFrame,
                  held_data: pd.DataFrame | None, step: int | None,
                  aero: dict[str, list[Term]] | None = None) -> list[Cause]:
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
    causes = []
    aero = aero or {}

    def rms(x: np.ndarray) -> float:
        return float(np.sqrt(np.mean(x ** 2)))

    def beside(frame: pd.DataFrame, held: pd.DataFrame, c: str) -> np.ndarray:
        y = frame[f"r_{c}"].to_numpy()
        fit = _fit(y, [t.design(frame) for t in aero[c]], aero[c])
        x = design_matrix(aero[c], held)
        return held[f"r_{c}"].to_numpy() - x @ fit.beta

    for p in compat.applied:
        undone = compat.without(p.name)
        r = corrected_residuals(undone, raw, evaluator, step)
        effect = {c: float(np.max(np.abs(r[f"r_{c}"].to_numpy() - data[f"r_{c}"].to_numpy()))) for c in COEFFS}
        c = max(effect, key=effect.get)
        gain = float("nan")
        if raw_held and held_data is not None:
            h = corrected_residuals(undone, raw_held, evaluator, step)
            after = rms(held_data[f"r_{c}"].to_numpy())
            gain = rms(h[f"r_{c}"].to_numpy()) / after if after > 0 else float("inf")
            if aero.get(c) and p.beside_aero:
                gain = max(gain, rms(beside(r, h, c)) / max(rms(beside(data, held_data, c)), 1e-300))
        reasons = []
        if p.z < SENSOR_Z and not p.chosen:
            reasons.append(f"only {p.z:.1f} standard errors (needs {SENSOR_Z:g}, or the residuals to agree)")
        if effect[c] < SENSOR_EFFECT:
            reasons.append(f"moves {c} by {effect[c]:.2g} at most (needs {SENSOR_EFFECT:g})")
        if not gain >= MIN_HOLDOUT_GAIN:
            reasons.append("no held-out data" if not np.isfinite(gain) else
                           f"does not improve held-out data (gain x{gain:.3f}, needs x{MIN_HOLDOUT_GAIN})")
        cause = Cause(c, [p.channel], [], p.error, {"z": p.z, "F": p.z ** 2, "p_value": 0.0, "dof": [1, 0],
                                                  "rss_reduction_pct": float("nan"), "method": "data compatibility",
                                                  "methods": {k: {"estimate": e, "se": se}
                                                              for k, (e, se) in p.sources.items()},
                                                  "effect_by_coefficient": effect,
                                                  **({"confounded_with": p.confounded_with or None,
                                                      "chosen_because": p.chosen} if p.chosen else {})},
                      effect[c], size=effect[c], kind="sensor", channel=p.channel, error=p.error,
                      estimate=p.estimate, se=p.se)
        cause.verdict = {"accepted": not reasons, "reason": "; ".join(reasons), "holdout_gain": gain,
                         "noise_floor": SENSOR_EFFECT, "size_over_floor": effect[c] / SENSOR_EFFECT,
                         "unit": p.unit}
        causes.append(cause)
    return causes


def _merge_sensors(causes: list[Cause]) -> list[Cause]:
    """One cause per instrument error: its sightings in several coefficients' residuals become
    evidence of the strongest (named once, with the others' estimates)."""
    out, seen = [], {}
    for c in causes:
        key = (c.channel, c.error) if c.kind == "sensor" else None
        if key is None or key not in seen:
            if key:
                seen[key] = c
                c.evidence.setdefault("also_in", [])
            out.append(c)
            continue
        first = seen[key]
        keep, other = (first, c) if first.evidence["F"] >= c.evidence["F"] else (c, first)
        keep.evidence.setdefault("also_in", []).append(
            {"coefficient": other.coefficient, "estimate": other.estimate, "se": other.se, "F": other.evidence["F"]})
        keep.evidence["also_in"] += other.evidence.get("also_in", [])
        if keep is c:
            out[out.index(first)] = c
            seen[key] = c
    return out


def _conditions(frame: pd.DataFrame, logs: list[Log], offset: int = 0) -> pd.DataFrame:
    frame = frame.copy()
    frame["log"] = frame["log"] + offset
    keys = {i + offset: "/".join(f"{x:g}" for x in lg.condition) for i, lg in enumerate(logs)}
    frame["condition"] = frame["log"].map(keys)
    return frame


def refit(res: StepwiseResult, keep: list[Term], data: pd.DataFrame) -> StepwiseResult:
    """The same stepwise result with only ``keep`` terms, refitted."""
    y = data[f"r_{res.coefficient}"].to_numpy()
    fit = _fit(y, [t.design(data) for t in keep], keep)
    return StepwiseResult(res.coefficient, list(keep), fit.beta, {k: v for k, v in res.evidence.items()
                                                                    if k in {t.label for t in keep}},
                          res.alternatives, res.rms_before, float(np.sqrt(np.mean(fit.resid ** 2))), res.n_eff,
                          {k: v for k, v in res.close.items() if k in {t.label for t in keep}})


def diagnose(logs: list[Log], evaluator, held: list[Log] = (), step: int | None = None, realizations: int = 20,
             compatibility: bool = True, jobs: int = 1, progress=None, **kw) -> Diagnosis:
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
    realizations : int
        Noise realizations of the instrument-noise floor.
    compatibility : bool
        Estimate the instrument errors first and correct the logs (:mod:`identify.compat`).
    jobs : int
        Worker processes for the residuals and the noise floor's realizations (sets ``evaluator.jobs``).
    progress : callable, optional
        Called with the name of each stage as it starts (see ``campaign.diagnose.STAGES``).
    """
    stage = progress or (lambda name: None)
    evaluator.jobs, evaluator.residual_memo = jobs, {}
    held = list(held)
    raw, raw_held = list(logs), held
    stage("data compatibility")
    compat = estimate(logs) if compatibility else None
    if compat is not None:
        compat = arbitrate(compat, raw, raw_held, evaluator, step)
        stage("instrument delays")
        compat = residual_delays(compat, raw, raw_held, evaluator, step)
        logs = [compat.correct(lg) for lg in logs]
        held = [compat.correct(lg) for lg in held]
    for refined in (False, True):
        stage("residuals")
        if compat is None:
            data = residual_data(logs, evaluator, step)
            held_data = residual_data(held, evaluator, step, wait=jobs <= 1) if held else None
        else:
            data = corrected_residuals(compat, raw, evaluator, step)
            held_data = corrected_residuals(compat, raw_held, evaluator, step, wait=jobs <= 1) if held else None
        noise = channel_noise(logs + held)
        # the workers compute the held-out residuals and then the sensitivities beside the stepwise search
        early = model_sensitivities(logs, evaluator, noise, jobs) if jobs > 1 else None
        stage("stepwise")
        lags = _Lags(data["log"].to_numpy())
        terms = {c: candidate_terms(data, c) for c in COEFFS}
        shared = candidate_gram(data, terms)
        results = {c: stepwise(data, c, terms[c], lags=lags, gram=shared, **kw) for c in COEFFS}
        del shared
        causes = name_causes(results, data, lags)
        stage("noise floor")
        held_data = held_data() if callable(held_data) else held_data
        sens = early() if early else None  # wanted or not: the workers are then free for what comes next
        floor = (NoiseFloor(logs, evaluator, noise, step, realizations,
                            uncertain=compat.uncertainty() if compat else None,
                            unmeasured=compat.unmeasured if compat else (), jobs=jobs,
                            sensitivities=(lambda: sens) if early else None) if causes else None)
        groups = [(c.coefficient, c.terms) for c in causes]
        floors = floor.sizes(groups) if causes else []
        stage("instrument reach")
        aero = [c for c in causes if c.kind == "aero"]  # a sensor signature is itself an instrument error
        by_aero = dict(zip(map(id, aero), floor.reach([(c.coefficient, c.terms, contribution(results[c.coefficient], c,
                                                                                                 data)) for c in aero],
                                                      data))) if aero else {}
        reach = [by_aero.get(id(c), {"made": 0.0, "left": c.size, "alternatives": []}) for c in causes]
        noisy = [floor.noisy(c.variables) for c in causes]
        data_all = pd.concat([_conditions(data, logs)] + ([_conditions(held_data, held, len(logs))] if held else []),
                             ignore_index=True)
        stage("verdict")
        judge(causes, results, data_all, floors, noisy, reach, kw.get("alpha_in", 1e-6))
        better = (None if refined or compat is None else
                  residual_refinement(compat, causes, reach, kw.get("alpha_in", 1e-6)))
        if better is None:
            break
        compat = better
        logs, held = [compat.correct(lg) for lg in raw], [compat.correct(lg) for lg in raw_held]
    aero_terms = {c: [t for t in r.terms if sensor_of(t.variables[0]) is None] for c, r in results.items()}
    sensors = compat_causes(compat, raw, raw_held, evaluator, data, held_data, step, aero_terms) if compat else []
    sensors.sort(key=lambda c: -c.evidence["z"])
    accepted = _merge_sensors([c for c in sensors + causes if c.verdict["accepted"]])
    rejected = [c for c in sensors + causes if not c.verdict["accepted"]]
    for c in COEFFS:
        keep = [t for cause in accepted if cause.coefficient == c and cause.terms for t in cause.terms]
        if len(keep) != len(results[c].terms):
            results[c] = refit(results[c], [t for t in results[c].terms if t in keep], data)
    first = {c: r.alternatives[0] for c, r in results.items() if r.alternatives}
    evaluator.residual_memo = None
    return Diagnosis(data, results, accepted, rejected, held_data, noise, list(evaluator.unset), first, compat,
                     logs, held)
