"""Data compatibility: flight-path reconstruction before eq. (1).

Real data is wrong in its instruments before it is wrong in its model. As
SIDPAC's ``compat`` and Jategaonkar (Flight Vehicle System Identification,
2nd ed., ch. 10) do, the kinematic equations are integrated from the measured
rates and accelerations, and the air-data and attitude channels are compared
with what they should read. The instrument errors are estimated by output
error, pooled over the logs (the same instruments flew them all), each log
with its own initial state:

1. attitude: theta and phi integrated from the gyros give the gyro biases and
   the scale factors and time shifts of the attitude channels;
2. velocity: the body velocity integrated from the accelerometers (a linear
   system once the rates and attitude are known, solved by superposition) gives
   the accelerometer biases, the attitude biases (through gravity), and the bias,
   scale factor and time shift of alpha, beta and airspeed. Sensor positions the
   logs document are taken out first; without one, the distance of the air-data
   head ahead of the CG is estimated too (a boom's vane sees alpha - q x / V).

Standard errors are a delete-one-log jackknife, the logs as clusters: turbulence
is in the air data and not in the kinematics, and it wanders for seconds. A
parameter the logs do not excite is reported as not identifiable; two the data
cannot tell apart are each estimated with the other held at 0. Corrections larger than a channel's
resolution are applied at 5 standard errors; from 3, or when the kinematics
cannot tell two errors apart (an accelerometer bias and an attitude bias), only
if other evidence chooses them: the diagnosis asks the aerodynamic residuals.
The compatibility never reads an instrument profile; it sees the logs only.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.interpolate import BSpline

from identify.logs import Log

D2R = np.pi / 180.0
FT_PER_KT = 1.6878098571011957
G0_FPS2 = 32.174049
EARTH_RADIUS_FT = 20_925_646.0
#: The Earth's rotation rate [rad/s] (WGS84, as JSBSim's planet).
EARTH_RATE = 7.292115e-5
#: At most this many logs are reconstructed (the instruments are shared); spread over the conditions.
MAX_LOGS = 12
#: Reconstruction rate [Hz]: faster logs are thinned (the kinematics need no more).
RATE_HZ = 50.0
#: Smallest correction worth applying, per unit: below these, what the data hold is the
#: kinematic model's own mismatch (on perfect JSBSim data: the Earth's rotation, 0.004 deg/s in
#: the roll gyro; JSBSim's half-frame timing, 4 ms; 0.2 % in airspeed), not an instrument error.
MATTERS = {"deg": 0.005, "kt": 0.5, "ft/s^2": 0.01, "deg/s": 0.005, "-": 0.005, "s": 0.01, "ft": 2.0}
#: Corrections this many standard errors from 0 are applied on the kinematics' word alone ...
APPLY_Z = 5.0
#: ... from this many on, only if other evidence agrees (:meth:`CompatResult.choose`). Few logs make a
#: clustered standard error itself uncertain: in turbulence it came out 4x too small in 1 null of 6.
CANDIDATE_Z = 3.0
#: Above this variance inflation a parameter is confounded with others (its error is 10x a lone one's).
MAX_VIF = 100.0
#: Of a confounded pair these go first: an attitude bias does not enter eq. (1), the accelerometer
#: bias it trades with does, and the aerodynamic residuals can then choose between them.
PRUNE_FIRST = ("theta_deg.bias", "phi_deg.bias")
#: Larger estimates are not instrument errors but a reconstruction gone wrong (not applied).
PLAUSIBLE = {"deg": 5.0, "kt": 20.0, "ft/s^2": 1.0, "deg/s": 1.0, "-": 0.3, "s": 0.5, "ft": 200.0}
#: Span a lateral channel's reconstruction needs before its scale factor and time shift can be
#: told from turbulence [deg] (light turbulence alone moves them about 2 deg): a lateral manoeuvre.
LATERAL_SPAN = {"beta_deg": 4.0, "phi_deg": 10.0}
#: Span of pitch attitude a pitch-angle bias needs to be told from an accelerometer bias [deg].
THETA_BIAS_SPAN = 15.0
#: Above this RMS vertical gust in the reconstruction [ft/s] the air-data time shifts are not identifiable:
#: the aircraft's answer to the gusts biases them (null flights at 1.5 ft/s: +15 to +45 ms on alpha).
TURBULENT_FPS = 0.5
#: Knot spacing of each log's gust [s]: Dryden turbulence has most of its power below V / (2 pi L),
#: about 0.04 Hz at 1750 ft scale length; a 2-3-1-1 excites 0.15-1 Hz.
GUST_KNOT_S = 3.0


@dataclass
class Parameter:
    """One instrument error: estimate and standard error, in the channel's units (scale: -; delay: s)."""

    channel: str
    error: str  # bias | scale | delay | position
    unit: str
    estimate: float = 0.0
    se: float = float("nan")
    identifiable: bool = True
    reason: str = ""
    sources: dict = field(default_factory=dict)  # method -> (estimate, se) when several methods combine
    confounded_with: str = ""  # the parameter the kinematics cannot tell it from (held at 0)
    chosen: str = ""  # why it is applied although confounded (the aerodynamic residuals chose it)
    beside_aero: bool = False  # the residuals agreed only beside the aerodynamic terms fitted to them

    @property
    def name(self) -> str:
        return f"{self.channel}.{self.error}"

    @property
    def z(self) -> float:
        return abs(self.estimate) / self.se if self.se > 0 else float("inf") if self.estimate else 0.0

    @property
    def correctable(self) -> bool:
        """At least :data:`CANDIDATE_Z` standard errors (or measured by the kinematics and refined by the
        aerodynamic residuals), larger than the channel's resolution, plausible."""
        return bool(self.identifiable and (self.z >= CANDIDATE_Z or {"kinematics", "residuals"} <= set(self.sources))
                    and MATTERS[self.unit] <= abs(self.estimate) <= PLAUSIBLE[self.unit])

    @property
    def applied(self) -> bool:
        """The data are corrected for it: correctable, at least :data:`APPLY_Z` standard errors and
        not confounded, or chosen by other evidence (the aerodynamic residuals)."""
        return self.correctable and (bool(self.chosen) or (not self.reason and self.z >= APPLY_Z))

    def to_dict(self) -> dict:
        ok = bool(self.identifiable)
        return {"channel": self.channel, "error": self.error, "unit": self.unit,
                "estimate": float(self.estimate) if ok else None,
                "se": float(self.se) if ok else None, "z": float(self.z) if ok else None,
                "identifiable": ok, "reason": self.reason, "applied": bool(self.applied),
                "confounded_with": self.confounded_with or None, "chosen_because": self.chosen or None,
                "methods": {k: {"estimate": float(e), "se": float(se)} for k, (e, se) in self.sources.items()}}


