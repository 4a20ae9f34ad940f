"""Instrument profiles: how flight-test instrumentation records a flight.

A profile (TOML) gives the logging rate, the channels not recorded, the
turbulence the aeroplane flies through, and per channel the sensor's noise,
bias, scale factor, lag, delay and position. Shipped profiles live in
``campaign/instruments/``; a user's file may start from one (``extends``).

The sensors see the flight at JSBSim's rate, in this order: the quantity where
the sensor sits (a vane on a nose boom sees the local flow, an accelerometer
away from the CG the rotational accelerations), its first-order lag, the
acquisition delay, scale and bias; then the anti-alias filter and resampling
to the logging rate, then white noise. The recording never disturbs the flight;
turbulence does, and the engine flies it (:mod:`campaign.simulation.turbulence`).
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import lfilter, lfilter_zi, resample_poly

from campaign.simulation.catalog import LOG_COLUMNS
from campaign.errors import UserError

SHIPPED = Path(__file__).resolve().parent / "profiles"
TOP_KEYS = {"extends", "description", "rate_hz", "omit", "turbulence", "channels"}
CHANNEL_KEYS = {"noise", "bias", "scale", "lag_s", "delay_s", "position_ft"}
#: Channels a sensor position changes (vanes and pitot on a boom, accelerometers off the CG).
POSITIONED = ("alpha_deg", "beta_deg", "tas_kt", "ax_fps2", "ay_fps2", "az_fps2")
#: Channels that may not be omitted: what eq. (1) and the states cannot do without.
REQUIRED = (
    "t_s",
    "alt_ft",
    "tas_kt",
    "alpha_deg",
    "theta_deg",
    "q_dps",
    "ax_fps2",
    "az_fps2",
    "qbar_psf",
    "thrust_lbf",
    "elevator_deg",
    "gear_norm",
    "mass_slug",
)
#: Positions and set quantities are sampled, not filtered (a filter rings at a gear's end stops).
SAMPLED = ("gear_norm", "flap_deg", "mass_slug", "xcg_in")
D2R = np.pi / 180.0
FT_PER_KT = 1.6878098571011957
#: The simulation's rate, 1 / :data:`campaign.simulation.engine.DT_S` [Hz]: a logging rate at most this.
SIM_RATE_HZ = 120.0
#: The slowest logging rate [Hz]: below it a 2-3-1-1's unit step is a sample or two.
MIN_RATE_HZ = 5.0
#: Bounds of what a sensor can be: lag and delay [s], scale factor [-], distance from the CG [ft],
#: turbulence [ft/s].
MAX_LAG_S, MAX_DELAY_S = 5.0, 5.0
SCALE_RANGE = (0.5, 2.0)
MAX_POSITION_FT = 500.0
MAX_SIGMA_FPS = 30.0


@dataclass(frozen=True)
class Sensor:
    """One channel's sensor: white noise (1 sigma), bias and scale in the channel's units,
    lag time constant and delay [s], position relative to the CG in body axes [ft]."""

    noise: float = 0.0
    bias: float = 0.0
    scale: float = 1.0
    lag_s: float = 0.0
    delay_s: float = 0.0
    position_ft: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def ideal(self) -> bool:
        return self == Sensor()


@dataclass(frozen=True)
class InstrumentProfile:
    """A parsed, validated instrument profile (picklable, hashable).

    Attributes
    ----------
    name : str
        The shipped name or the file's name.
    rate_hz : float or None
        Logging rate after anti-alias filtering; None keeps the simulation's.
    omit : tuple of str
        Channels not recorded.
    sigma_fps : float
        RMS vertical gust of the turbulence at the point's altitude [ft/s].
    sensors : tuple of (channel, Sensor)
        Only the channels whose sensor is not ideal.
    """

    name: str
    rate_hz: float | None = None
    omit: tuple[str, ...] = ()
    sigma_fps: float = 0.0
    sensors: tuple[tuple[str, Sensor], ...] = ()
    description: str = field(default="", compare=False)

    def sensor(self, channel: str) -> Sensor:
        return dict(self.sensors).get(channel, Sensor())

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "rate_hz": self.rate_hz,
            "omit": list(self.omit),
            "turbulence": {"sigma_fps": self.sigma_fps},
            "channels": {
                c: {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(s).items()} for c, s in self.sensors
            },
        }

    @property
    def sha256(self) -> str:
        """Hash of what the profile does (its name and description excluded)."""
        doc = self.to_json()
        doc.pop("name")
        return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def shipped() -> list[str]:
    """Names of the shipped profiles."""
    return sorted(p.stem for p in SHIPPED.glob("*.toml"))


def _num(
    path: str, where: str, value, lo: float | None = None, positive: bool = False, hi: float | None = None
) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise UserError(f"{path}: {where}: expected a number, found {str(value)[:40]!r}")
    if positive and value <= 0:
        raise UserError(f"{path}: {where}: must be > 0, found {value!r}")
    if lo is not None and value < lo:
        raise UserError(f"{path}: {where}: must be >= {lo:g}, found {value!r}")
    if hi is not None and value > hi:
        raise UserError(f"{path}: {where}: must be <= {hi:g}, found {value!r}")
    return float(value)


#: Per-channel keys: (lowest, highest) value, None where unbounded.
SENSOR_BOUNDS = {
    "noise": (0.0, None),
    "bias": (None, None),
    "scale": SCALE_RANGE,
    "lag_s": (0.0, MAX_LAG_S),
    "delay_s": (0.0, MAX_DELAY_S),
}


def _read(path: Path, seen: tuple[str, ...] = ()) -> dict:
    """The profile's table with ``extends`` resolved (a child's keys override its parent's)."""
    ps = str(path)
    if not path.is_file():
        raise UserError(f"{ps}: instrument profile not found")
    try:
        doc = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{ps}: TOML does not parse: {exc}") from None
    extra = sorted(set(doc) - TOP_KEYS)
    if extra:
        raise UserError(f"{ps}: {extra[0]}: unknown key (allowed: {', '.join(sorted(TOP_KEYS))})")
    for key in ("turbulence", "channels"):
        if not isinstance(doc.get(key, {}), dict):
            raise UserError(f"{ps}: {key}: expected a table [{key}]")
    parent = doc.pop("extends", None)
    if parent is None:
        return doc
    if not isinstance(parent, str) or parent not in shipped():
        raise UserError(f"{ps}: extends: {parent!r} is not a shipped profile ({', '.join(shipped())})")
    if parent in seen:
        raise UserError(f"{ps}: extends: {parent!r} extends itself")
    base = _read(SHIPPED / f"{parent}.toml", seen + (parent,))
    channels = {c: dict(v) for c, v in base.get("channels", {}).items()}
    for c, v in doc.get("channels", {}).items():
        channels[c] = {**channels.get(c, {}), **v} if isinstance(v, dict) else v
    merged = {**base, **doc, "channels": channels}
    merged["turbulence"] = {**base.get("turbulence", {}), **doc.get("turbulence", {})}
    return merged


