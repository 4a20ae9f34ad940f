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

from dataclasses import dataclass, field
from itertools import combinations

import numpy as np
import pandas as pd
from scipy import stats

from identify.coefficients import D2R, FT_PER_KT, coefficients
from identify.evaluate import moment_transfer
from identify.kinematics import angle_rates
from identify.logs import Log
from identify.models import EDGE_S, lowpass

COEFFS = ("CL", "CD", "Cm")
#: Candidate variables: log column (or derived quantity) -> JSBSim property of the model it maps to.
VARIABLES = {
    "gear_norm": "gear/gear-pos-norm",
    "alpha_deg": "aero/alpha-deg",
    "mach": "velocities/mach",
    "flap_deg": "fcs/flap-pos-deg",
    "elevator_deg": "fcs/elevator-pos-deg",
    "stabilizer_deg": "fcs/stabilizer-pos-deg",
    "qhat_rad": None,  # q cbar / 2V: aero/ci2vel * velocities/q-aero-rad_sec
    "adothat_rad": None,  # alpha-dot cbar / 2V: aero/ci2vel * aero/alphadot-rad_sec
    "CL": "aero/cl-squared",  # the measured lift coefficient; exported through CL^2
}
#: Rates normalised by cbar/2V: exported as linear terms (products of properties), never as tables.
RATES = {"qhat_rad": "velocities/q-aero-rad_sec", "adothat_rad": "aero/alphadot-rad_sec"}
#: Variables a coefficient's residual may not be regressed on (they contain that residual).
EXCLUDED = {"CL": ("CL",)}
#: A variable must vary at least this much (std) to be a candidate.
MIN_STD = {"gear_norm": 0.05, "alpha_deg": 0.1, "mach": 0.002, "flap_deg": 0.5, "elevator_deg": 0.1,
           "stabilizer_deg": 0.1, "qhat_rad": 1e-5, "adothat_rad": 1e-5, "CL": 0.01}
#: Channels low-passed before they become variables (the gear and flap are not: they are set, not sensed).
FILTERED = ("alpha_deg", "mach", "elevator_deg", "stabilizer_deg", "qhat_rad", "adothat_rad", "CL")
GEAR_KNOTS = tuple(np.round(np.linspace(0.0, 1.0, 11), 10))


def variables(data: pd.DataFrame, meta: dict, cl: np.ndarray) -> pd.DataFrame:
    """The candidate variables of one log, unfiltered.

    Parameters
    ----------
    data : DataFrame
        A log in the schema.
    meta : dict
        Its metadata (``geometry.cbar_ft``).
    cl : ndarray
        Its measured lift coefficient [-].
    """
    half_chord_over_v = meta["geometry"]["cbar_ft"] / (2.0 * data["tas_kt"].to_numpy() * FT_PER_KT)
    alpha_dot, _ = angle_rates(data)
    out = pd.DataFrame({v: data[v].to_numpy(dtype=float) for v in VARIABLES if v in data.columns}, index=data.index)
    out["qhat_rad"] = data["q_dps"].to_numpy() * D2R * half_chord_over_v
    out["adothat_rad"] = alpha_dot * half_chord_over_v
    out["CL"] = np.asarray(cl, dtype=float)
    return out


def measured_about(coef: pd.DataFrame, meta: dict, evaluator) -> pd.DataFrame:
    """Measured CL, CD and Cm in the model's reference, Cm about the model's AERORP.

    The log's own area and chord are converted to the model's; the moment moves
    from the log's CG (the model's CG if the log does not give one) to the
    model's AERORP, with the full x and z offset.
    """
    g = meta["geometry"]
    k = g["S_ft2"] / evaluator.S
    cg_x, cg_z = g.get("cg_x_in", evaluator.cg_in[0]), g.get("cg_z_in", evaluator.cg_in[2])
    cm = coef["Cm"].to_numpy() * k * g["cbar_ft"] / evaluator.cbar
    cm = moment_transfer(cm, coef["Cx"].to_numpy() * k, coef["Cz"].to_numpy() * k,
                         evaluator.aerorp_in[0] - cg_x, evaluator.aerorp_in[2] - cg_z, evaluator.cbar)
    return pd.DataFrame({"CL": coef["CL"].to_numpy() * k, "CD": coef["CD"].to_numpy() * k, "Cm": cm},
                        index=coef.index)