def _parameters() -> list[Parameter]:
    p = [Parameter(c, "bias", "deg/s") for c in ("p_dps", "q_dps", "r_dps")]
    p += [Parameter(c, e, u) for c in ("theta_deg", "phi_deg") for e, u in (("scale", "-"), ("delay", "s"))]
    p += [Parameter(c, "bias", "ft/s^2") for c in ("ax_fps2", "ay_fps2", "az_fps2")]
    p += [Parameter(c, "bias", "deg") for c in ("theta_deg", "phi_deg")]
    for c, unit in (("alpha_deg", "deg"), ("beta_deg", "deg"), ("tas_kt", "kt")):
        p += [Parameter(c, "bias", unit), Parameter(c, "scale", "-"), Parameter(c, "delay", "s")]
    p.append(Parameter("alpha_deg", "position", "ft"))  # the air-data head's distance ahead of the CG
    return p


@dataclass
class CompatResult:
    """What the data compatibility found.

    Attributes
    ----------
    parameters : list of Parameter
    logs : list of str
        The logs reconstructed.
    residual_rms : dict
        Output channel -> RMS of (measured - reconstructed) without and with the
        estimated errors, ``{"before": ..., "after": ...}``.
    positions : dict
        Sensor positions the logs document (channel -> [x, y, z] from the CG, body
        axes [ft]); the data are corrected for them, they are not estimated.
    """

    parameters: list[Parameter]
    logs: list[str] = field(default_factory=list)
    residual_rms: dict = field(default_factory=dict)
    positions: dict = field(default_factory=dict)
    covariance: list = field(default_factory=list)  # [(parameter names, covariance matrix)] per stage
    turbulence_fps: float = float("nan")  # RMS vertical gust the reconstruction needed [ft/s]

    def uncertainty(self) -> tuple[list[tuple[str, str]], np.ndarray]:
        """The identifiable biases, scale factors and time shifts, (channel, error), and the
        covariance of their estimates: how wrong the corrected data may still be."""
        names, blocks = [], []
        ok = {p.name for p in self.parameters if p.identifiable and "residuals" not in p.sources}
        for ns, cov in self.covariance:
            keep = [j for j, n in enumerate(ns) if n.split(".")[1] in ("bias", "scale", "delay") and n in ok]
            names += [tuple(ns[j].split(".")) for j in keep]
            blocks.append(cov[np.ix_(keep, keep)])
        total = np.zeros((len(names), len(names)))
        i = 0
        for b in blocks:
            total[i:i + len(b), i:i + len(b)] = b
            i += len(b)
        return names, total

    def choose(self, name: str, why: str, beside_aero: bool = False) -> "CompatResult":
        """The same result with a confounded parameter applied (its partner held at 0), and why."""
        return replace(self, parameters=[replace(p, chosen=why, beside_aero=beside_aero) if p.name == name else p
                                         for p in self.parameters])

    def note(self, name: str, text: str) -> "CompatResult":
        """The same result with a note added to one parameter's reason."""
        return replace(self, parameters=[replace(p, reason=f"{p.reason}; {text}") if p.name == name else p
                                         for p in self.parameters])

    @property
    def undecided(self) -> list[Parameter]:
        """Correctable parameters held back: confounded with a partner the kinematics cannot tell
        them from, or short of :data:`APPLY_Z` standard errors. Other evidence may choose them."""
        return [p for p in self.parameters if p.correctable and not p.applied
                and (p.confounded_with or not p.reason)]

    def without(self, name: str) -> "CompatResult":
        """The same result with one parameter's correction not applied."""
        params = [replace(p, identifiable=False, reason="undone") if p.name == name else p
                  for p in self.parameters]
        return replace(self, parameters=params)

    @property
    def unmeasured(self) -> list[tuple[str, str]]:
        """Air-data errors the manoeuvres could have shown but the conditions hid (turbulence)."""
        return [(p.channel, p.error) for p in self.parameters
                if not p.identifiable and p.reason.startswith("turbulence") and p.channel == "alpha_deg"]

    def get(self, name: str) -> Parameter:
        return next(p for p in self.parameters if p.name == name)

    def value(self, name: str) -> float:
        """The estimate if it is applied, else 0."""
        p = self.get(name)
        return p.estimate if p.applied else 0.0

    @property
    def applied(self) -> list[Parameter]:
        return [p for p in self.parameters if p.applied]

    def correction_key(self) -> tuple:
        """What :meth:`correct` does, as a hashable value: results with equal keys correct every log alike."""
        return tuple((p.name, float(p.estimate)) for p in self.applied), repr(sorted(self.positions.items()))

    def to_dict(self) -> dict:
        return {"parameters": [p.to_dict() for p in self.parameters], "logs": [Path(p).name for p in self.logs],
                "residual_rms": self.residual_rms, "documented_positions_ft": self.positions,
                "vertical_gust_rms_fps": self.turbulence_fps}

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([p.to_dict() for p in self.parameters])

    def summary(self) -> str:
        lines = [f"Data compatibility (flight-path reconstruction of {len(self.logs)} logs):"]
        for c, r in self.positions.items():
            lines.append(f"  {c} sensor documented at {r} ft from the CG: corrected for")
        for p in self.parameters:
            if not p.identifiable:
                lines.append(f"  {p.name:<22} not identifiable ({p.reason})")
                continue
            mark = ("  applied" + (f" ({p.chosen})" if p.chosen else "") if p.applied else
                    f"  {p.reason}" if p.reason else
                    "  implausible, not applied" if abs(p.estimate) > PLAUSIBLE[p.unit] else "")
            how = "; ".join(f"{k} {e:+.4g} +- {se:.2g}" for k, (e, se) in p.sources.items())
            lines.append(f"  {p.name:<22} {p.estimate:+11.5g} +- {p.se:.3g} {p.unit:<7} (z {p.z:5.1f}){mark}"
                         + (f"  [{how}]" if how else ""))
        for ch, v in self.residual_rms.items():
            lines.append(f"  residual RMS {ch}: {v['before']:.4g} -> {v['after']:.4g}")
        if np.isfinite(self.turbulence_fps):
            lines.append(f"  vertical gust in the reconstruction: {self.turbulence_fps:.2g} ft/s RMS")
        return "\n".join(lines)

    def correct(self, log: Log) -> Log:
        """The log with its documented sensor positions and the applied instrument errors
        removed (before eq. 1)."""
        if not self.applied and not self.positions:
            return log
        raw = columns_of(log.data)
        d = at_cg(raw, self.positions, accelerometers_only=True)
        t = np.asarray(d["t_s"], dtype=float)
        for c in ("p_dps", "q_dps", "r_dps", "ax_fps2", "ay_fps2", "az_fps2"):
            if c in d:
                d[c] = d[c] - self.value(f"{c}.bias")
        for c in ("theta_deg", "phi_deg", "tas_kt", "alpha_deg", "beta_deg"):
            if c in d:
                x = np.interp(t + self.value(f"{c}.delay"), t, np.asarray(d[c], dtype=float))
                d[c] = (x - self.value(f"{c}.bias")) / (1.0 + self.value(f"{c}.scale"))
        if "tas_kt" in d and self.applied and any(p.channel == "tas_kt" for p in self.applied):
            ratio = d["tas_kt"] / raw["tas_kt"]
            for c in ("ias_kt", "mach"):
                if c in d:
                    d[c] = d[c] * ratio
        x = self.value("alpha_deg.position")
        positions = dict(self.positions)
        if x:
            positions.update({c: [x, 0.0, 0.0] for c in ("alpha_deg", "beta_deg")})
        d = at_cg(d, positions, air_data_only=True)
        meta = {**log.meta, "corrections": {p.name: p.estimate for p in self.applied},
                "positions_corrected": positions}
        return replace(log, data=pd.DataFrame(d, index=log.data.index), meta=meta)


