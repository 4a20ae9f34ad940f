"""Causes: the selected terms that share a variable, grouped, shaped and ranked by F."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from diagnose.stepwise import Fit, Lags, StepwiseResult, f_logsf, f_test, fit_terms
from diagnose.terms import Term, connected, hats, sensor_of


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
        common = {
            "kind": self.kind,
            "shape": self.shape,
            "evidence": self.evidence,
            "peak": self.peak,
            "size": self.size,
            "verdict": self.verdict,
            "terms": [t.label for t in self.terms],
            "curve": self.curve,
        }
        if self.kind == "sensor":
            return {
                **common,
                "channel": self.channel,
                "error": self.error,
                "estimate": self.estimate,
                "se": self.se,
                "coefficient": self.coefficient,
            }
        return {**common, "coefficient": self.coefficient, "variables": self.variables}


def shape_of(x: np.ndarray, y: np.ndarray) -> str:
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
    design = np.column_stack([np.ones(len(x)), hats(x, tuple(knots))])
    beta, *_ = np.linalg.lstsq(design, y, rcond=None)
    e = y - design @ beta
    ss = float(((y - y.mean()) ** 2).sum())
    return 1.0 - float(e @ e) / ss if ss > 0 else 0.0


def along(
    group: list[Term], res: StepwiseResult, data: pd.DataFrame, variable: str, n: int = 41
) -> tuple[np.ndarray, np.ndarray]:
    """A group's contribution along one of its variables, the others at their median."""
    names = {v for t in group for v in t.variables}
    grid = pd.DataFrame({v: np.full(n, float(np.median(data[v]))) for v in names})
    grid[variable] = np.linspace(float(data[variable].min()), float(data[variable].max()), n)
    return grid[variable].to_numpy(), sum(t.design(grid) @ res.term_beta(t) for t in group)


def held_constant(contrib: np.ndarray) -> float:
    """The constant a cause's contribution [-] carries that the intercept takes back: its median, if that
    is larger than the contribution's whole range over the data, else 0. Terms whose columns nearly hold
    a constant between them (smooth(elevator) beside elevator x Mach, where each condition trims at its
    own elevator) split it with the intercept arbitrarily: "CL vs elevator_deg, mach" was reported with a
    peak of 83,000, and five of 806 causes in the detection curve's records were so."""
    contrib = np.asarray(contrib, dtype=float)
    med = float(np.median(contrib)) if contrib.size else 0.0
    return med if abs(med) > float(np.ptp(contrib)) else 0.0


def name_causes(results: dict[str, StepwiseResult], data: pd.DataFrame, lags: Lags) -> list[Cause]:
    """Group selected terms into causes (terms sharing a variable), rank by F."""
    causes = []
    for c, res in results.items():
        groups = connected(res.terms)
        y = data[f"r_{c}"].to_numpy()
        designs = {t: t.design(data) for t in res.terms}
        full = fit_terms(y, [designs[t] for t in res.terms], res.terms)
        n_eff = lags.n_eff(full.resid)
        p_all = 1 + sum(t.width for t in res.terms)
        for g in groups:
            rest = [t for t in res.terms if t not in g]
            small = fit_terms(y, [designs[t] for t in rest], rest)
            k = sum(t.width for t in g)
            f, p = f_test(small, full, k, n_eff, p_all)
            contrib = sum(t.design(data) @ res.term_beta(t) for t in g)
            # one-variable terms' variables first, the one whose function alone makes most of the cause
            # first of them (not the one that entered first: a drag step in alpha on the A320 came in
            # as smooth(CL), then quadratic(alpha) and alpha x CL, and was named "CD vs CL, alpha")
            single = list(dict.fromkeys(t.variables[0] for t in g if t.kind in ("smooth", "linear", "quadratic")))
            variables = (
                sorted(single, key=lambda v: -_share(contrib, data[v].to_numpy())) if len(single) > 1 else single
            )
            for t in sorted(g, key=lambda t: t.kind not in ("smooth", "linear", "quadratic")):
                ordered = t.variables
                # the variable that alone explains more of the cause comes first; a smooth gear term that
                # varies with another variable is a gear effect (the pool holds no smooth term the other way)
                if t.kind == "product" or (t.kind == "smooth_x_linear" and t.variables[0] != "gear_norm"):
                    ordered = tuple(sorted(t.variables, key=lambda v: -_share(contrib, data[v].to_numpy())))
                variables += [v for v in ordered if v not in variables]
            primary = variables[0]
            cx, cy = along(g, res, data, primary)
            held = held_constant(contrib)
            contrib, cy = contrib - held, cy - held
            shape = shape_of(cx, cy)
            if len(variables) > 1:
                shape += f", depends on {', '.join(variables[1:])}"
            sensor = sensor_of(variables[0]) if len(g) == 1 else None
            if sensor:
                # the signature is per unit of the logged value: beta = e / (1 + e) for logged = (1 + e) true
                beta = float(res.term_beta(g[0])[0])
                se = _se(
                    full,
                    [designs[t] for t in res.terms],
                    sum(t.width for t in res.terms[: res.terms.index(g[0])]),
                    n_eff,
                )
                cause_kw = {
                    "kind": "sensor",
                    "channel": sensor[0],
                    "error": sensor[1],
                    "estimate": beta / (1.0 - beta),
                    "se": se / (1.0 - beta) ** 2,
                    "shape": "scale factor",
                }
            else:
                cause_kw = {}
            causes.append(
                Cause(
                    c,
                    variables,
                    g,
                    shape,
                    {
                        "F": f,
                        "p_value": p,
                        "dof": [k, max(n_eff - p_all, 1.0)],
                        "log10_p": f_logsf(f, k, max(n_eff - p_all, 1.0)) / np.log(10.0),
                        "rss_reduction_pct": 100.0 * (1.0 - full.rss / small.rss),
                        "terms": {t.label: res.evidence.get(t.label, {}) for t in g},
                        "hardly_separated_from": [a for t in g for a in res.close.get(t.label, [])],
                    },
                    float(np.max(np.abs(contrib))),
                    {
                        primary: cx.tolist(),
                        f"d{c}": np.asarray(cy).tolist(),
                        "others_at_median": {v: float(np.median(data[v])) for v in variables[1:]},
                    },
                    float(np.ptp(contrib)),
                )
            )
            for k, v in cause_kw.items():
                setattr(causes[-1], k, v)
    causes.sort(key=lambda c: -c.evidence["F"])
    return causes


def _se(fit: Fit, cols: list[np.ndarray], column: int, n_eff: float) -> float:
    """Standard error of one design column's coefficient (0 is the first after the intercept),
    inflated by N / N_eff for the residual's autocorrelation."""
    x = np.column_stack([np.ones(len(fit.resid))] + cols)
    n, p = x.shape
    var = np.linalg.pinv(x.T @ x)[1 + column, 1 + column] * fit.rss / max(n - p, 1) * n / max(n_eff, 1.0)
    return float(np.sqrt(var))


def merge_sensors(causes: list[Cause]) -> list[Cause]:
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
            {"coefficient": other.coefficient, "estimate": other.estimate, "se": other.se, "F": other.evidence["F"]}
        )
        keep.evidence["also_in"] += other.evidence.get("also_in", [])
        if keep is c:
            out[out.index(first)] = c
            seen[key] = c
    return out
