"""Baseline (eq. 3), linear gear (eq. 4) and nonlinear gear (eqs. 8, 9) models.

Regressors are deviations from one reference state per flight condition
(altitude, Mach, flap): the gear-up trim. Gear-up and gear-down fits then share
a reference, and ``C0_gearDn - C0_gearUp`` is the gear increment at that state.
Before the fits, the coefficients and the regressors pass through the same
zero-phase low-pass filter: a linear relation between them is unchanged, while
sensor noise in the regressors (which biases least squares) shrinks.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np
import pandas as pd
from scipy.interpolate import make_smoothing_spline
from scipy.linalg import eigh, solve
from scipy.optimize import minimize_scalar
from scipy.signal import butter, lfilter, lfilter_zi

from identify.coefficients import D2R, coefficients, qhat
from identify.kinematics import ANCHOR_S, odd_extension
from identify.logs import Log
from identify.lsq import LeastSquares, LSResults

COEFFS = ("CL", "CD", "Cm")
REGRESSORS = ("dalpha_rad", "qhat_rad", "delevator_rad", "dstabilizer_rad", "dmach", "dalpha2_rad2")
PARAM_SUFFIX = {
    "const": "0",
    "dalpha_rad": "alpha_per_rad",
    "qhat_rad": "q_per_rad",
    "delevator_rad": "de_per_rad",
    "dstabilizer_rad": "dh_per_rad",
    "dmach": "mach",
    "dalpha2_rad2": "alpha2_per_rad2",
}
#: A regressor varying less than this (std over the manoeuvre) was not excited.
MIN_STD = {
    "dalpha_rad": 0.05 * D2R,
    "qhat_rad": 1e-5,
    "delevator_rad": 0.05 * D2R,
    "dstabilizer_rad": 0.05 * D2R,
    "dmach": 0.002,
    "dalpha2_rad2": (0.5 * D2R) ** 2,
}
CUTOFF_HZ = 3.0
EDGE_S = 0.25  # dropped at both ends of a filtered record (filter start-up)
GRID = np.round(np.linspace(0.0, 1.0, 21), 10)


@lru_cache(maxsize=64)
def _butter(wn: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The filter's coefficients and the steady state of its step response (``lfilter_zi``)."""
    b, a = butter(4, wn)
    return b, a, lfilter_zi(b, a)