def documented_positions(logs: list[Log]) -> dict:
    """Sensor positions the logs document (all must agree), channel -> [x, y, z] [ft]."""
    docs = [lg.meta.get("sensor_positions_ft", {}) for lg in logs]
    return docs[0] if docs and all(d == docs[0] for d in docs) else {}


def columns_of(frame: pd.DataFrame) -> dict[str, np.ndarray]:
    """A frame's columns as arrays, in its order (what :func:`at_cg` takes): a frame's column
    arithmetic and assignment cost more than the arrays' own."""
    if len(frame.columns) and all(t == np.float64 for t in frame.dtypes):
        return dict(zip(frame.columns, frame.to_numpy().T))
    return {c: frame[c].to_numpy() for c in frame.columns}


def at_cg(d: dict[str, np.ndarray], positions: dict, accelerometers_only: bool = False,
          air_data_only: bool = False) -> dict[str, np.ndarray]:
    """Channels moved from where their sensors sit to the CG.

    Accelerometers lose the rotational terms (angular acceleration from the
    gyros' smoothing derivative); the vanes and the pitot lose the flow the
    rotation makes at the boom (vanes ``x`` ahead of the CG read
    ``atan((w - q x) / u)``).

    Parameters
    ----------
    d : dict
        A log's columns, name -> array (:func:`columns_of`).
    positions : dict
        Channel -> sensor position [x, y, z] [ft] from the CG.

    Returns
    -------
    dict
        The same columns, the moved ones replaced.
    """
    from identify.kinematics import smooth_derivative

    out = dict(d)
    t = np.asarray(d["t_s"], dtype=float)
    rates = [np.asarray(d[c], dtype=float) * D2R if c in d else np.zeros(len(t)) for c in ("p_dps", "q_dps", "r_dps")]
    moved = [c for c in ("ax_fps2", "ay_fps2", "az_fps2") if c in positions and c in d]
    if moved and not air_data_only:
        rdot = [smooth_derivative(t, w) for w in rates]
        om = np.stack(rates)
        for k, c in enumerate(("ax_fps2", "ay_fps2", "az_fps2")):
            if c in positions and c in d:
                r = np.asarray(positions[c], float)[:, None]
                wxr = np.cross(om.T, np.broadcast_to(r.T, om.T.shape)).T
                extra = np.cross(np.stack(rdot).T, np.broadcast_to(r.T, om.T.shape)).T + np.cross(om.T, wxr.T).T
                out[c] = np.asarray(d[c], dtype=float) - extra[k]
    if accelerometers_only:
        return out
    x = positions.get("alpha_deg", [0.0])[0]
    if x and "alpha_deg" in d:
        out["alpha_deg"], beta = _at_cg(d, x, positions.get("beta_deg", [x])[0])
        if "beta_deg" in d:
            out["beta_deg"] = beta
    if "tas_kt" in positions and "tas_kt" in d:
        xt = positions["tas_kt"][0]
        a, b = out["alpha_deg"] * D2R, out["beta_deg"] * D2R if "beta_deg" in out else 0.0
        out["tas_kt"] = d["tas_kt"] - xt * (rates[2] * np.sin(b) - rates[1] * np.sin(a) * np.cos(b)) / FT_PER_KT
    return out


