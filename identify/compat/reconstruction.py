"""The kinematic model the data compatibility fits: the logs at a common length, the attitude
and velocity integrated from the gyros and accelerometers, and the Gauss-Newton fit of both."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.interpolate import BSpline

from identify.compat.config import CompatSettings
from identify.compat.result import (
    D2R,
    EARTH_RADIUS_FT,
    EARTH_RATE,
    FT_PER_KT,
    G0_FPS2,
    GUST_KNOT_S,
    MAX_LOGS,
    NEEDS_TURN,
    RATE_HZ,
)
from identify.logs import CALIBRATION, Log

# ----------------------------------------------------------------------------- data


@dataclass
class _Data:
    """The reconstructed logs at a common length (padded, masked), SI-like units (ft, s, rad)."""

    t: np.ndarray  # (L, N)
    mask: np.ndarray  # (L, N) valid samples
    dt: np.ndarray  # (L,)
    ch: dict  # channel -> (L, N)
    present: set
    g: np.ndarray  # (L,)
    frame_rate: np.ndarray | None = None  # (L, n, 3) rotation of the local NED frame, in body axes [rad/s]
    earth_rate: np.ndarray | None = None  # (L, n, 3) the Earth's rotation alone, in body axes [rad/s]


def select(logs: list[Log]) -> list[Log]:
    """At most MAX_LOGS logs spread over the conditions: calibration manoeuvres (level turns)
    first, then 2-3-1-1s (they excite most)."""
    ranked = sorted(
        logs, key=lambda lg: (lg.maneuver not in CALIBRATION, lg.transition, lg.gear_down, lg.condition, lg.path)
    )
    out, seen = [], set()
    for lg in ranked:  # one per condition and manoeuvre first
        key = (lg.condition, lg.maneuver)
        if key not in seen and len(out) < MAX_LOGS:
            out.append(lg)
            seen.add(key)
    for lg in ranked:
        if len(out) >= MAX_LOGS:
            break
        if lg not in out:
            out.append(lg)
    return out


CHANNELS = {
    "p_dps": D2R,
    "q_dps": D2R,
    "r_dps": D2R,
    "ax_fps2": 1.0,
    "ay_fps2": 1.0,
    "az_fps2": 1.0,
    "theta_deg": D2R,
    "phi_deg": D2R,
    "psi_deg": D2R,
    "alpha_deg": D2R,
    "beta_deg": D2R,
    "tas_kt": FT_PER_KT,
    "alt_ft": 1.0,
    "vn_fps": 1.0,
    "ve_fps": 1.0,
    "vd_fps": 1.0,
}
#: An inertial/GPS unit's heading and velocity north-east-down: with them the accelerometer biases are pinned.
INS = ("psi_deg", "vn_fps", "ve_fps", "vd_fps")
#: Without these the flight path cannot be reconstructed at all.
ESSENTIAL = (
    "t_s",
    "p_dps",
    "q_dps",
    "r_dps",
    "ax_fps2",
    "ay_fps2",
    "az_fps2",
    "theta_deg",
    "phi_deg",
    "alpha_deg",
    "beta_deg",
    "tas_kt",
    "alt_ft",
)


def prepare(logs: list[Log]) -> _Data:
    frames = []
    for lg in logs:
        d = lg.data
        dt = float(np.median(np.diff(d["t_s"])))
        k = max(1, round(1.0 / (RATE_HZ * dt)))
        frames.append((d.iloc[::k], dt * k, float(lg.meta.get("gravity_fps2", G0_FPS2))))
    n = max(len(f) for f, *_ in frames)
    L = len(frames)
    t = np.zeros((L, n))
    mask = np.zeros((L, n), bool)
    ch = {c: np.zeros((L, n)) for c in CHANNELS}
    present = set.intersection(*[set(f.columns) for f, *_ in frames])
    for i, (f, _, _) in enumerate(frames):
        m = len(f)
        tt = f["t_s"].to_numpy(dtype=float) - float(f["t_s"].iloc[0])
        t[i, :m] = tt
        t[i, m:] = tt[-1] + (np.arange(n - m) + 1) * (tt[-1] - tt[-2])
        mask[i, :m] = True
        for c, k in CHANNELS.items():
            if c in f:
                x = f[c].to_numpy(dtype=float) * k
                ch[c][i, :m] = x
                ch[c][i, m:] = x[-1]
    data = _Data(t, mask, np.array([dt for _, dt, _ in frames]), ch, present, np.array([g for *_, g in frames]))
    lats = [lg.meta.get("latitude_deg") for lg in logs]
    if "psi_deg" in present and all(isinstance(x, (int, float)) for x in lats):
        data.frame_rate, data.earth_rate = _frame_rates(data, np.radians(np.asarray(lats, float)))
    return data


def _frame_rates(data: _Data, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation of the local north-east-down frame (the Earth's rate plus the transport rate of
    flight over a round Earth) and the Earth's rate alone, in body axes at the measured attitude
    [rad/s]. A gyro measures inertial rates; the Euler angles are relative to that frame."""
    th, ph, ps = (data.ch[c] for c in ("theta_deg", "phi_deg", "psi_deg"))
    if all(c in data.present for c in ("vn_fps", "ve_fps")):
        vn, ve = data.ch["vn_fps"], data.ch["ve_fps"]
    else:  # the air speed along the heading: a wind of 30 kt moves the transport rate by 2e-6 rad/s
        vn, ve = data.ch["tas_kt"] * FT_PER_KT * np.cos(ps), data.ch["tas_kt"] * FT_PER_KT * np.sin(ps)
    r = EARTH_RADIUS_FT + data.ch["alt_ft"]
    lat = lat[:, None] * np.ones_like(th)
    earth = EARTH_RATE * np.stack([np.cos(lat), np.zeros_like(lat), -np.sin(lat)], -1)
    transport = np.stack([ve / r, -vn / r, -ve * np.tan(lat) / r], -1)
    n2b = np.swapaxes(body_to_ned(th, ph, ps), -1, -2)
    return (
        np.einsum("lnij,lnj->lni", n2b, earth + transport, optimize=True),
        np.einsum("lnij,lnj->lni", n2b, earth, optimize=True),
    )