def load_profile(spec: str | Path) -> InstrumentProfile:
    """A shipped profile by name, or a profile file.

    Raises
    ------
    UserError
        One line naming the file and the key: unknown keys or channels, values out
        of range, a position on a channel without one, omitting a required channel.
    """
    path = SHIPPED / f"{spec}.toml" if str(spec) in shipped() else Path(spec)
    doc = _read(path)
    ps = str(path)
    rate = doc.get("rate_hz")
    if rate is not None:
        rate = _num(ps, "rate_hz", rate, positive=True)
        if not MIN_RATE_HZ <= rate <= SIM_RATE_HZ:
            raise UserError(
                f"{ps}: rate_hz: {rate:g} Hz is outside {MIN_RATE_HZ:g}..{SIM_RATE_HZ:g} Hz (the "
                f"simulation runs at {SIM_RATE_HZ:g} Hz: a recorder logs at most that)"
            )
    omit = doc.get("omit", [])
    if not isinstance(omit, list) or not all(isinstance(c, str) for c in omit):
        raise UserError(f"{ps}: omit: expected a list of log channels")
    for c in omit:
        if c not in LOG_COLUMNS:
            raise UserError(f"{ps}: omit: {c!r} is not a log channel")
        if c in REQUIRED:
            raise UserError(f"{ps}: omit: {c!r} cannot be omitted (eq. 1 and the states need it)")
    turb = doc.get("turbulence", {})
    if not isinstance(turb, dict):
        raise UserError(f"{ps}: turbulence: expected a table")
    if set(turb) - {"sigma_fps"}:
        raise UserError(f"{ps}: turbulence.{sorted(set(turb) - {'sigma_fps'})[0]}: unknown key (allowed: sigma_fps)")
    sigma = _num(ps, "turbulence.sigma_fps", turb.get("sigma_fps", 0.0), lo=0.0, hi=MAX_SIGMA_FPS)
    sensors = []
    channels = doc.get("channels", {})
    if not isinstance(channels, dict):
        raise UserError(f"{ps}: channels: expected tables [channels.<log channel>]")
    for c, spec_c in sorted(channels.items()):
        where = f"channels.{c}"
        if c not in LOG_COLUMNS or c == "t_s":
            raise UserError(f"{ps}: {where}: {c!r} is not a log channel")
        if not isinstance(spec_c, dict):
            raise UserError(f"{ps}: {where}: expected a table")
        extra = sorted(set(spec_c) - CHANNEL_KEYS)
        if extra:
            raise UserError(f"{ps}: {where}.{extra[0]}: unknown key (allowed: {', '.join(sorted(CHANNEL_KEYS))})")
        kw = {
            k: _num(ps, f"{where}.{k}", spec_c[k], *SENSOR_BOUNDS[k][:1], hi=SENSOR_BOUNDS[k][1])
            for k in SENSOR_BOUNDS
            if k in spec_c
        }
        if "position_ft" in spec_c:
            pos = spec_c["position_ft"]
            if not isinstance(pos, list) or len(pos) != 3:
                raise UserError(f"{ps}: {where}.position_ft: expected [x, y, z] in feet")
            kw["position_ft"] = tuple(
                _num(ps, f"{where}.position_ft", v, -MAX_POSITION_FT, hi=MAX_POSITION_FT) for v in pos
            )
            if any(kw["position_ft"]) and c not in POSITIONED:
                raise UserError(f"{ps}: {where}.position_ft: a position applies only to {', '.join(POSITIONED)}")
        s = Sensor(**kw)
        if not s.ideal:
            sensors.append((c, s))
    name = str(spec) if str(spec) in shipped() else path.name
    return InstrumentProfile(name, rate, tuple(omit), sigma, tuple(sensors), str(doc.get("description", "")))