def _at_cg(d: dict[str, np.ndarray], x_ft: float, xb_ft: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Alpha and beta at the CG from vanes ``x_ft`` (beta: ``xb_ft``) ahead of it [deg]."""
    xb_ft = x_ft if xb_ft is None else xb_ft
    v = np.asarray(d["tas_kt"], dtype=float) * FT_PER_KT
    q = np.asarray(d["q_dps"], dtype=float) * D2R
    r = np.asarray(d["r_dps"], dtype=float) * D2R if "r_dps" in d else 0.0
    av = np.asarray(d["alpha_deg"], dtype=float) * D2R
    bv = np.asarray(d["beta_deg"], dtype=float) * D2R if "beta_deg" in d else np.zeros(len(v))
    vs = v * np.sin(bv)
    vb = vs - r * xb_ft
    uw = np.sqrt(np.maximum(v ** 2 - vs ** 2, 1.0))
    a = av.copy()
    for _ in range(4):  # the vane reads atan((w - q x) / u) with u, w of the CG
        u = uw * np.cos(a)
        a = np.arctan2(u * np.tan(av) + q * x_ft, u)
    beta = np.arcsin(np.clip(vb / v, -1.0, 1.0)) if "beta_deg" in d else np.zeros(len(v))
    return a / D2R, beta / D2R


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


def _select(logs: list[Log]) -> list[Log]:
    """At most MAX_LOGS logs spread over the conditions, 2-3-1-1s first (they excite most)."""
    ranked = sorted(logs, key=lambda lg: (lg.transition, lg.gear_down, lg.condition, lg.path))
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


CHANNELS = {"p_dps": D2R, "q_dps": D2R, "r_dps": D2R, "ax_fps2": 1.0, "ay_fps2": 1.0, "az_fps2": 1.0,
            "theta_deg": D2R, "phi_deg": D2R, "psi_deg": D2R, "alpha_deg": D2R, "beta_deg": D2R,
            "tas_kt": FT_PER_KT, "alt_ft": 1.0, "vn_fps": 1.0, "ve_fps": 1.0, "vd_fps": 1.0}
#: An inertial/GPS unit's heading and velocity north-east-down: with them the accelerometer biases are pinned.
INS = ("psi_deg", "vn_fps", "ve_fps", "vd_fps")
#: Without these the flight path cannot be reconstructed at all.
ESSENTIAL = ("t_s", "p_dps", "q_dps", "r_dps", "ax_fps2", "ay_fps2", "az_fps2", "theta_deg", "phi_deg",
             "alpha_deg", "beta_deg", "tas_kt", "alt_ft")


def _prepare(logs: list[Log]) -> _Data:
    frames = []
    for lg in logs:
        d = lg.data
        dt = float(np.median(np.diff(d["t_s"])))
        k = max(1, int(round(1.0 / (RATE_HZ * dt))))
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
    n2b = np.swapaxes(_body_to_ned(th, ph, ps), -1, -2)
    return (np.einsum("lnij,lnj->lni", n2b, earth + transport, optimize=True),
            np.einsum("lnij,lnj->lni", n2b, earth, optimize=True))


def _shift(x: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """x(t - tau) per row (held at the ends)."""
    if tau == 0.0:
        return x
    return np.stack([np.interp(t[i] - tau, t[i], x[i]) for i in range(len(x))])


def _shift_columns(x: np.ndarray, t: np.ndarray, tau: float) -> np.ndarray:
    """:func:`_shift` of every column of ``x`` (L, n, P) at once: the interpolation
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
    return np.stack([a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3, a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
                     a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1, a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0], -1)


def _attitude(data: _Data, bp: float, bq: float, br: float, th0: np.ndarray, ph0: np.ndarray,
              ps0: np.ndarray, steps: np.ndarray | None = None):
    """Euler angles integrated from the gyros [rad], less the local frame's own rotation when
    the logs give the latitude and the heading. ``steps`` are :func:`_rotations` of these
    biases if already known.
    """
    steps = _rotations(data, bp, bq, br) if steps is None else steps
    (cy, ct, cf), (sy, st, sf) = np.cos(0.5 * np.stack([ps0, th0, ph0])), np.sin(0.5 * np.stack([ps0, th0, ph0]))
    q0 = np.stack([cf * ct * cy + sf * st * sy, sf * ct * cy - cf * st * sy, cf * st * cy + sf * ct * sy,
                   cf * ct * sy - sf * st * cy], -1)[:, None]
    a, b, c, e = np.moveaxis(np.concatenate([q0, _qmul(np.broadcast_to(q0, steps.shape), steps)], 1), -1, 0)
    th = np.arcsin(np.clip(2.0 * (a * c - e * b), -1.0, 1.0))
    ph = np.arctan2(2.0 * (a * b + c * e), 1.0 - 2.0 * (b * b + c * c))
    ps = np.unwrap(np.arctan2(2.0 * (a * e + b * c), 1.0 - 2.0 * (c * c + e * e)), axis=1)
    ps += np.round((ps0 - ps[:, 0]) / (2.0 * np.pi))[:, None] * 2.0 * np.pi
    return th, ph, ps


def _rotations(data: _Data, bp: float, bq: float, br: float) -> np.ndarray:
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
    rot = 0.5 * (wa + wb) * h + (h ** 2 / 12.0) * np.cross(wa, wb)
    ang = np.linalg.norm(rot, axis=-1, keepdims=True)
    steps = np.concatenate([np.cos(0.5 * ang), np.sin(0.5 * ang) * rot / np.maximum(ang, 1e-300)], -1)
    d = 1
    while d < steps.shape[1]:  # Hillis-Steele scan: steps[k] becomes steps[0] ... steps[k]
        steps = np.concatenate([steps[:, :d], _qmul(steps[:, :-d], steps[:, d:])], 1)
        d *= 2
    return steps


def _body_to_ned(th: np.ndarray, ph: np.ndarray, ps: np.ndarray) -> np.ndarray:
    """Rotation matrices body -> north-east-down (L, n, 3, 3)."""
    ct, st, cp, sp, cs, ss = np.cos(th), np.sin(th), np.cos(ph), np.sin(ph), np.cos(ps), np.sin(ps)
    return np.stack([np.stack([ct * cs, sp * st * cs - cp * ss, cp * st * cs + sp * ss], -1),
                     np.stack([ct * ss, sp * st * ss + cp * cs, cp * st * ss - sp * cs], -1),
                     np.stack([-st, sp * ct, cp * ct], -1)], -2)


# ------------------------------------------------------------------------ velocity


def _skew_exp(w: np.ndarray, h: np.ndarray) -> np.ndarray:
    """exp(-[w]x h) for rows of w (L, 3): the body axes' rotation over a step."""
    ang = np.linalg.norm(w, axis=1) * h
    axis = w / np.maximum(np.linalg.norm(w, axis=1), 1e-12)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
    s, c = np.sin(-ang)[:, None, None], (1 - np.cos(-ang))[:, None, None]
    return np.eye(3)[None] + s * K + c * (K @ K)


def _responses(data: _Data, rates: tuple[np.ndarray, ...], th: np.ndarray, ph: np.ndarray):
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
    for k in range(n - 1):
        R = _skew_exp(0.5 * (w[:, k] + w[:, k + 1]), data.dt)
        Phi[:, k + 1] = R @ Phi[:, k]
        X[:, k + 1] = R @ (X[:, k] + 0.5 * h * forcing[:, k]) + 0.5 * h * forcing[:, k + 1]
    rate_phi = np.einsum("lni,lnij->lnj", c, Phi, optimize=True)
    rate_x = np.einsum("lni,lnij->lnj", c, X, optimize=True)
    dt = data.dt[:, None, None]
    HPhi = np.concatenate([np.zeros((L, 1, 3)), np.cumsum(0.5 * dt * (rate_phi[:, 1:] + rate_phi[:, :-1]), 1)], 1)
    HX = np.concatenate([np.zeros((L, 1, 6)), np.cumsum(0.5 * dt * (rate_x[:, 1:] + rate_x[:, :-1]), 1)], 1)
    return Phi, X, HPhi, HX


# ------------------------------------------------------------------------ estimation


def _gust_basis(data: _Data) -> np.ndarray:
    """Zero-mean cubic B-splines, knots :data:`GUST_KNOT_S` apart over each log (L, n, K):
    the slow wander of the air mass (turbulence) the air data see and the kinematics do not."""
    L, n = data.t.shape
    span = float(max(data.t[i][data.mask[i]][-1] for i in range(L)))
    inner = max(int(np.ceil(span / GUST_KNOT_S)), 1)
    out = np.zeros((L, n, inner + 3))
    for i in range(L):
        t = data.t[i]
        end = float(t[data.mask[i]][-1])
        knots = np.concatenate([[0.0] * 3, np.linspace(0.0, end, inner + 1), [end] * 3])
        b = BSpline.design_matrix(np.clip(t, 0.0, end), knots, 3).toarray()
        b -= b[data.mask[i]].mean(axis=0)
        out[i] = b * data.mask[i][:, None]
    return out


def _noise(x: np.ndarray, mask: np.ndarray, floor: float) -> float:
    d2 = np.diff(x, 2, axis=1)[mask[:, 2:]]
    s = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0) if d2.size else 0.0
    return max(s, floor)