def lowpass(x: np.ndarray, dt: float, cutoff_hz: float = CUTOFF_HZ) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass filter, the ends padded by
    :func:`identify.kinematics.odd_extension`. A 2-D ``x`` is filtered along axis 0,
    each column on its own (one call for many signals of the same record).

    This is ``scipy.signal.filtfilt(b, a, x, axis=0, padtype=None)`` step by step, with
    ``lfilter_zi`` computed once per filter instead of once per call (a third of the
    filter's time on a log's columns); the results are the same to the bit.
    """
    b, a, zi = _butter(cutoff_hz * 2.0 * dt)
    x = np.asarray(x, dtype=float)
    pad = min(len(x) - 1, 3 * max(len(a), len(b)) * 20)
    ext = odd_extension(x, pad, int(round(ANCHOR_S / dt)))
    z = zi.reshape((-1,) + (1,) * (ext.ndim - 1))
    y, _ = lfilter(b, a, ext, axis=0, zi=z * ext[:1])
    y, _ = lfilter(b, a, y[::-1], axis=0, zi=z * y[-1:])
    return y[::-1][pad : pad + len(x)]


def sample_interval(log: Log) -> float:
    return float(np.median(np.diff(log.data["t_s"].to_numpy())))


@dataclass(frozen=True)
class Reference:
    """Reference state of a flight condition: its gear-up trim."""

    alpha_deg: float
    elevator_deg: float
    stabilizer_deg: float
    mach: float
    source: str
    se: tuple = ()  # ((regressor, standard error of the reference value [regressor units]), ...)


def _steady_head(log: Log, seconds: float = 1.0) -> pd.DataFrame:
    d = log.data
    return d[d["t_s"] < seconds]


def _reference(frame: pd.DataFrame, source: str) -> Reference:
    n = max(len(frame), 1)
    se = (
        ("dalpha_rad", float(frame.alpha_deg.std(ddof=1)) * D2R / np.sqrt(n)),
        ("delevator_rad", float(frame.elevator_deg.std(ddof=1)) * D2R / np.sqrt(n)),
        ("dstabilizer_rad", float(frame.stabilizer_deg.std(ddof=1)) * D2R / np.sqrt(n)),
        ("dmach", float(frame.mach.std(ddof=1)) / np.sqrt(n)),
    )
    return Reference(
        float(frame.alpha_deg.mean()),
        float(frame.elevator_deg.mean()),
        float(frame.stabilizer_deg.mean()),
        float(frame.mach.mean()),
        source,
        tuple((k, v if np.isfinite(v) else 0.0) for k, v in se),
    )


def reference_order(logs: list) -> dict[tuple, tuple[list, object]]:
    """Per condition, the logs its reference may come from, from what is known before reading them
    (:class:`identify.logs.Log` or :class:`identify.logs.LogHead`): the candidates in order of
    preference (gear extensions first, gear-up points next) and the condition's first log, whose own
    trim serves a condition flown gear-down only (:func:`reference_of`)."""
    order: dict[tuple, tuple[list, object]] = {}
    for log in logs:
        order.setdefault(log.condition, ([], log))
    for log in sorted(logs, key=lambda lg: (lg.maneuver != "gear_extension", lg.gear_down)):
        order[log.condition][0].append(log)
    return order


def reference_of(candidates, fallback: Log) -> Reference:
    """The reference of one condition: the first second of the first candidate log that starts gear
    up, else of ``fallback`` (:func:`reference_order`); ``candidates`` may be an iterator that reads
    each log as it is asked for."""
    for log in candidates:
        if log.data["gear_norm"].iloc[0] == 0.0:
            return _reference(_steady_head(log), log.path)
    return _reference(_steady_head(fallback), fallback.path)


def regressors(log: Log, ref: Reference) -> pd.DataFrame:
    """Eq. (3) regressors [rad] about the reference state, with a constant."""
    d = log.data
    return pd.DataFrame(
        {
            "const": 1.0,
            "dalpha_rad": (d["alpha_deg"] - ref.alpha_deg) * D2R,
            "qhat_rad": qhat(d, log.meta),
            "delevator_rad": (d["elevator_deg"] - ref.elevator_deg) * D2R,
            "dstabilizer_rad": (d["stabilizer_deg"] - ref.stabilizer_deg) * D2R,
            "dmach": d["mach"] - ref.mach,
            "dalpha2_rad2": ((d["alpha_deg"] - ref.alpha_deg) * D2R) ** 2,
        },
        index=d.index,
    )


def filtered_frame(log: Log, frame: pd.DataFrame) -> pd.DataFrame:
    dt = sample_interval(log)
    out = frame.copy()
    cols = [c for c in frame.columns if c != "const"]
    if cols:
        out[cols] = lowpass(frame[cols].to_numpy(dtype=float), dt)
    return out


@dataclass
class PointFit:
    """Eq. (3) fits of CL, CD and Cm on one 2-3-1-1."""

    point: str
    path: str
    condition: tuple
    gear_down: bool
    reference: Reference
    fits: dict[str, LSResults]
    alpha_trim_deg: float
    t_s: np.ndarray = field(repr=False, default=None)
    #: ``{"method", "reason"}`` when the time-domain method asked for did not converge (the fits
    #: are then the equation error's, labelled ``ee``)
    failure: dict | None = None
    #: what a time-domain fit reports of the point: method, records fitted together, structure,
    #: iterations, convergence, dimensional derivatives (None for equation error)
    timedomain: dict | None = None

    def param(self, coeff: str, regressor: str) -> float | None:
        res = self.fits[coeff]
        return float(res.params[regressor]) if regressor in res.params.index else None

    def slim(self) -> "PointFit":
        """The same fit without its per-sample series (kept for the points whose fit is plotted)."""
        return replace(self, fits={c: r.slim() for c, r in self.fits.items()}, t_s=None)

    def table(self) -> pd.DataFrame:
        """Parameters like the paper's Table 2: one row per coefficient, '' where not identifiable."""
        rows = {}
        for c, res in self.fits.items():
            rows[c] = [f"{res.params[r]:.6g}" if r in res.params.index else "n/i" for r in ("const", *REGRESSORS)]
        return pd.DataFrame(rows, index=[PARAM_SUFFIX[r] for r in ("const", *REGRESSORS)]).T

    def summary(self) -> str:
        head = (
            f"{self.point} ({'gear down' if self.gear_down else 'gear up'}), regressors about "
            f"alpha {self.reference.alpha_deg:.3f} deg, elevator {self.reference.elevator_deg:.3f} deg, "
            f"stabilizer {self.reference.stabilizer_deg:.3f} deg"
        )
        lines = [head]
        names = {"oe": "output error", "fe": "filter error"}
        if self.failure:
            lines.append(
                f"NOT CONVERGED by {names.get(self.failure['method'], self.failure['method'])}: "
                f"{self.failure['reason']}; the estimates below are the equation error's (ee)"
            )
        elif self.timedomain:
            td = self.timedomain
            lines.append(
                f"by {names.get(td['method'], td['method'])} ({td['method']}), converged in {td['iterations']} "
                f"iterations, records fitted together: {', '.join(td['records'])}"
            )
            lines.append(
                "  structure: "
                + ", ".join(f"{c} {' '.join(t)}" for c, t in td["structure"]["terms"].items() if t)
                + f"; states {' '.join(td['structure']['states'])}"
            )
            if td["structure"]["left_out"]:
                lines.append("  left out: " + "; ".join(f"{k}: {v}" for k, v in td["structure"]["left_out"].items()))
            if td.get("derivatives"):
                lines.append(
                    "  dimensional derivatives: " + ", ".join(f"{k} {v:.4g}" for k, v in td["derivatives"].items())
                )
        return "\n".join(lines + [self.fits[c].summary() for c in COEFFS])