def _at_position(df, extra, channel: str, r: tuple[float, float, float]) -> np.ndarray:
    """What a sensor at ``r`` (body axes, from the CG) [ft] sees of a channel (``df`` and ``extra``
    as :func:`record` takes them)."""
    x, y, z = r
    p, q, rr = (np.asarray(df[c]) * D2R for c in ("p_dps", "q_dps", "r_dps"))
    if channel in ("ax_fps2", "ay_fps2", "az_fps2"):
        pd_, qd, rd = (np.asarray(extra[c]) for c in ("pdot_rps2", "qdot_rps2", "rdot_rps2"))
        wxr = np.stack([q * z - rr * y, rr * x - p * z, p * y - q * x])  # omega x r
        om = np.stack([p, q, rr])
        centripetal = np.cross(om.T, wxr.T).T
        angular = np.stack([qd * z - rd * y, rd * x - pd_ * z, pd_ * y - qd * x])
        k = "xyz".index(channel[1])
        return np.asarray(df[channel]) + angular[k] + centripetal[k]
    a, b = np.asarray(df["alpha_deg"]) * D2R, np.asarray(df["beta_deg"]) * D2R
    v = np.asarray(df["tas_kt"]) * FT_PER_KT
    u_s = v * np.cos(a) * np.cos(b) + q * z - rr * y
    v_s = v * np.sin(b) + rr * x - p * z
    w_s = v * np.sin(a) * np.cos(b) + p * y - q * x
    vt = np.sqrt(u_s**2 + v_s**2 + w_s**2)
    if channel == "alpha_deg":
        return np.arctan2(w_s, u_s) / D2R
    if channel == "beta_deg":
        return np.arcsin(v_s / vt) / D2R
    return vt / FT_PER_KT