class _Blocks:
    """Normal equations of [shared | per-log] parameters, solved log by log (Schur complement).

    ``Js`` (rows x shared) is dense; ``Jp`` (rows x per) holds each row's derivatives
    by its own log's parameters only.
    """

    def __init__(self, Js: np.ndarray, Jp: np.ndarray, e: np.ndarray, rows: list[np.ndarray]) -> None:
        self.rows = rows
        ns, per = Js.shape[1], Jp.shape[1]
        self.Hll, self.Hsl, self.gl, self.Bb, self.gb = [], [], [], [], []  # each log's products only
        for r in rows:
            hll, hsl, gl, bb, gb = np.zeros((per, per)), np.zeros((ns, per)), np.zeros(per), np.zeros((ns, ns)), \
                np.zeros(ns)
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

    def cluster_cov(self) -> np.ndarray:
        """Covariance of the shared parameters robust to any correlation within a log (logs as
        clusters; turbulence makes the air data wander for seconds against the kinematics, longer
        than a 28-second record shows): the delete-one-log jackknife, one Gauss-Newton step per
        log, ``(L-1)/L sum_l (d_l - mean)(d_l - mean)'``. Unlike the plain cluster sandwich it sees
        a log's leverage: a scale factor that only a few conditions' trim alphas pin down is as
        uncertain as those few logs make it."""
        if not len(self.gs):
            return np.zeros((0, 0))
        hll_inv = [np.linalg.pinv(h) for h in self.Hll]
        own = [bb - h @ hi @ h.T for bb, h, hi in zip(self.Bb, self.Hsl, hll_inv)]
        S = self.Hss - sum(h @ hi @ h.T for h, hi in zip(self.Hsl, hll_inv))
        L = len(self.rows)
        d = np.array([np.linalg.pinv(S - s_l) @ (gb - h @ hi @ g)
                      for gb, g, h, hi, s_l in zip(self.gb, self.gl, self.Hsl, hll_inv, own)])
        d -= d.mean(axis=0)
        return d.T @ d * ((L - 1) / L)


def _excited(data: _Data, recon: dict[str, np.ndarray]) -> dict[str, str]:
    """Parameters the logs cannot identify, with the reason. Scale factors and time shifts
    need the reconstructed signal to move (turbulence moves the measured one too)."""
    out = {}
    m = data.mask
    for c, need, unit, k in (("theta_deg", 2.0, "deg", D2R), ("phi_deg", LATERAL_SPAN["phi_deg"], "deg", D2R),
                             ("alpha_deg", 1.0, "deg", D2R), ("beta_deg", LATERAL_SPAN["beta_deg"], "deg", D2R),
                             ("tas_kt", 5.0, "kt", FT_PER_KT)):
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
    if "q_dps" not in data.present or float(np.std(data.ch["q_dps"][m])) < 0.5 * D2R:
        out["alpha_deg.position"] = "pitch rate hardly excited"
    # what longitudinal manoeuvres without a ground-speed reference cannot separate, whatever the data
    beta_span = float(np.ptp(recon.get("beta_deg", data.ch["beta_deg"])[m])) / D2R
    phi_span = float(np.ptp(recon.get("phi_deg", data.ch["phi_deg"])[m])) / D2R
    theta_span = float(np.ptp(recon.get("theta_deg", data.ch["theta_deg"])[m])) / D2R
    if beta_span < LATERAL_SPAN["beta_deg"]:
        out.setdefault("beta_deg.bias", "a sideslip offset is a lateral velocity offset without a lateral manoeuvre")
    if phi_span < LATERAL_SPAN["phi_deg"]:
        out.setdefault("phi_deg.bias", "confounded with the lateral accelerometer's bias through gravity without a "
                                       "bank")
    if theta_span < THETA_BIAS_SPAN:
        out.setdefault("theta_deg.bias", f"confounded with the longitudinal accelerometer's bias through gravity "
                                         f"(pitch spans {theta_span:.0f} deg, needs {THETA_BIAS_SPAN:g})")
    for e in ("bias", "scale", "delay"):
        out.setdefault(f"tas_kt.{e}", "a steady wind along the track takes it (no turns in the manoeuvres)"
                       if all(c in data.present for c in INS) else
                       "no inertial speed reference in the logs (ground speed): each log's own initial speed "
                       "absorbs it")
    for c in ("p_dps", "r_dps", "ay_fps2"):
        if c not in data.present:
            out[f"{c}.bias"] = "channel not in the logs"
    if "phi_deg" not in data.present:
        out["p_dps.bias"] = "roll angle not in the logs"
    return out