def fit_baseline(log: Log, ref: Reference) -> PointFit:
    """Least squares of eq. (3) on one 2-3-1-1 log."""
    edge = int(round(EDGE_S / sample_interval(log)))
    inner = slice(edge, len(log.data) - edge)
    y = filtered_frame(log, coefficients(log.data, log.meta)).iloc[inner]
    x = filtered_frame(log, regressors(log, ref)).iloc[inner]
    fits = {
        c: LeastSquares(y[c], x, MIN_STD, hac_lags=int(round(2.0 / sample_interval(log))), name=c).fit() for c in COEFFS
    }
    for res in fits.values():
        # C0 is the coefficient at the reference state, itself a mean of measured samples
        extra = sum((res.params[r] * se) ** 2 for r, se in ref.se if r in res.params.index)
        res.bse["const"] = float(np.sqrt(res.bse["const"] ** 2 + extra))
    return PointFit(
        log.point,
        log.path,
        log.condition,
        log.gear_down,
        ref,
        fits,
        float(_steady_head(log).alpha_deg.mean()),
        log.data["t_s"].to_numpy()[inner],
    )


@dataclass
class LinearGearModel:
    """Eq. (4) at one condition: averaged derivatives, C0 gear up and gear down (Table 3)."""

    condition: tuple
    alpha_trim_deg: float
    derivatives: dict[str, dict[str, float]]
    c0_up: dict[str, float]
    c0_dn: dict[str, float]
    c0_up_bse: dict[str, float] = field(default_factory=dict)
    c0_dn_bse: dict[str, float] = field(default_factory=dict)

    def increment(self, coeff: str) -> float:
        """Gear-down minus gear-up at the reference state [-]."""
        return self.c0_dn[coeff] - self.c0_up[coeff]

    def to_dict(self) -> dict:
        return {
            "condition": {"alt_ft": self.condition[0], "mach": self.condition[1], "flap_deg": self.condition[2]},
            "alpha_trim_deg": self.alpha_trim_deg,
            "derivatives": self.derivatives,
            "C0_gearup": self.c0_up,
            "C0_gearDn": self.c0_dn,
            "C0_gearup_bse": self.c0_up_bse,
            "C0_gearDn_bse": self.c0_dn_bse,
            "increment": {c: self.increment(c) for c in COEFFS},
        }


def linear_models(fits) -> dict[tuple, LinearGearModel]:
    """One linear gear model per condition flown gear up and gear down, from per-point results
    (``fits``, any iterable of :class:`PointFit`, read once: only what the models need of each is kept)."""
    by_cond: dict[tuple, dict[bool, tuple]] = {}
    for f in fits:
        by_cond.setdefault(f.condition, {})[f.gear_down] = (
            f.alpha_trim_deg,
            {c: {r: f.param(c, r) for r in ("const", *REGRESSORS)} for c in COEFFS},
            {c: float(f.fits[c].bse["const"]) for c in COEFFS},
        )
    out = {}
    for cond, pair in by_cond.items():
        if True not in pair or False not in pair:
            continue
        (alpha_up, up, up_bse), (_, dn, dn_bse) = pair[False], pair[True]
        deriv = {}
        for c in COEFFS:
            deriv[c] = {}
            for r in REGRESSORS:
                vals = [v for v in (up[c][r], dn[c][r]) if v is not None]
                if vals:
                    deriv[c][r] = float(np.mean(vals))
        out[cond] = LinearGearModel(
            cond,
            alpha_up,
            deriv,
            {c: up[c]["const"] for c in COEFFS},
            {c: dn[c]["const"] for c in COEFFS},
            up_bse,
            dn_bse,
        )
    return out