def _lag(x: np.ndarray, tau: float, dt: float) -> np.ndarray:
    """First-order lag (bilinear transform), starting at rest at the first sample."""
    c = 2.0 * tau / dt
    b, a = [1.0 / (1.0 + c)] * 2, [1.0, (1.0 - c) / (1.0 + c)]
    y, _ = lfilter(b, a, x, zi=lfilter_zi(b, a) * x[0])
    return y


def _delay(x: np.ndarray, d: float, dt: float) -> np.ndarray:
    t = np.arange(len(x)) * dt
    return np.interp(t - d, t, x)


def _resample(x: np.ndarray, ratio: Fraction) -> np.ndarray:
    """Anti-alias filtered and resampled by ``ratio``, each column of ``x`` (samples x columns)."""
    return resample_poly(x, ratio.numerator, ratio.denominator, axis=0, padtype="line")


def record(df, extra, profile: InstrumentProfile, dt_s: float, rng: np.random.Generator) -> pd.DataFrame:
    """What the instrumentation records of a flight.

    Parameters
    ----------
    df : DataFrame or dict of str to ndarray
        The flight at JSBSim's rate: the log columns (true values), plus any test-only
        ``truth_`` columns (resampled, never corrupted).
    extra : DataFrame or dict of str to ndarray, or None
        True body angular accelerations ``pdot_rps2``, ``qdot_rps2``, ``rdot_rps2`` [rad/s^2]
        (for accelerometers off the CG).
    profile : InstrumentProfile
    dt_s : float
        JSBSim's time step [s].
    rng : numpy.random.Generator
        Seeded: the same seed gives the same log, bit for bit.

    Returns
    -------
    DataFrame
        At the logging rate, the omitted channels dropped.
    """
    out = {c: np.asarray(df[c]) for c in df}  # one frame is built at the end
    for c, s in profile.sensors:
        if c not in out:
            continue
        x = _at_position(df, extra, c, s.position_ft) if any(s.position_ft) else out[c].astype(float)
        if c == "tas_kt" and any(s.position_ft):  # the same pitot feeds the other airspeeds
            ratio = x / np.asarray(df["tas_kt"])
            for other in ("ias_kt", "mach"):
                out[other] = out[other] * ratio
        if s.lag_s:
            x = _lag(x, s.lag_s, dt_s)
        if s.delay_s:
            x = _delay(x, s.delay_s, dt_s)
        out[c] = s.scale * x + s.bias
    if profile.rate_hz and abs(profile.rate_hz * dt_s - 1.0) > 1e-9:
        ratio = Fraction(profile.rate_hz * dt_s).limit_denominator(1000)
        n = int(np.floor((len(out["t_s"]) - 1) * ratio)) + 1
        t_new = np.arange(n) / profile.rate_hz
        t_old = out["t_s"].astype(float)
        filtered = [c for c in out if c not in SAMPLED and c != "t_s"]
        together = _resample(np.column_stack([out[c] for c in filtered]).astype(float), ratio)[:n]  # one design
        out = {
            c: t_new if c == "t_s" else np.interp(t_new, t_old, x.astype(float)) if c in SAMPLED else x
            for c, x in {**out, **dict(zip(filtered, together.T))}.items()
        }
    for c in sorted(c for c, s in profile.sensors if s.noise and c in out):
        out[c] = out[c] + rng.normal(0.0, profile.sensor(c).noise, len(out[c]))
    return pd.DataFrame({c: x for c, x in out.items() if c not in profile.omit})