def _gauss_newton(residual, x: np.ndarray, free: np.ndarray, ns: int, L: int, per: int,
                  rows: list[np.ndarray], perlog=None, max_iter: int = 40):
    """Damped Gauss-Newton: x = [shared (ns), per log (L x per)]; ``free`` masks the shared ones
    (each log's own parameters are always free).

    The shared columns of the Jacobian are forward differences; the per-log ones
    too (one evaluation per slot: each log's rows depend on its own only), unless
    ``perlog(x)`` gives them: an array (residual rows, per).

    Returns
    -------
    x, _Blocks at x, residual at x
    """
    idx = np.flatnonzero(free[:ns])
    steps = 1e-6 * np.maximum(np.abs(x), 1.0)
    n_rows = sum(len(r) for r in rows)
    row_log = np.empty(n_rows, int)
    for i, r in enumerate(rows):
        row_log[r] = i

    def blocks(x0, e0):
        Js = np.empty((len(e0), len(idx)))
        for j, i in enumerate(idx):
            xp = x0.copy()
            xp[i] += steps[i]
            Js[:, j] = (residual(xp) - e0) / steps[i]
        if perlog is not None:
            Jp = perlog(x0)
        else:
            Jp = np.empty((len(e0), per))
            for slot in range(per):
                cols = ns + np.arange(L) * per + slot
                xp = x0.copy()
                xp[cols] += steps[cols]
                Jp[:, slot] = (residual(xp) - e0) / steps[cols][row_log]
        return _Blocks(Js, Jp, e0, rows)

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
        done = cost - cn <= 1e-10 * max(cost, 1e-300)
        x, e, cost, lam = xn, en, cn, max(lam / 10.0, 1e-9)
        blk = blocks(x, e)
        if done:
            break
    return x, blk, e