@dataclass
class Increments:
    """Eq. (8) increments along one gear transition, and their smoothing spline."""

    point: str
    condition: tuple
    alpha_trim_deg: float
    gear_norm: np.ndarray
    raw: dict[str, np.ndarray]
    grid: np.ndarray
    smooth: dict[str, np.ndarray]
    alpha_deg: np.ndarray
    #: Standard error of :attr:`smooth` [-], one value per coefficient (the noise about the
    #: spline over its effective number of parameters).
    se: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "gear_norm": self.grid.tolist(),
            **{f"d{c}": self.smooth[c].tolist() for c in COEFFS},
            "alpha_trim_deg": self.alpha_trim_deg,
        }

    def slim(self, samples: int = 200) -> "Increments":
        """The same increments with the per-sample series cut to the gear's travel, at most
        ``samples`` of them (what Fig. 11 draws), and the raw increments dropped: what a campaign of
        thousands of points holds."""
        moving = np.flatnonzero((self.gear_norm > 0.0) & (self.gear_norm < 1.0))
        moving = moving[:: max(1, -(-len(moving) // samples))]
        return replace(self, gear_norm=self.gear_norm[moving], alpha_deg=self.alpha_deg[moving], raw={})


def increments(log: Log, derivatives: dict[str, dict[str, float]]) -> Increments:
    """Eq. (8): what the baseline does not explain along a gear transition.

    The gear-up part of the log (before an extension, after a retraction) is the
    reference: its mean coefficients are ``C0_gearup`` and its mean state the
    point the regressors are taken about.
    """
    coef = filtered_frame(log, coefficients(log.data, log.meta))
    d = log.data
    up = (d["gear_norm"] == 0.0).to_numpy()
    ref = _reference(d[up], log.path)
    x = filtered_frame(log, regressors(log, ref))
    x["qhat_rad"] = x["qhat_rad"] - x["qhat_rad"][up].mean()
    raw = {}
    for c in COEFFS:
        f = coef[c].to_numpy() - coef[c][up].mean()
        for r, v in derivatives[c].items():
            f = f - v * x[r].to_numpy()
        raw[c] = f
    g = d["gear_norm"].to_numpy()
    fitted = {c: _spline_on_grid(g, raw[c]) for c in COEFFS}
    return Increments(
        log.point,
        log.condition,
        ref.alpha_deg,
        g,
        raw,
        GRID,
        {c: v for c, (v, _) in fitted.items()},
        d["alpha_deg"].to_numpy(),
        {c: se for c, (_, se) in fitted.items()},
    )


def _spline_on_grid(g: np.ndarray, f: np.ndarray, bins: int = 100) -> tuple[np.ndarray, float]:
    """Smoothing spline of f(g), its smoothing chosen by GCV, evaluated on GRID, and its
    standard error.

    Samples are first averaged in ``bins`` equal bins of g (weights: counts),
    so the end stops and the slow end of the travel do not crowd the spline. The standard
    error is the average pointwise one, ``sigma sqrt(edf / n)``: ``sigma`` the weighted scatter
    of the bin means about the spline over ``n - edf`` degrees of freedom, ``edf`` the spline's
    effective number of parameters.
    """
    edges = np.linspace(0.0, 1.0, bins + 1)
    idx = np.clip(np.digitize(g, edges[1:-1]), 0, bins - 1)
    xs, ys, ws = [], [], []
    for b in range(bins):
        sel = idx == b
        if sel.any():
            xs.append(float(g[sel].mean()))
            ys.append(float(f[sel].mean()))
            ws.append(float(sel.sum()))
    x, y, w = np.array(xs), np.array(ys), np.array(ws) / np.mean(ws)
    lam, edf = gcv_lambda(x, y, w, edf=True)
    spline = make_smoothing_spline(x, y, w=w, lam=lam)
    n = len(x)
    sigma2 = float(np.sum(w * (y - spline(x)) ** 2)) / max(n - edf, 1.0)
    return spline(GRID), float(np.sqrt(sigma2 * edf / n))


def gcv_lambda(x: np.ndarray, y: np.ndarray, w: np.ndarray, edf: bool = False) -> float | tuple[float, float]:
    """The smoothing ``lam`` that scipy's ``make_smoothing_spline(x, y, w, lam=None)`` chooses by
    generalized cross-validation, found in the Reinsch form with one eigendecomposition.

    The same criterion (unweighted residual over ``(1 - tr A / n)^2``) and the same bounded
    search over ``[0, n]``; each evaluation is a matrix-vector product instead of scipy's
    banded inverse in Python loops (5-6 times faster at 100 points, the same ``lam`` to
    about 1e-7). With ``edf`` it returns ``(lam, edf)``, ``edf`` the smoother's trace (its
    effective number of parameters).
    """
    n = len(x)
    h = np.diff(x)
    j = np.arange(n - 2)
    q = np.zeros((n, n - 2))
    q[j, j], q[j + 1, j], q[j + 2, j] = 1 / h[:-1], -1 / h[:-1] - 1 / h[1:], 1 / h[1:]
    r = np.diag((h[:-1] + h[1:]) / 3) + np.diag(h[1:-1] / 6, 1) + np.diag(h[1:-1] / 6, -1)
    sw = np.sqrt(w)
    d, u = eigh(q @ solve(r, q.T, assume_a="pos") / np.outer(sw, sw))
    d = np.clip(d, 0.0, None)
    z, v = u.T @ (sw * y), u / sw[:, None]

    def gcv(lam: float) -> float:
        res = v @ (lam * d / (1 + lam * d) * z)
        return (res @ res / n) / (1 - np.sum(1 / (1 + lam * d)) / n) ** 2

    lam = float(minimize_scalar(gcv, bounds=(0, n), method="Bounded").x)
    return (lam, float(np.sum(1 / (1 + lam * d)))) if edf else lam


ALPHA_MARGIN_DEG = 5.0
MACH_MARGIN = 0.1

#: Candidate designs for eq. (9) across conditions of one flap setting.
DESIGNS = {"constant": ("const",), "alpha": ("const", "alpha"), "alpha+mach": ("const", "alpha", "mach")}


@dataclass
class GearSurface:
    """Eq. (9): gear increments over delta_LG, alpha, Mach and flap.

    For each flap setting and each delta_LG node, each coefficient increment is
    a linear function of alpha and Mach, its terms chosen by leave-one-out
    cross-validation among :data:`DESIGNS`. Between flap settings the model
    interpolates linearly; outside them it holds the nearest. In alpha and Mach
    it extrapolates linearly up to :data:`ALPHA_MARGIN_DEG` and
    :data:`MACH_MARGIN` beyond the data, and holds its value further out.

    :attr:`basis` carries each fit's uncertainty: a draw of the surface is
    ``coef + sum_j z_j basis[j]`` (:meth:`draw`), whose covariance is the least-squares one
    (see :func:`fit_surface`). The ``z_j`` are standard normal times one
    ``sqrt(dof / chi2(dof))`` per fit: Student's t, as the residual variance is itself estimated
    from ``dof`` degrees of freedom.
    """

    grid: np.ndarray
    flaps: list[int]
    designs: dict[tuple[int, str], str]
    coef: dict[tuple[int, str], np.ndarray]  # (flap, C) -> (n_grid, n_terms)
    alpha_range: dict[int, tuple[float, float]]
    mach_range: dict[int, tuple[float, float]]
    cv_rmse: dict[tuple[int, str], dict[str, float]]
    basis: dict[tuple[int, str], np.ndarray] = field(default_factory=dict)  # (flap, C) -> (m, n_grid, n_terms)
    dof: dict[tuple[int, str], float] = field(default_factory=dict)  # residual degrees of freedom (inf: known)

    def se(self, flap: int, c: str) -> np.ndarray:
        """Standard errors of :attr:`coef` ``[(flap, c)]`` [-], shape (n_grid, n_terms): the scale of the
        draws (their Student-t spread is wider by ``sqrt(dof / (dof - 2))`` where that is finite)."""
        b = self.basis.get((flap, c))
        return np.zeros_like(self.coef[(flap, c)]) if b is None or not len(b) else np.sqrt(np.sum(b**2, axis=0))

    def draw(self, rng: np.random.Generator) -> "GearSurface":
        """The surface with its coefficients drawn from their covariance."""
        coef = {}
        for k, v in self.coef.items():
            b = self.basis.get(k, ())
            if not len(b):
                coef[k] = v.copy()
                continue
            z = rng.standard_normal(len(b))
            dof = self.dof.get(k, np.inf)
            if np.isfinite(dof):
                z *= np.sqrt(dof / rng.chisquare(dof))
            coef[k] = v + np.einsum("m,mgp->gp", z, b)
        return replace(self, coef=coef)

    def to_arrays(self) -> dict:
        """Everything :meth:`from_arrays` needs, as JSON-ready lists."""
        return {
            **self.to_dict(),
            "coef": {f"{f}/{c}": v.tolist() for (f, c), v in self.coef.items()},
            "basis": {f"{f}/{c}": v.tolist() for (f, c), v in self.basis.items()},
            "dof": {f"{f}/{c}": v if np.isfinite(v) else None for (f, c), v in self.dof.items()},
        }

    @classmethod
    def from_arrays(cls, d: dict) -> "GearSurface":
        def key(k: str) -> tuple[float, str]:
            f, c = k.split("/")
            return float(f), c

        return cls(
            np.array(d["grid"]),
            [float(f) for f in d["flaps"]],
            {key(k): v for k, v in d["designs"].items()},
            {key(k): np.array(v) for k, v in d["coef"].items()},
            {float(f): tuple(v) for f, v in d["alpha_range_deg"].items()},
            {float(f): tuple(v) for f, v in d["mach_range"].items()},
            {key(k): v for k, v in d["cv_rmse"].items()},
            {key(k): np.array(v).reshape(-1, *np.shape(d["coef"][k])) for k, v in d["basis"].items()},
            {key(k): np.inf if v is None else float(v) for k, v in d.get("dof", {}).items()},
        )

    def table_range(self, flap: int) -> tuple[tuple[float, float], tuple[float, float]]:
        """Alpha [deg] and Mach intervals the tables span (data plus margins)."""
        lo, hi = self.alpha_range[flap]
        mlo, mhi = self.mach_range[flap]
        return ((lo - ALPHA_MARGIN_DEG, hi + ALPHA_MARGIN_DEG), (max(mlo - MACH_MARGIN, 0.0), mhi + MACH_MARGIN))

    def _at_flap(self, flap: int, c: str, alpha_deg: float, mach: float) -> np.ndarray:
        (lo, hi), (mlo, mhi) = self.table_range(flap)
        a = min(max(alpha_deg, lo), hi)
        m = min(max(mach, mlo), mhi)
        terms = {"const": 1.0, "alpha": a, "mach": m}
        names = DESIGNS[self.designs[(flap, c)]]
        return self.coef[(flap, c)] @ np.array([terms[t] for t in names])

    def curve(self, c: str, alpha_deg: float, mach: float, flap_deg: float) -> np.ndarray:
        """Increment of coefficient ``c`` on :attr:`grid` at one state."""
        flaps = self.flaps
        if flap_deg <= flaps[0]:
            return self._at_flap(flaps[0], c, alpha_deg, mach)
        if flap_deg >= flaps[-1]:
            return self._at_flap(flaps[-1], c, alpha_deg, mach)
        i = int(np.searchsorted(flaps, flap_deg)) - 1
        w = (flap_deg - flaps[i]) / (flaps[i + 1] - flaps[i])
        return (1 - w) * self._at_flap(flaps[i], c, alpha_deg, mach) + w * self._at_flap(
            flaps[i + 1], c, alpha_deg, mach
        )

    def __call__(self, c: str, gear_norm: float, alpha_deg: float, mach: float, flap_deg: float) -> float:
        return float(np.interp(gear_norm, self.grid, self.curve(c, alpha_deg, mach, flap_deg)))

    def to_dict(self) -> dict:
        return {
            "grid": self.grid.tolist(),
            "flaps": self.flaps,
            "designs": {f"{f}/{c}": d for (f, c), d in self.designs.items()},
            "cv_rmse": {f"{f}/{c}": v for (f, c), v in self.cv_rmse.items()},
            "alpha_range_deg": {str(f): list(v) for f, v in self.alpha_range.items()},
            "mach_range": {str(f): list(v) for f, v in self.mach_range.items()},
        }


def fit_surface(curves: list[tuple]) -> GearSurface:
    """Fit eq. (9) from per-condition curves.

    The coefficients' covariance is least squares' ``(X'X)^-1`` (across conditions) times the
    covariance of the curves' scatter about the fit (across grid nodes, over ``n - p``
    degrees of freedom), so it holds the measurement noise and what the design leaves
    unexplained. A flap setting with no degrees of freedom left (as many conditions as terms)
    falls back on the curves' own standard errors.

    Parameters
    ----------
    curves : list of (condition, alpha_trim_deg, grid, {C: values on grid}[, {C: standard error on grid}])
    """
    grid = curves[0][2]
    flaps = sorted({cond[2] for cond, *_ in curves})
    designs, coef, cv, ar, mr, basis, dof = {}, {}, {}, {}, {}, {}, {}
    for flap in flaps:
        rows = [(cur[1], cur[0][1], cur[3], cur[4] if len(cur) > 4 else {}) for cur in curves if cur[0][2] == flap]
        alpha = np.array([r[0] for r in rows])
        mach = np.array([r[1] for r in rows])
        ar[flap] = (float(alpha.min()), float(alpha.max()))
        mr[flap] = (float(mach.min()), float(mach.max()))
        terms = {"const": np.ones_like(alpha), "alpha": alpha, "mach": mach}
        for c in COEFFS:
            y = np.array([r[2][c] for r in rows])  # (n, n_grid)
            scores = {}
            for name, cols in DESIGNS.items():
                x = np.column_stack([terms[t] for t in cols])
                if len(rows) <= len(cols) or np.linalg.matrix_rank(x) < len(cols):
                    continue
                scores[name] = _loo_rmse(x, y)
            # one condition alone: the constant, no cross-validation possible
            best = min(scores, key=scores.get) if scores else "constant"
            x = np.column_stack([terms[t] for t in DESIGNS[best]])
            beta, *_ = np.linalg.lstsq(x, y, rcond=None)  # (n_terms, n_grid)
            designs[(flap, c)] = best
            coef[(flap, c)] = beta.T
            cv[(flap, c)] = scores
            se = np.array([np.broadcast_to(r[3].get(c, 0.0), len(grid)) for r in rows], dtype=float)
            basis[(flap, c)] = _coef_basis(x, y - x @ beta, se)
            dof[(flap, c)] = float(len(rows) - x.shape[1]) if len(rows) > x.shape[1] else np.inf
    return GearSurface(grid, flaps, designs, coef, ar, mr, cv, basis, dof)


def _coef_basis(x: np.ndarray, resid: np.ndarray, se: np.ndarray) -> np.ndarray:
    """The perturbation basis of a least-squares fit of curves ``y (n, n_grid) ~ x (n, p)``:
    ``(m, n_grid, p)`` such that ``sum_j z_j basis[j]`` has the coefficients' covariance.

    With ``n > p``: ``(X'X)^-1 kron S``, ``S = resid' resid / (n - p)``, factored as
    ``L[:, a] F[r, :]`` (``L L' = (X'X)^-1`` from QR, ``F'F = S`` from its eigenvectors: at most
    ``n_grid`` rows, so the basis does not grow with the number of conditions). With ``n = p`` the
    curves' own errors ``se (n, n_grid)``, taken as fully correlated along each curve, through
    ``X^-1``.
    """
    n, p = x.shape
    if n > p:
        lo = np.linalg.inv(np.linalg.qr(x, mode="r"))  # L L' = R^-1 R^-T = (X'X)^-1
        w, v = np.linalg.eigh(resid.T @ resid / (n - p))
        keep = w > 1e-12 * max(float(w.max(initial=0.0)), 1e-300)
        f = (np.sqrt(w[keep]) * v[:, keep]).T  # F'F = S in at most n_grid rows, however many conditions
        return np.einsum("ia,rg->argi", lo, f).reshape(p * len(f), resid.shape[1], p)
    xinv = np.linalg.pinv(x)  # (p, n)
    return np.einsum("ik,kg->kgi", xinv, se)


def _loo_rmse(x: np.ndarray, y: np.ndarray) -> float:
    """Leave-one-out RMS prediction error of least squares (PRESS) [-]."""
    h = x @ np.linalg.pinv(x.T @ x) @ x.T
    beta, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ beta
    lev = np.clip(1.0 - np.diag(h), 1e-12, None)
    return float(np.sqrt(np.mean((resid / lev[:, None]) ** 2)))