def _smooth(frame: pd.DataFrame, dt: float, columns) -> pd.DataFrame:
    out = frame.copy()
    for c in columns:
        if c in out:
            out[c] = lowpass(out[c].to_numpy(), dt)
    return out


def residual_data(logs: list[Log], evaluator, step: int = 2) -> pd.DataFrame:
    """Measured minus model coefficients at the measured states, for every log.

    The model is evaluated at the raw measured states (exact on noise-free
    data); the measured and model coefficients and the variables then pass
    through the zero-phase low-pass filter of the identification, 0.25 s is
    dropped at both ends, and every ``step``-th sample is kept.

    Returns
    -------
    DataFrame
        One row per sample: ``log`` (index into ``logs``), ``t_s``, the
        variables, measured ``CL``/``CD``/``Cm``, the model's ``model_CL``...
        and residuals ``r_CL``/``r_CD``/``r_Cm`` (Cm about the model's AERORP).
    """
    frames = []
    for i, log in enumerate(logs):
        d = log.data
        dt = float(np.median(np.diff(d["t_s"])))
        meas = measured_about(coefficients(d, log.meta), log.meta, evaluator)
        cl = meas["CL"].to_numpy()
        pred = evaluator.predict(d, cl)
        both = pd.concat([meas, pred.add_prefix("model_")], axis=1)
        both = _smooth(both, dt, both.columns)
        var = _smooth(variables(d, log.meta, cl), dt, FILTERED)
        edge = int(round(EDGE_S / dt))
        keep = np.arange(edge, len(d) - edge, step)
        out = pd.DataFrame({"log": i, "t_s": d["t_s"].to_numpy()[keep], "maneuver": log.maneuver, "point": log.point})
        for v in VARIABLES:
            out[v] = var[v].to_numpy()[keep]
        for c in COEFFS:
            out[f"model_{c}"] = both[f"model_{c}"].to_numpy()[keep]
            out[f"meas_{c}"] = both[c].to_numpy()[keep]
            out[f"r_{c}"] = out[f"meas_{c}"] - out[f"model_{c}"]
        frames.append(out)
    return pd.concat(frames, ignore_index=True)


def _hats(x: np.ndarray, knots: tuple[float, ...]) -> np.ndarray:
    """Piecewise-linear basis: column j is 1 at knots[j], 0 at the others (flat outside)."""
    cols = []
    for j in range(len(knots)):
        y = np.zeros(len(knots))
        y[j] = 1.0
        cols.append(np.interp(x, knots, y))
    return np.column_stack(cols)


