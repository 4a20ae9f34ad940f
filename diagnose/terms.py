"""The candidate terms of a residual: every logged variable, linear and smooth (a piecewise-linear
basis), and pairwise interactions; and the sensor-error signatures that compete with them."""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
import pandas as pd

from diagnose.config import current
from diagnose.residuals import COEFFS, SIGNATURES, VARIABLES

#: Rates normalised by cbar/2V: exported as linear terms (products of properties), never as tables.
RATES = {"qhat_rad": "velocities/q-aero-rad_sec", "adothat_rad": "aero/alphadot-rad_sec"}
#: Variables a coefficient's residual may not be regressed on: the CL residual on the model's own CL,
#: a lift error on the lift it is an error of.
EXCLUDED = {"CL": ("CL",)}
GEAR_KNOTS = tuple(np.round(np.linspace(0.0, 1.0, 11), 10))


def hats(x: np.ndarray, knots: tuple[float, ...], out: np.ndarray | None = None) -> np.ndarray:
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
        return {"linear": f"linear({v})", "quadratic": f"quadratic({v})", "smooth": f"smooth({v})", "product": v}[
            self.kind
        ]

    def _lin(self, frame: pd.DataFrame, i: int) -> np.ndarray:
        v = self.variables[i]
        lo, hi = self.ranges[i]
        return np.clip(frame[v].to_numpy(), lo, hi) - self.centers[i]

    def design(self, frame: pd.DataFrame, out: np.ndarray | None = None) -> np.ndarray:
        """The term's columns over ``frame`` (n, :attr:`width`), written into ``out`` if given."""
        out = np.empty((len(frame), self.width)) if out is None else out
        if self.kind in ("smooth", "smooth_x_linear"):
            k = len(self.knots) - 1
            h = hats(frame[self.variables[0]].to_numpy(), self.knots, out[:, :k])
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
        return {
            "linear": 1,
            "quadratic": 2,
            "product": 3,
            "smooth": len(self.knots) - 1,
            "smooth_x_linear": 2 * (len(self.knots) - 1),
        }[self.kind]


def connected(terms: list[Term]) -> list[list[Term]]:
    """``terms`` grouped as one cause where they share a variable, directly or through others."""
    groups: list[list[Term]] = []
    for t in terms:
        hit = [g for g in groups if set(t.variables) & {v for u in g for v in u.variables}]
        groups = [g for g in groups if g not in hit] + [[t] + [u for g in hit for u in g]]
    return groups


def _spread(knots: np.ndarray) -> tuple[float, ...]:
    """Quantile knots thinned so that neighbours are at least ``min_knot_spacing`` of the range apart
    (:func:`diagnose.config.current`)."""
    s = current()
    gap = s.min_knot_spacing * float(knots[-1] - knots[0])
    out = [float(knots[0])]
    for k in knots[1:-1]:
        if k - out[-1] >= gap and knots[-1] - k >= gap:
            out.append(float(k))
    out.append(float(knots[-1]))
    return tuple(out)


def _quantile_knots(x: np.ndarray) -> tuple[float, ...]:
    s = current()
    return _spread(np.unique(np.round(np.quantile(x, np.linspace(0, 1, s.knot_quantiles)), 6)))


def tail_twin(term: Term, data: pd.DataFrame) -> Term | None:
    """``term`` with the tails' knots added (``tail_levels``), if it is a smooth term on quantile
    knots and the tails have room for any; else None. The stepwise search may refine a smooth term it
    chose to its twin (:func:`diagnose.stepwise.stepwise`)."""
    s = current()
    v = term.variables[0]
    if term.kind != "smooth" or v not in data or v in ("gear_norm", "flap_deg"):
        return None
    x = data[v].to_numpy(float)
    knots = list(term.knots)
    gap = s.tail_spacing * (knots[-1] - knots[0])
    for q in np.round(np.quantile(x, s.tail_levels), 6):
        if min(abs(float(q) - k) for k in knots) >= gap:
            knots.append(float(q))
    return Term(term.kind, term.variables, tuple(sorted(knots))) if len(knots) > len(term.knots) else None


def candidate_terms(data: pd.DataFrame, coefficient: str | None = None) -> list[Term]:
    """The candidate pool of one coefficient's residual: every excited variable,
    linear and smooth, and pairs (interactions carry their main effects): products of two,
    a smooth gear term that varies linearly with each other variable, and a smooth term in
    alpha or Mach that varies linearly with the other (a shape in alpha that compressibility
    scales: with only their product, a table in alpha growing with Mach was named against one).

    Rates normalised by cbar/2V enter linearly only. A coefficient is never
    regressed on itself (:data:`EXCLUDED`). A variable is a candidate where it varies by the settings'
    ``min_std`` (:func:`diagnose.config.current`), smooth terms' knots are its ``knot_quantiles``
    thinned to ``min_knot_spacing``.
    """
    s = current()
    banned = EXCLUDED.get(coefficient, ())
    excited = [v for v in VARIABLES if v in data and v not in banned and float(data[v].std()) >= s.min_std[v]]
    if "CL" in excited and float(data["CL"].min()) <= 0.05:
        excited.remove("CL")  # exported through CL^2: needs a lift coefficient that stays positive
    center = {v: float(np.median(data[v])) for v in excited}
    rng = {v: (-np.inf, np.inf) if v in RATES else (float(data[v].min()), float(data[v].max())) for v in excited}
    shaped = [v for v in excited if v not in RATES]
    terms = []
    smooth_knots = {}
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
                knots = _quantile_knots(data[v])
            if len(knots) >= 3:
                terms.append(Term("smooth", (v,), knots))
                smooth_knots[v] = knots
    for a, b in combinations(shaped, 2):
        terms.append(Term("product", (a, b), (), (center[a], center[b]), (rng[a], rng[b])))
    if "gear_norm" in shaped:
        for b in shaped:
            if b != "gear_norm":
                terms.append(
                    Term("smooth_x_linear", ("gear_norm", b), GEAR_KNOTS, (0.0, center[b]), ((0.0, 1.0), rng[b]))
                )
    for a, b in (("alpha_deg", "mach"), ("mach", "alpha_deg")):
        if a in smooth_knots and b in shaped:
            terms.append(Term("smooth_x_linear", (a, b), smooth_knots[a], (0.0, center[b]), (rng[a], rng[b])))
    for sig in SIGNATURES:  # sensor errors the kinematics cannot see compete with the aero terms
        v = f"{sig}_{coefficient}"
        if coefficient and v in data and float(data[v].std()) > 1e-6:
            terms.append(Term("linear", (v,), (), (0.0,), ((-np.inf, np.inf),)))
    return terms


def sensor_of(variable: str) -> tuple[str, str] | None:
    """(channel, error) if a variable is a sensor error's signature, else None."""
    head = variable.rsplit("_", 1)[0]
    return SIGNATURES.get(head) if variable.rsplit("_", 1)[-1] in COEFFS else None