def estimate(logs: list[Log]) -> CompatResult:
    """Estimate the instrument errors from the logs (see the module notes).

    Returns
    -------
    CompatResult
    """
    params = _parameters()
    by = {p.name: p for p in params}
    positions = documented_positions(logs)
    missing = [c for c in ESSENTIAL if not logs or not all(c in lg.data for lg in logs)]
    if missing:
        for p in params:
            p.identifiable, p.reason = False, f"no reconstruction: {missing[0]} is not logged"
        return CompatResult(params, [lg.path for lg in logs], {}, positions)
    chosen = _select(logs)
    data = _prepare([replace(lg, data=pd.DataFrame(at_cg(columns_of(lg.data), positions, accelerometers_only=True),
                                                    index=lg.data.index)) for lg in chosen])
    x_doc = positions.get("alpha_deg", [None])[0]
    xb_doc = positions.get("beta_deg", [x_doc])[0]
    if x_doc is not None:
        by["alpha_deg.position"].identifiable = False
        by["alpha_deg.position"].reason = f"documented in the logs: {x_doc:g} ft ahead of the CG"
    L = len(chosen)
    mask = data.mask
    valid = mask.ravel()
    sig = {c: _noise(data.ch[c], mask, fl) for c, fl in (("theta_deg", 0.002 * D2R), ("phi_deg", 0.002 * D2R),
                                                           ("psi_deg", 0.002 * D2R), ("alpha_deg", 0.005 * D2R),
                                                           ("beta_deg", 0.005 * D2R), ("tas_kt", 0.02 * FT_PER_KT),
                                                           ("alt_ft", 0.5), ("vn_fps", 0.02), ("ve_fps", 0.02),
                                                           ("vd_fps", 0.02))}
    rms: dict = {}
    covs: list = []

    # ---- stage 1: attitude from the gyros
    s1 = ["p_dps.bias", "q_dps.bias", "r_dps.bias", "theta_deg.scale", "theta_deg.delay", "phi_deg.scale",
          "phi_deg.delay"]
    outs1 = [c for c in ("theta_deg", "phi_deg", "psi_deg") if c in data.present]

    last_rotations: dict = {}  # the gyro biases of the last evaluation -> its rotations

    def model1(x):
        v = dict(zip(s1, x[:len(s1)]))
        per = x[len(s1):].reshape(L, 3)
        biases = (v["p_dps.bias"] * D2R, v["q_dps.bias"] * D2R, v["r_dps.bias"] * D2R)
        key = np.array(biases).tobytes()  # bit for bit
        if key not in last_rotations:  # a difference in an initial angle, a scale or a delay keeps them
            last_rotations.clear()
            last_rotations[key] = _rotations(data, *biases)
        th, ph, ps = _attitude(data, *biases, per[:, 0], per[:, 1], per[:, 2], steps=last_rotations[key])
        return {"theta_deg": (1 + v["theta_deg.scale"]) * _shift(th, data.t, v["theta_deg.delay"]),
                "phi_deg": (1 + v["phi_deg.scale"]) * _shift(ph, data.t, v["phi_deg.delay"]),
                "psi_deg": ps}, (th, ph, ps)

    def resid1(x):
        m, _ = model1(x)
        return np.concatenate([((data.ch[c] - m[c]) / sig[c]).ravel()[valid] for c in outs1])

    x1 = np.concatenate([np.zeros(len(s1)), np.stack([data.ch[c][:, 0] for c in ("theta_deg", "phi_deg",
                                                                                  "psi_deg")], 1).ravel()])
    rows1 = np.tile(np.repeat(np.arange(L), mask.sum(1)), len(outs1))
    if outs1:
        x1 = _solve_stage(resid1, x1, s1, by, 3, L, rows1, outs1, sig, valid, rms, mask,
                          lambda x: {c: model1(x)[0][c] for c in outs1}, data, covs=covs)
    v1 = dict(zip(s1, x1[:len(s1)]))
    _, (th_r, ph_r, ps_r) = model1(x1)

    # ---- stage 2: velocity, air data and altitude from the accelerometers
    rates = tuple(data.ch[c] - v1[f"{c}.bias"] * D2R for c in ("p_dps", "q_dps", "r_dps"))
    Phi, X, HPhi, HX = _responses(data, rates, th_r, ph_r)
    s2 = ["ax_fps2.bias", "ay_fps2.bias", "az_fps2.bias", "theta_deg.bias", "phi_deg.bias",
          "alpha_deg.bias", "alpha_deg.scale", "alpha_deg.delay", "alpha_deg.position",
          "beta_deg.bias", "beta_deg.scale", "beta_deg.delay", "tas_kt.bias", "tas_kt.scale", "tas_kt.delay"]
    ins = all(c in data.present for c in INS)
    outs2 = [c for c in ("alpha_deg", "beta_deg", "tas_kt", "alt_ft") + (INS[1:] if ins else ())
             if c in data.present]
    q_c, r_c = rates[1], rates[2]

    gust = _gust_basis(data)
    k_gust = gust.shape[2]
    n_wind = 2 if ins else 0  # a steady horizontal wind per log, where the INS tells air from ground
    g0 = 4 + n_wind
    n_per = g0 + 3 * k_gust
    b2n = _body_to_ned(th_r, ph_r, ps_r)
    wind_dirs = np.swapaxes(b2n, -1, -2)[..., :2]  # (L, n, 3, 2): north and east in body axes
    ins_phi = np.einsum("lnij,lnjk->lnik", b2n, Phi, optimize=True) if ins else None  # d(v_NED)/d(v0)

    forcing = [s2.index(n) for n in ("ax_fps2.bias", "ay_fps2.bias", "az_fps2.bias", "theta_deg.bias",
                                     "phi_deg.bias")]
    last_state: dict = {}  # the parameters the flight path depends on, bit for bit -> the path

    def state(x):
        """Shared values, per-log values, air-relative body velocity, altitude and the inertial
        velocity north-east-down (if the logs have it). A difference in an air-data error keeps the
        flight path: it is computed again only when the parameters it depends on change."""
        v = dict(zip(s2, x[:len(s2)]))
        key = x[forcing].tobytes() + x[len(s2):].tobytes()
        if key not in last_state:
            per = x[len(s2):].reshape(L, n_per).copy()
            lin = np.concatenate([[1.0], [v["ax_fps2.bias"], v["ay_fps2.bias"], v["az_fps2.bias"]],
                                  [v["theta_deg.bias"] * D2R, v["phi_deg.bias"] * D2R]])
            inertial = np.einsum("lnij,lj->lni", Phi, per[:, :3], optimize=True) + X @ lin
            h = per[:, 3:4] + np.einsum("lnj,lj->ln", HPhi, per[:, :3], optimize=True) + HX @ lin
            # air = inertial - gust
            vel = inertial - np.einsum("lnk,lck->lnc", gust, per[:, g0:].reshape(L, 3, k_gust), optimize=True)
            if n_wind:
                vel = vel - np.einsum("lncw,lw->lnc", wind_dirs, per[:, 4:6], optimize=True)
            ned = np.moveaxis(np.einsum("lnij,lnj->lni", b2n, inertial, optimize=True), -1, 0) if ins else None
            last_state.clear()
            last_state[key] = per, vel, h, ned
        return (v, *last_state[key])

    def model2(x):
        v, _, vel, h, ned = state(x)
        u, vv, w = vel[..., 0], vel[..., 1], vel[..., 2]
        xh = v["alpha_deg.position"] if x_doc is None else x_doc
        xb = xh if xb_doc is None else xb_doc
        vt = np.sqrt(u ** 2 + vv ** 2 + w ** 2)
        alpha_v = np.arctan2(w - q_c * xh, u)
        beta_v = np.arcsin(np.clip((vv + r_c * xb) / vt, -1, 1))
        return {"alpha_deg": (1 + v["alpha_deg.scale"]) * _shift(alpha_v, data.t, v["alpha_deg.delay"])
                + v["alpha_deg.bias"] * D2R,
                "beta_deg": (1 + v["beta_deg.scale"]) * _shift(beta_v, data.t, v["beta_deg.delay"])
                + v["beta_deg.bias"] * D2R,
                "tas_kt": (1 + v["tas_kt.scale"]) * _shift(vt, data.t, v["tas_kt.delay"])
                + v["tas_kt.bias"] * FT_PER_KT,
                "alt_ft": h,
                **(dict(zip(INS[1:], ned)) if ins else {})}

    def resid2(x):
        m = model2(x)
        return np.concatenate([((data.ch[c] - m[c]) / sig[c]).ravel()[valid] for c in outs2])

    def perlog2(x):
        """d(residual)/d(each log's initial velocity, altitude and gust coefficients), by the chain rule."""
        v, _, vel, _, _ = state(x)
        u, vv, w = vel[..., 0], vel[..., 1], vel[..., 2]
        xh = v["alpha_deg.position"] if x_doc is None else x_doc
        xb = xh if xb_doc is None else xb_doc
        vt2 = u ** 2 + vv ** 2 + w ** 2
        vt = np.sqrt(vt2)
        wv, vb = w - q_c * xh, vv + r_c * xb
        den_a = u ** 2 + wv ** 2
        sb = np.clip(vb / vt, -0.999999, 0.999999)
        cb = np.sqrt(1 - sb ** 2)
        d_out = {  # derivative of each air-data output by (u, v, w), before scale and delay
            "alpha_deg": np.stack([-wv / den_a, np.zeros_like(u), u / den_a], -1),
            "beta_deg": np.stack([-vb * u / (vt2 * vt), (1 / vt - vb * vv / (vt2 * vt)), -vb * w / (vt2 * vt)], -1)
            / cb[..., None],
            "tas_kt": vel / vt[..., None],
        }
        # d vel / d per-log parameters: Phi for the initial velocity, -basis for the gust coefficients,
        # minus the north and east directions for the wind
        n_valid = int(valid.sum())
        out = np.zeros((len(outs2) * n_valid, n_per))
        for b, c in enumerate(outs2):
            block = out[b * n_valid:(b + 1) * n_valid]
            if c == "alt_ft":
                block[:, :3] = HPhi.reshape(-1, 3)[valid]
                block[:, 3] = 1.0
            elif c in INS:
                block[:, :3] = ins_phi[..., INS.index(c) - 1, :].reshape(-1, 3)[valid]
            else:
                dc = d_out[c]
                d = np.zeros((L, vel.shape[1], n_per))
                d[..., :3] = np.einsum("lnc,lncj->lnj", dc, Phi, optimize=True)
                if n_wind:
                    d[..., 4:6] = -np.einsum("lnc,lncw->lnw", dc, wind_dirs, optimize=True)
                for j in range(3):
                    d[..., g0 + j * k_gust:g0 + (j + 1) * k_gust] = dc[..., j, None] * -gust
                block[:] = _shift_columns(d, data.t, v[f"{c}.delay"]).reshape(-1, n_per)[valid]
                block *= 1 + v[f"{c}.scale"]
            block /= -sig[c]
        return out

    a0, b0 = data.ch["alpha_deg"][:, 0], data.ch["beta_deg"][:, 0]
    v0 = data.ch["tas_kt"][:, 0]
    init = np.stack([v0 * np.cos(a0) * np.cos(b0), v0 * np.sin(b0), v0 * np.sin(a0) * np.cos(b0),
                     data.ch["alt_ft"][:, 0]], 1)
    x2 = np.concatenate([np.zeros(len(s2)), np.hstack([init, np.zeros((L, n_wind + 3 * k_gust))]).ravel()])
    rows2 = np.tile(np.repeat(np.arange(L), mask.sum(1)), len(outs2))
    x2 = _solve_stage(resid2, x2, s2, by, n_per, L, rows2, outs2, sig, valid, rms, mask, model2, data, perlog2,
                      covs)
    per = x2[len(s2):].reshape(L, n_per)
    w_gust = np.einsum("lnk,lk->ln", gust, per[:, g0 + 2 * k_gust:g0 + 3 * k_gust], optimize=True)
    turbulence = float(np.sqrt(np.mean(w_gust[mask] ** 2)))
    if turbulence > TURBULENT_FPS:
        for c in ("alpha_deg", "beta_deg", "tas_kt"):
            p = by[f"{c}.delay"]
            if p.identifiable:
                p.identifiable = False
                p.reason = (f"turbulence: the reconstruction's vertical gust is {turbulence:.2g} ft/s RMS, and the "
                            f"aircraft's answer to it biases the kinematic time shift by tens of ms (fly the "
                            f"compatibility manoeuvres in calm air); kinematic estimate {p.estimate * 1000:+.0f} ms")
    for ch, k in (("theta_deg", D2R), ("phi_deg", D2R), ("alpha_deg", D2R), ("beta_deg", D2R),
                  ("tas_kt", FT_PER_KT)):
        if ch in rms:
            rms[ch] = {key: v / k for key, v in rms[ch].items()}
    return CompatResult(params, [lg.path for lg in chosen], rms, positions, covs, turbulence)