@dataclass(frozen=True)
class Term:
    """A candidate group of regressors.

    kind : "linear" | "smooth" | "product" | "smooth_x_linear"
        Interactions carry their main effects (hierarchy): ``product`` is
        a, b and a*b; ``smooth_x_linear`` is smooth(a) and smooth(a)*b.
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
        return {"linear": f"linear({v})", "smooth": f"smooth({v})", "product": v}[self.kind]

    def _lin(self, frame: pd.DataFrame, i: int) -> np.ndarray:
        v = self.variables[i]
        lo, hi = self.ranges[i]
        return np.clip(frame[v].to_numpy(), lo, hi) - self.centers[i]

    def design(self, frame: pd.DataFrame) -> np.ndarray:
        if self.kind == "linear":
            return self._lin(frame, 0)[:, None]
        if self.kind == "smooth":
            return _hats(frame[self.variables[0]].to_numpy(), self.knots)[:, 1:]
        if self.kind == "product":
            a, b = self._lin(frame, 0), self._lin(frame, 1)
            return np.column_stack([a, b, a * b])
        h = _hats(frame[self.variables[0]].to_numpy(), self.knots)[:, 1:]
        return np.hstack([h, h * self._lin(frame, 1)[:, None]])

    @property
    def width(self) -> int:
        return {"linear": 1, "product": 3, "smooth": len(self.knots) - 1,
                "smooth_x_linear": 2 * (len(self.knots) - 1)}[self.kind]


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
        if v == "gear_norm":
            terms.append(Term("smooth", (v,), GEAR_KNOTS))
        elif v in shaped:
            if v == "flap_deg":
                knots = tuple(float(x) for x in np.unique(np.round(data[v].to_numpy(), 6)))
            else:
                knots = tuple(np.unique(np.round(np.quantile(data[v], np.linspace(0, 1, 6)), 6)))
            if len(knots) >= 3:
                terms.append(Term("smooth", (v,), knots))
    for a, b in combinations(shaped, 2):
        terms.append(Term("product", (a, b), (), (center[a], center[b]), (rng[a], rng[b])))
    if "gear_norm" in shaped:
        for b in shaped:
            if b != "gear_norm":
                terms.append(Term("smooth_x_linear", ("gear_norm", b), GEAR_KNOTS, (0.0, center[b]),
                                  ((0.0, 1.0), rng[b])))
    return terms


class _Lags:
    """Sample pairs ``(i, i + k)`` within one log, for k = 1..max_lag (cached per dataset)."""

    def __init__(self, log_id: np.ndarray, max_lag: int = 300) -> None:
        n = len(log_id)
        self.pairs = [np.flatnonzero(log_id[k:] == log_id[:n - k]) for k in range(1, max_lag + 1)]

    def n_eff(self, resid: np.ndarray) -> float:
        """Effective number of independent samples: N / (1 + 2 sum rho_k), rho up to its first zero."""
        n = len(resid)
        e = resid - resid.mean()
        r0 = float(e @ e) / n
        if r0 <= 0:
            return float(n)
        tau = 1.0
        for k, idx in enumerate(self.pairs, start=1):
            rho = float(e[idx + k] @ e[idx]) / n / r0
            if rho <= 0:
                break
            tau += 2.0 * rho
        return max(n / tau, 2.0)


@dataclass
class _Fit:
    terms: list[Term]
    beta: np.ndarray
    resid: np.ndarray
    rss: float


def _fit(y: np.ndarray, cols: list[np.ndarray], terms: list[Term]) -> _Fit:
    x = np.column_stack([np.ones(len(y))] + cols) if cols else np.ones((len(y), 1))
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    r = y - x @ beta
    return _Fit(list(terms), beta, r, float(r @ r))


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
             min_reduction: float = 0.01, max_terms: int = 6, lags: _Lags | None = None) -> StepwiseResult:
    """Forward-backward stepwise regression of ``r_<coefficient>`` on candidate terms.

    A term enters if its partial F-test (on the effective sample size of the
    residual after it enters) has p < ``alpha_in`` and it removes at least
    ``min_reduction`` of the initial residual sum of squares (about its mean);
    a term leaves when its removal test no longer passes.
    """
    y = data[f"r_{coefficient}"].to_numpy()
    lags = lags or _Lags(data["log"].to_numpy())
    designs = {t: t.design(data) for t in terms}
    chosen: list[Term] = []
    close: dict[str, list] = {}
    current = _fit(y, [], [])
    rss0 = current.rss
    rms_before = float(np.sqrt(np.mean((y - y.mean()) ** 2)))
    alternatives = []
    for _ in range(max_terms):
        p_now = 1 + sum(t.width for t in chosen)
        rows = []
        for t in terms:
            if t in chosen or (t.kind == "linear" and any(c.kind == "smooth" and c.variables == t.variables
                                                           for c in chosen)):
                continue
            big = _fit(y, [designs[c] for c in chosen] + [designs[t]], chosen + [t])
            n_eff = lags.n_eff(big.resid)
            f, p = _f_test(current, big, t.width, n_eff, p_now + t.width)
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
        current = best["fit"]
        for t in list(chosen[:-1]):  # backward step
            rest = [c for c in chosen if c != t]
            small = _fit(y, [designs[c] for c in rest], rest)
            f, p = _f_test(small, current, t.width, lags.n_eff(current.resid),
                           1 + sum(c.width for c in chosen))
            if p >= alpha_in or (small.rss - current.rss) / rss0 < min_reduction / 2:
                chosen.remove(t)
                current = small
    evidence = {}
    n_eff = lags.n_eff(current.resid)
    p_all = 1 + sum(t.width for t in chosen)
    for t in chosen:
        rest = [c for c in chosen if c != t]
        small = _fit(y, [designs[c] for c in rest], rest)
        f, p = _f_test(small, current, t.width, n_eff, p_all)
        evidence[t.label] = {"F": f, "p_value": p, "dof": [t.width, max(n_eff - p_all, 1.0)],
                             "rss_reduction_pct": 100.0 * (1.0 - current.rss / small.rss)}
    rms_after = float(np.sqrt(np.mean(current.resid ** 2)))
    return StepwiseResult(coefficient, chosen, current.beta, evidence, alternatives, rms_before, rms_after, n_eff,
                          {t.label: close.get(t.label, []) for t in chosen})


@dataclass
class Cause:
    """One named cause: a coefficient, the variables, a shape, the evidence."""

    coefficient: str
    variables: list[str]
    terms: list[Term]
    shape: str
    evidence: dict
    peak: float
    curve: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"coefficient": self.coefficient, "variables": self.variables, "shape": self.shape,
                "evidence": self.evidence, "peak": self.peak, "terms": [t.label for t in self.terms],
                "curve": self.curve}


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
            variables = []
            for t in sorted(g, key=lambda t: t.kind != "smooth" and t.kind != "linear"):
                variables += [v for v in t.variables if v not in variables]
            contrib = sum(t.design(data) @ res.term_beta(t) for t in g) + res.beta[0]
            primary = variables[0]
            grid = pd.DataFrame({v: np.full(41, float(np.median(data[v]))) for v in variables})
            grid[primary] = np.linspace(float(data[primary].min()), float(data[primary].max()), 41)
            cy = sum(t.design(grid) @ res.term_beta(t) for t in g) + res.beta[0]
            cx = grid[primary].to_numpy()
            shape = _shape(cx, cy)
            if len(variables) > 1:
                shape += f", depends on {', '.join(variables[1:])}"
            causes.append(Cause(c, variables, g, shape,
                                {"F": f, "p_value": p, "dof": [k, max(n_eff - p_all, 1.0)],
                                 "rss_reduction_pct": 100.0 * (1.0 - full.rss / small.rss),
                                 "terms": {t.label: res.evidence.get(t.label, {}) for t in g},
                                 "hardly_separated_from": [a for t in g for a in res.close.get(t.label, [])]},
                                float(np.max(np.abs(contrib))),
                                {primary: cx.tolist(), f"d{c}": np.asarray(cy).tolist(),
                                 "others_at_median": {v: float(np.median(data[v])) for v in variables[1:]}}))
    causes.sort(key=lambda c: -c.evidence["F"])
    return causes


@dataclass
class Diagnosis:
    """The result: residuals, stepwise fits, named causes."""

    data: pd.DataFrame
    results: dict[str, StepwiseResult]
    causes: list[Cause]

    @property
    def discrepancy(self) -> bool:
        return bool(self.causes)

    def predict(self, coefficient: str, frame: pd.DataFrame) -> np.ndarray:
        """The fitted discrepancy of one coefficient at the states of ``frame``."""
        res = self.results[coefficient]
        return res.predict(frame) if res.terms else np.zeros(len(frame))

    def summary(self) -> str:
        lines = []
        if not self.causes:
            lines.append("No significant discrepancy: noise alone explains the residuals.")
        for i, c in enumerate(self.causes, 1):
            e = c.evidence
            p = f"p = {e['p_value']:.2g}" if e["p_value"] > 0 else "p < 1e-300"
            lines.append(f"{i}. {c.coefficient} vs {', '.join(c.variables)}: {c.shape}; peak {c.peak:.4g}; "
                         f"F = {e['F']:.4g} on {e['dof'][0]} and {e['dof'][1]:.0f} dof, {p}, "
                         f"removes {e['rss_reduction_pct']:.1f} % of the residual")
            for a in e.get("hardly_separated_from", []):
                lines.append(f"   caution: the data hardly separate it from {a['term']} "
                             f"(F = {a['F']:.4g}, {100 * a['F_ratio']:.0f} % of the chosen term's)")
        lines.append("")
        for c, res in self.results.items():
            lines.append(f"{c}: residual RMS {res.rms_before:.3g} -> {res.rms_after:.3g} with "
                         f"{', '.join(t.label for t in res.terms) or 'no term'} (N_eff {res.n_eff:.0f})")
            lines.append("   alternatives at the first step: " + "; ".join(
                f"{a['term']} F={a['F']:.3g}" for a in res.alternatives[:5]))
        return "\n".join(lines)


def diagnose(logs: list[Log], evaluator, step: int = 2, **kw) -> Diagnosis:
    """Residuals against the model, stepwise structure per coefficient, causes."""
    data = residual_data(logs, evaluator, step)
    lags = _Lags(data["log"].to_numpy())
    results = {c: stepwise(data, c, candidate_terms(data, c), lags=lags, **kw) for c in COEFFS}
    return Diagnosis(data, results, name_causes(results, data, lags))