def delayed(x: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """x(t - tau) per row (held at the ends)."""
    if tau == 0.0:
        return x
    return np.stack([np.interp(t[i] - tau, t[i], x[i]) for i in range(len(x))])


def shift_columns(x: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """:func:`delayed` of every column of ``x`` (L, n, P) at once: the interpolation
    weights are the same for all of a log's columns."""
    if tau == 0.0:
        return x
    out = np.empty_like(x)
    for i in range(len(x)):
        ti = t[i]
        tq = ti - tau
        j = np.clip(np.searchsorted(ti, tq, side="right") - 1, 0, len(ti) - 2)
        w = np.clip((tq - ti[j]) / (ti[j + 1] - ti[j]), 0.0, 1.0)[:, None]
        out[i] = x[i, j] + w * (x[i, j + 1] - x[i, j])
    return out


# ------------------------------------------------------------------------ attitude


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternion arrays (..., 4)."""
    a0, a1, a2, a3 = np.moveaxis(a, -1, 0)
    b0, b1, b2, b3 = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
            a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
            a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
            a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
        ],
        -1,
    )


def integrated_attitude(
    data: _Data,
    bp: float,
    bq: float,
    br: float,
    th0: np.ndarray,
    ph0: np.ndarray,
    ps0: np.ndarray,
    steps: np.ndarray | None = None,
):
    """Euler angles integrated from the gyros [rad], less the local frame's own rotation when
    the logs give the latitude and the heading. ``steps`` are :func:`body_rotations` of these
    biases if already known.
    """
    steps = body_rotations(data, bp, bq, br) if steps is None else steps
    (cy, ct, cf), (sy, st, sf) = np.cos(0.5 * np.stack([ps0, th0, ph0])), np.sin(0.5 * np.stack([ps0, th0, ph0]))
    q0 = np.stack(
        [
            cf * ct * cy + sf * st * sy,
            sf * ct * cy - cf * st * sy,
            cf * st * cy + sf * ct * sy,
            cf * ct * sy - sf * st * cy,
        ],
        -1,
    )[:, None]
    a, b, c, e = np.moveaxis(np.concatenate([q0, _qmul(np.broadcast_to(q0, steps.shape), steps)], 1), -1, 0)
    th = np.arcsin(np.clip(2.0 * (a * c - e * b), -1.0, 1.0))
    ph = np.arctan2(2.0 * (a * b + c * e), 1.0 - 2.0 * (b * b + c * c))
    ps = np.unwrap(np.arctan2(2.0 * (a * e + b * c), 1.0 - 2.0 * (c * c + e * e)), axis=1)
    ps += np.round((ps0 - ps[:, 0]) / (2.0 * np.pi))[:, None] * 2.0 * np.pi
    return th, ph, ps


def body_rotations(data: _Data, bp: float, bq: float, br: float) -> np.ndarray:
    """The body's rotation from the first sample to each later one, as quaternions (L, n-1, 4).

    Each step's rotation is the fourth-order Magnus one of rates linear between
    samples (``h w_mean + h^2/12 w_k x w_k+1``); the steps compose by a parallel
    prefix product of quaternions (log2 n vectorised passes instead of n).
    """
    w = np.stack([data.ch["p_dps"] - bp, data.ch["q_dps"] - bq, data.ch["r_dps"] - br], -1)
    if data.frame_rate is not None:
        w = w - data.frame_rate
    h = data.dt[:, None, None]
    wa, wb = w[:, :-1], w[:, 1:]
    rot = 0.5 * (wa + wb) * h + (h**2 / 12.0) * np.cross(wa, wb)
    ang = np.linalg.norm(rot, axis=-1, keepdims=True)
    steps = np.concatenate([np.cos(0.5 * ang), np.sin(0.5 * ang) * rot / np.maximum(ang, 1e-300)], -1)
    d = 1
    while d < steps.shape[1]:  # Hillis-Steele scan: steps[k] becomes steps[0] ... steps[k]
        steps = np.concatenate([steps[:, :d], _qmul(steps[:, :-d], steps[:, d:])], 1)
        d *= 2
    return steps


def body_to_ned(th: np.ndarray, ph: np.ndarray, ps: np.ndarray) -> np.ndarray:
    """Rotation matrices body -> north-east-down (L, n, 3, 3)."""
    ct, st, cp, sp, cs, ss = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph), np.cos(ps), np.sin(ps)
    return np.stack(
        [
            np.stack([ct * cs, sp * st * cs - cp * ss, cp * st * cs + sp * ss], -1),
            np.stack([ct * ss, sp * st * ss + cp * cs, cp * st * ss - sp * cs], -1),
            np.stack([-st, sp * ct, cp * ct], -1),
        ],
        -2,
    )


# ------------------------------------------------------------------------ velocity


def _skew_exp(w: np.ndarray, h: np.ndarray) -> np.ndarray:
    """exp(-[w]x h) for vectors w (..., 3), each over its step h (broadcast against w's leading axes): the
    body axes' rotation over a step (..., 3, 3)."""
    norm = np.linalg.norm(w, axis=-1)
    ang = norm * h
    axis = w / np.maximum(norm, 1e-12)[..., None]
    K = np.zeros((*w.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = axis[..., 2], -axis[..., 1], axis[..., 0]
    s, c = np.sin(-ang)[..., None, None], (1 - np.cos(-ang))[..., None, None]
    return np.eye(3) + s * K + c * (K @ K)


def velocity_responses(data: _Data, rates: tuple[np.ndarray, ...], th: np.ndarray, ph: np.ndarray):
    """Body velocity responses of ``V' = -w x V + f``: to the initial velocity (Phi), to the
    measured forcing, to unit accelerometer biases and to attitude biases; and of altitude.

    Returns
    -------
    Phi : (L, n, 3, 3); X : (L, n, 3, 6) columns [forcing, -ex, -ey, -ez, -dg/dtheta, -dg/dphi];
    HPhi : (L, n, 3); HX : (L, n, 6)  (altitude, h - h0)
    """
    p, q, r = rates
    L, n = p.shape
    if data.earth_rate is not None:  # V' = f + g - (w_ib + w_ie) x V for the velocity over the Earth
        p, q, r = (x + data.earth_rate[..., k] for k, x in enumerate(rates))
        g = data.g[:, None] * np.ones_like(p)
    else:
        # the gyro biases took the frame's rotation: level flight over the round Earth is a turn,
        # it takes V^2 / R of the weight (0.012 ft/s^2 at 500 ft/s)
        g = data.g[:, None] - data.ch["tas_kt"] ** 2 / (EARTH_RADIUS_FT + data.ch["alt_ft"])
    gb = np.stack([-g * np.sin(th), g * np.cos(th) * np.sin(ph), g * np.cos(th) * np.cos(ph)], -1)
    dth = np.stack([-g * np.cos(th), -g * np.sin(th) * np.sin(ph), -g * np.sin(th) * np.cos(ph)], -1)
    dph = np.stack([np.zeros_like(th), g * np.cos(th) * np.cos(ph), -g * np.cos(th) * np.sin(ph)], -1)
    acc = np.stack([data.ch["ax_fps2"], data.ch["ay_fps2"], data.ch["az_fps2"]], -1)
    forcing = np.stack([acc + gb, *[-np.broadcast_to(e, acc.shape) for e in np.eye(3)], -dth, -dph], -1)
    c = np.stack([np.sin(th), -np.sin(ph) * np.cos(th), -np.cos(ph) * np.cos(th)], -1)
    Phi = np.empty((L, n, 3, 3))
    X = np.empty((L, n, 3, 6))
    Phi[:, 0], X[:, 0] = np.eye(3), 0.0
    h = data.dt[:, None, None]
    w = np.stack([p, q, r], -1)
    steps = _skew_exp(0.5 * (w[:, :-1] + w[:, 1:]), data.dt[:, None])  # every step's rotation at once
    for k in range(n - 1):
        R = steps[:, k]
        Phi[:, k + 1] = R @ Phi[:, k]
        X[:, k + 1] = R @ (X[:, k] + 0.5 * h * forcing[:, k]) + 0.5 * h * forcing[:, k + 1]
    rate_phi = np.einsum("lni,lnij->lnj", c, Phi, optimize=True)
    rate_x = np.einsum("lni,lnij->lnj", c, X, optimize=True)
    dt = data.dt[:, None, None]
    HPhi = np.concatenate([np.zeros((L, 1, 3)), np.cumsum(0.5 * dt * (rate_phi[:, 1:] + rate_phi[:, :-1]), 1)], 1)
    HX = np.concatenate([np.zeros((L, 1, 6)), np.cumsum(0.5 * dt * (rate_x[:, 1:] + rate_x[:, :-1]), 1)], 1)
    return Phi, X, HPhi, HX


# ------------------------------------------------------------------------ estimation


def gust_basis(data: _Data) -> np.ndarray:
    """Zero-mean cubic B-splines, knots about :data:`GUST_KNOT_S` apart over each log (L, n, K):
    the slow wander of the air mass (turbulence) the air data see and the kinematics do not. A
    log shorter than the longest leaves its last columns zero."""
    L, n = data.t.shape
    ends = [float(data.t[i][data.mask[i]][-1]) for i in range(L)]
    inner = [max(int(np.ceil(end / GUST_KNOT_S)), 1) for end in ends]
    out = np.zeros((L, n, max(inner) + 3))
    for i, (end, k) in enumerate(zip(ends, inner)):
        knots = np.concatenate([[0.0] * 3, np.linspace(0.0, end, k + 1), [end] * 3])
        b = BSpline.design_matrix(np.clip(data.t[i], 0.0, end), knots, 3).toarray()
        b -= b[data.mask[i]].mean(axis=0)
        out[i, :, : k + 3] = b * data.mask[i][:, None]
    return out


def noise_level(x: np.ndarray, mask: np.ndarray, floor: float) -> float:
    d2 = np.diff(x, 2, axis=1)[mask[:, 2:]]
    s = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0) if d2.size else 0.0
    return max(s, floor)


class _Blocks:
    """Normal equations of [shared | per-log] parameters, solved log by log (Schur complement).

    ``Js`` (rows x shared) is dense; ``Jp`` (rows x per) holds each row's derivatives
    by its own log's parameters only.
    """

    def __init__(
        self,
        Js: np.ndarray,
        Jp: np.ndarray,
        e: np.ndarray,
        rows: list[np.ndarray],
        blocks: np.ndarray | None = None,
        steady: np.ndarray | None = None,
    ) -> None:
        self.rows = rows
        self.scores = None  # per log: each time block's (shared, per-log) gradient, with ``blocks``
        # per log: the shared and per-log normal-equation columns of the steady gusts, with ``steady``
        self.steady = None if steady is None else [(Js[r].T @ steady[r], Jp[r].T @ steady[r]) for r in rows]
        if blocks is not None:
            self.scores = []
            for r in rows:
                labels = blocks[r]
                self.scores.append(
                    [
                        (Js[r[labels == b]].T @ e[r[labels == b]], Jp[r[labels == b]].T @ e[r[labels == b]])
                        for b in np.unique(labels)
                    ]
                )
        ns, per = Js.shape[1], Jp.shape[1]
        self.Hll, self.Hsl, self.gl, self.Bb, self.gb = [], [], [], [], []  # each log's products only
        for r in rows:
            hll, hsl, gl, bb, gb = (
                np.zeros((per, per)),
                np.zeros((ns, per)),
                np.zeros(per),
                np.zeros((ns, ns)),
                np.zeros(ns),
            )
            cuts = np.flatnonzero(np.diff(r) != 1) + 1
            for lo, hi in zip(r[np.r_[0, cuts]], r[np.r_[cuts - 1, len(r) - 1]] + 1):  # its runs of rows: views
                a, b, ee = Jp[lo:hi], Js[lo:hi], e[lo:hi]
                cols = np.flatnonzero(np.any(a, axis=0))  # an output may not depend on all of them
                if len(cols) < per:
                    a = a[:, cols]
                    hll[np.ix_(cols, cols)] += a.T @ a
                    hsl[:, cols] += b.T @ a
                    gl[cols] += a.T @ ee
                else:
                    hll += a.T @ a
                    hsl += b.T @ a
                    gl += a.T @ ee
                bb += b.T @ b
                gb += b.T @ ee
            for acc, x in zip((self.Hll, self.Hsl, self.gl, self.Bb, self.gb), (hll, hsl, gl, bb, gb)):
                acc.append(x)
        self.Hss = sum(self.Bb, np.zeros((ns, ns)))  # every row is one log's
        self.gs = sum(self.gb, np.zeros(ns))

    def step(self, lam: float) -> tuple[np.ndarray, list[np.ndarray]]:
        """Damped Gauss-Newton step: shared part and each log's part."""

        def damp(h):
            d = np.diag(h).copy()
            d[d <= 0] = 1.0
            return h + lam * np.diag(d)

        hll_inv = [np.linalg.pinv(damp(h)) for h in self.Hll]
        S = damp(self.Hss) - sum(h @ hi @ h.T for h, hi in zip(self.Hsl, hll_inv)) if len(self.gs) else None
        rhs = self.gs - sum(h @ hi @ g for h, hi, g in zip(self.Hsl, hll_inv, self.gl))
        ds = -np.linalg.solve(S, rhs) if S is not None and len(S) else np.zeros(0)
        dl = [-hi @ (g + h.T @ ds) for h, hi, g in zip(self.Hsl, hll_inv, self.gl)]
        return ds, dl

    @cached_property
    def _reduced(self) -> tuple[list[np.ndarray], np.ndarray]:
        """Each log's own normal matrix inverted, and the shared parameters' normal matrix with
        every log's own parameters eliminated (the covariances' common part)."""
        hll_inv = [np.linalg.pinv(h) for h in self.Hll]
        return hll_inv, self.Hss - sum(h @ hi @ h.T for h, hi in zip(self.Hsl, hll_inv))

    def block_cov(self) -> np.ndarray:
        """Covariance of the shared parameters robust to correlation within a time block (the
        sandwich with blocks as clusters, each log's own parameters eliminated). Unlike the
        delete-one-log jackknife it holds when one log alone pins a parameter down (a turn)."""
        if not len(self.gs):
            return np.zeros((0, 0))
        hll_inv, S = self._reduced
        S_inv = np.linalg.pinv(S)
        g = np.array([b - h @ hi @ a for h, hi, blocks in zip(self.Hsl, hll_inv, self.scores) for b, a in blocks])
        B = len(g)
        return S_inv @ (g.T @ g) @ S_inv * (B / max(B - 1, 1))

    def offset_cov(self, sd: np.ndarray) -> np.ndarray:
        """Covariance the shared parameters take from a steady gust along each body axis in each
        log, of standard deviation ``sd`` per log [ft/s], which the fit holds at zero: each gust's
        effect on the estimate through the normal equations, each log's own parameters refitted."""
        if not len(self.gs) or self.steady is None:
            return np.zeros((len(self.gs), len(self.gs)))
        hll_inv, S = self._reduced
        S_inv = np.linalg.pinv(S)
        moves = [S_inv @ (js - h @ hi @ jp) * s for (js, jp), h, hi, s in zip(self.steady, self.Hsl, hll_inv, sd)]
        return sum(m @ m.T for m in moves)

    def cluster_cov(self) -> np.ndarray:
        """Covariance of the shared parameters robust to any correlation within a log (logs as
        clusters; turbulence makes the air data wander for seconds against the kinematics, longer
        than a 28-second record shows): the delete-one-log jackknife, one Gauss-Newton step per
        log, ``(L-1)/L sum_l (d_l - mean)(d_l - mean)'``. Unlike the plain cluster sandwich it sees
        a log's leverage: a scale factor that only a few conditions' trim alphas pin down is as
        uncertain as those few logs make it."""
        if not len(self.gs):
            return np.zeros((0, 0))
        hll_inv, S = self._reduced
        own = [bb - h @ hi @ h.T for bb, h, hi in zip(self.Bb, self.Hsl, hll_inv)]
        L = len(self.rows)
        d = np.array(
            [
                np.linalg.pinv(S - s_l) @ (gb - h @ hi @ g)
                for gb, g, h, hi, s_l in zip(self.gb, self.gl, self.Hsl, hll_inv, own)
            ]
        )
        d -= d.mean(axis=0)
        return d.T @ d * ((L - 1) / L)


def heading_change(data: _Data) -> np.ndarray:
    """Heading change of each log [deg] (0 without a heading channel)."""
    if "psi_deg" not in data.present:
        return np.zeros(len(data.mask))
    psi = np.unwrap(data.ch["psi_deg"], axis=1)
    return np.array([float(np.ptp(psi[i][m])) / D2R if m.any() else 0.0 for i, m in enumerate(data.mask)])


def unexcited_parameters(
    data: _Data, recon: dict[str, np.ndarray], settings: CompatSettings | None = None
) -> dict[str, str]:
    """Parameters the logs cannot identify, with the reason. Scale factors and time shifts
    need the reconstructed signal to move (turbulence moves the measured one too): by the spans of
    ``settings`` (None: the defaults)."""
    s = settings or CompatSettings()
    out = {}
    m = data.mask
    lateral, span_of = s.lateral_span_deg, s.scale_span
    for c, need, unit, k in (
        ("theta_deg", span_of["theta_deg"], "deg", D2R),
        ("phi_deg", lateral["phi_deg"], "deg", D2R),
        ("alpha_deg", span_of["alpha_deg"], "deg", D2R),
        ("beta_deg", lateral["beta_deg"], "deg", D2R),
        ("tas_kt", span_of["tas_kt"], "kt", FT_PER_KT),
    ):
        if c not in data.present:
            for e in ("bias", "scale", "delay"):
                out[f"{c}.{e}"] = "channel not in the logs"
            continue
        x = recon.get(c, data.ch[c])
        span = float(np.ptp(x[m])) / k
        if span < need:
            out[f"{c}.scale"] = f"{c} spans {span:.2g} {unit} in the manoeuvres, needs {need:g}"
        rate = (np.diff(x, axis=1) / data.dt[:, None])[m[:, 1:]] / k
        if float(np.std(rate)) < need / 4.0:
            out[f"{c}.delay"] = f"{c} hardly moves within the manoeuvres (rate std {np.std(rate):.2g} {unit}/s)"
    if "q_dps" not in data.present or float(np.std(data.ch["q_dps"][m])) < s.pitch_rate_std_dps * D2R:
        out["alpha_deg.position"] = "pitch rate hardly excited"
    # what longitudinal manoeuvres without a ground-speed reference cannot separate, whatever the data
    beta_span = float(np.ptp(recon.get("beta_deg", data.ch["beta_deg"])[m])) / D2R
    phi_span = float(np.ptp(recon.get("phi_deg", data.ch["phi_deg"])[m])) / D2R
    theta_span = float(np.ptp(recon.get("theta_deg", data.ch["theta_deg"])[m])) / D2R
    if beta_span < lateral["beta_deg"]:
        out.setdefault("beta_deg.bias", "a sideslip offset is a lateral velocity offset without a lateral manoeuvre")
    if phi_span < lateral["phi_deg"]:
        out.setdefault(
            "phi_deg.bias", "confounded with the lateral accelerometer's bias through gravity without a bank"
        )
    if theta_span < s.theta_bias_span_deg:
        out.setdefault(
            "theta_deg.bias",
            f"confounded with the longitudinal accelerometer's bias through gravity "
            f"(pitch spans {theta_span:.0f} deg, needs {s.theta_bias_span_deg:g})",
        )
    ins = all(c in data.present for c in INS)
    turned = float(heading_change(data).max(initial=0.0)) if ins else 0.0
    for e in ("bias", "scale", "delay"):
        if e != "delay" and turned >= s.turn_span_deg:
            continue  # a steady wind in the earth's axes, seen from several headings, is not an airspeed error
        out.setdefault(
            f"tas_kt.{e}",
            (f"{NEEDS_TURN} (no turn in the manoeuvres: the heading spans {turned:.0f} deg, needs {s.turn_span_deg:g})")
            if ins
            else "no inertial speed reference in the logs (ground speed): each log's own initial speed absorbs it",
        )
    for c in ("p_dps", "r_dps", "ay_fps2"):
        if c not in data.present:
            out[f"{c}.bias"] = "channel not in the logs"
    if "phi_deg" not in data.present:
        out["p_dps.bias"] = "roll angle not in the logs"
    return out


#: :func:`gauss_newton` has converged when an undamped step (its damping at most :data:`UNDAMPED`
#: of the normal matrix's diagonal) makes the cost smaller by at most this share of it. Each residual
#: is in its channel's noise, so the cost is about the number of rows (1e4-1e5) and this is a chi-square
#: of 0.01-0.1: the next step would move no estimate by as much as a thousandth of its standard
#: error (an alpha bias of 0.42454 deg, +- 0.033, moved by 3e-6 deg against 1e-10, with a sixth fewer
#: Jacobians) ...
CONVERGED = 1e-6
#: ... the damping [-] below which a step is undamped (a step a large damping shortened is no sign
#: of convergence).
UNDAMPED = 1e-3
#: :func:`gauss_newton`'s blocks at the point its last step converged to hold the Jacobian of the point
#: before it: a step that gains a millionth of the cost moves it by less than the covariance can tell (the
#: standard errors by at most 2e-5 of themselves in the compatibility tests, in still air and in turbulence
#: up to 3 ft/s; the estimates are the same), and that Jacobian is a fifth of an estimate's residual
#: evaluations.
REUSE_LAST_JACOBIAN = True


def gauss_newton(
    residual,
    x: np.ndarray,
    free: np.ndarray,
    ns: int,
    L: int,
    per: int,
    rows: list[np.ndarray],
    perlog=None,
    max_iter: int = 40,
    robust: tuple | None = None,
    column=None,
):
    """Damped Gauss-Newton: x = [shared (ns), per log (L x per)]; ``free`` masks the shared ones
    (each log's own parameters are always free).

    The shared columns of the Jacobian are forward differences; the per-log ones
    too (one evaluation per slot: each log's rows depend on its own only), unless
    ``perlog(x)`` gives them: an array (residual rows, per). ``robust``: (each row's time block,
    a callable giving the steady gusts' residual columns at the last ``perlog``, their standard
    deviations per log) for :meth:`_Blocks.block_cov` and :meth:`_Blocks.offset_cov`. ``column(x, i)``,
    if given, computes a shared column's difference on the rows it moves alone: (those rows as a
    slice, the residual there at ``x``), or None for all of them (the rest of the column is 0, as the
    whole residual's difference gives it).

    Returns
    -------
    x, _Blocks of the residual at x, residual at x
        Where the last step converged (:data:`CONVERGED`), the blocks hold the Jacobian of the point before
        it (:data:`REUSE_LAST_JACOBIAN`).
    """
    idx = np.flatnonzero(free[:ns])
    steps = 1e-6 * np.maximum(np.abs(x), 1.0)
    n_rows = sum(len(r) for r in rows)
    row_log = np.empty(n_rows, int)
    for i, r in enumerate(rows):
        row_log[r] = i

    last = {}  # the last Jacobian computed

    def blocks(x0, e0, reuse: bool = False):
        if reuse:  # the last Jacobian, and the steady gusts' columns of the same point
            Js, Jp, steady = last["J"]
            return _Blocks(Js, Jp, e0, rows, *((robust[0], steady) if robust is not None else ()))
        Js = np.empty((len(e0), len(idx)))
        for j, i in enumerate(idx):
            xp = x0.copy()
            xp[i] += steps[i]
            part = None if column is None else column(xp, i)
            if part is None:
                Js[:, j] = (residual(xp) - e0) / steps[i]
            else:
                Js[:, j] = 0.0
                Js[part[0], j] = (part[1] - e0[part[0]]) / steps[i]
        if perlog is not None:
            Jp = perlog(x0)
        else:
            Jp = np.empty((len(e0), per))
            for slot in range(per):
                cols = ns + np.arange(L) * per + slot
                xp = x0.copy()
                xp[cols] += steps[cols]
                Jp[:, slot] = (residual(xp) - e0) / steps[cols][row_log]
        steady = robust[1]() if robust is not None else None
        last["J"] = Js, Jp, steady
        return _Blocks(Js, Jp, e0, rows, *((robust[0], steady) if robust is not None else ()))

    e = residual(x)
    cost = float(e @ e)
    lam = 1e-6
    blk = blocks(x, e)
    for _ in range(max_iter):
        while True:
            ds, dl = blk.step(lam)
            xn = x.copy()
            xn[idx] += ds
            xn[ns:] += np.concatenate(dl)
            en = residual(xn)
            cn = float(en @ en)
            if cn <= cost or lam > 1e12:
                break
            lam *= 10.0
        if cn > cost:
            break
        done = cost - cn <= CONVERGED * max(cost, 1e-300) and lam <= UNDAMPED
        x, e, cost, lam = xn, en, cn, max(lam / 10.0, 1e-9)
        blk = blocks(x, e, reuse=done and REUSE_LAST_JACOBIAN)
        if done:
            break
    return x, blk, e