def _solve_stage(residual, x, names, by, per, L, rows, outs, sig, valid, rms, mask, model, data,
                 perlog=None, covs: list | None = None) -> np.ndarray:
    """Initial states alone (perfect instruments assumed), then the identifiable instrument
    errors too; parameters the data cannot tell apart (|correlation| > 0.995) are fixed at 0."""
    ns = len(names)
    free = np.zeros(ns, bool)
    rows = [np.flatnonzero(rows == i) for i in range(L)]  # residual rows of each log
    x, _, e = _gauss_newton(residual, x, free, ns, L, per, rows, perlog)
    n = int(valid.sum())
    for i, c in enumerate(outs):
        rms[c] = {"before": float(np.sqrt(np.mean((e[i * n:(i + 1) * n] * sig[c]) ** 2)))}
    recon = {c: v for c, v in model(x).items()}
    for name, why in _excited(data, recon).items():
        if name in by and name in names:
            by[name].identifiable, by[name].reason = False, why
    free[:] = [by[s].identifiable for s in names]
    pairs = []  # (pruned, kept) indices into names
    while True:
        x, blk, e = _gauss_newton(residual, x, free, ns, L, per, rows, perlog)
        cov = blk.cluster_cov()
        idx = np.flatnonzero(free)
        sd = np.sqrt(np.abs(np.diag(cov)))
        if len(idx) < 2:
            break
        corr = cov / np.maximum(np.outer(sd, sd), 1e-300)
        vif = np.diag(np.linalg.pinv(corr))
        if vif.max() <= MAX_VIF:
            break
        # the most inflated parameter goes (of near ties, the latest listed); the one it leans on is confounded
        worst = max(j for j in range(len(idx)) if vif[j] >= 0.9 * vif.max())
        partner = int(np.argmax(np.where(np.arange(len(idx)) == worst, -1.0, np.abs(corr[worst]))))
        if names[idx[partner]] in PRUNE_FIRST and names[idx[worst]] not in PRUNE_FIRST:
            worst, partner = partner, worst  # keep the error eq. (1) feels; the residuals may choose it
        by[names[idx[worst]]].identifiable = False
        by[names[idx[worst]]].reason = (f"not separable from {names[idx[partner]]} in these manoeuvres "
                                        f"(variance inflation {vif[worst]:.0f})")
        by[names[idx[partner]]].reason = (f"confounded with {names[idx[worst]]}: the estimate holds both "
                                          f"(not applied)")
        by[names[idx[partner]]].confounded_with = names[idx[worst]]
        pairs.append((idx[worst], idx[partner]))
        free[idx[worst]] = False
        x[idx[worst]] = 0.0
    for j, i in enumerate(idx):
        by[names[i]].estimate, by[names[i]].se = float(x[i]), float(sd[j])
    if covs is not None:
        covs.append(([names[i] for i in idx], cov))
    for pruned, kept in pairs:  # the other reading of the same data: the pruned error, its partner at 0
        if not free[kept]:
            continue
        alt_free = free.copy()
        alt_free[pruned], alt_free[kept] = True, False
        x_alt = x.copy()
        x_alt[kept] = 0.0
        x_alt, blk_alt, _ = _gauss_newton(residual, x_alt, alt_free, ns, L, per, rows, perlog)
        j = int(np.flatnonzero(np.flatnonzero(alt_free) == pruned)[0])
        p = by[names[pruned]]
        p.estimate, p.se = float(x_alt[pruned]), float(np.sqrt(abs(blk_alt.cluster_cov()[j, j])))
        p.identifiable, p.confounded_with = True, names[kept]
    for i, c in enumerate(outs):
        rms[c]["after"] = float(np.sqrt(np.mean((e[i * n:(i + 1) * n] * sig[c]) ** 2)))
    return x
