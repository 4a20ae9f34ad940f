"""What the data compatibility found, and the correction of a log for it: the instrument
errors with their standard errors (:class:`CompatResult`) and the sensor positions moved to the CG."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from identify.compat.config import CompatSettings
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
#: Of a confounded pair these go first: an attitude bias does not enter eq. (1), the accelerometer
#: bias it trades with does, and the aerodynamic residuals can then choose between them.
PRUNE_FIRST = ("theta_deg.bias", "phi_deg.bias")
#: Knot spacing of each log's gust [s]: Dryden turbulence has most of its power below V / (2 pi L),
#: about 0.04 Hz at 1750 ft scale length; a 2-3-1-1 excites 0.15-1 Hz.
GUST_KNOT_S = 3.0
#: How the reconstruction says an airspeed error needs a turn.
NEEDS_TURN = "a steady wind along the track takes it"
#: Smallest prior standard deviation of the gusts' spline coefficients [ft/s] (still air still
#: leaves the kinematic model's own mismatch, about 0.1 ft/s).
GUST_PRIOR_FLOOR_FPS = 0.3
#: Time blocks whose residuals are taken as correlated within, independent between [s], for the
#: standard errors when a turn pins the airspeed errors: several of Dryden's correlation times.
BLOCK_S = 15.0
#: Dryden's longitudinal scale length above 2,000 ft (MIL-F-8785C) [ft]: the correlation time of the
#: gusts is this over the airspeed.
DRYDEN_LENGTH_FT = 1750.0


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
    se_one_step: float = float("nan")  # the one-step jackknife's, where the whole estimate's is larger
    settings: CompatSettings = field(default=CompatSettings(), repr=False)  # what decides correctable, applied

    @property
    def name(self) -> str:
        return f"{self.channel}.{self.error}"

    @property
    def z(self) -> float:
        return abs(self.estimate) / self.se if self.se > 0 else float("inf") if self.estimate else 0.0

    @property
    def correctable(self) -> bool:
        """At least :attr:`settings`' ``candidate_z`` standard errors (or measured by the kinematics and
        refined by the aerodynamic residuals), at least what ``matters`` for its unit, and ``plausible``."""
        s = self.settings
        return bool(
            self.identifiable
            and (self.z >= s.candidate_z or {"kinematics", "residuals"} <= set(self.sources))
            and s.matters[self.unit] <= abs(self.estimate) <= s.plausible[self.unit]
        )

    @property
    def applied(self) -> bool:
        """The data are corrected for it: correctable, at least :attr:`settings`' ``apply_z`` standard
        errors and not confounded, or chosen by other evidence (the aerodynamic residuals)."""
        return self.correctable and (bool(self.chosen) or (not self.reason and self.z >= self.settings.apply_z))

    def to_dict(self) -> dict:
        ok = bool(self.identifiable)
        return {
            "channel": self.channel,
            "error": self.error,
            "unit": self.unit,
            "estimate": float(self.estimate) if ok else None,
            "se": float(self.se) if ok else None,
            "z": float(self.z) if ok else None,
            "identifiable": ok,
            "reason": self.reason,
            "applied": bool(self.applied),
            "confounded_with": self.confounded_with or None,
            "chosen_because": self.chosen or None,
            "se_one_step": float(self.se_one_step) if ok and np.isfinite(self.se_one_step) else None,
            "methods": {k: {"estimate": float(e), "se": float(se)} for k, (e, se) in self.sources.items()},
        }


def instrument_parameters(settings: CompatSettings | None = None) -> list[Parameter]:
    """Every instrument error the data compatibility knows, at 0, judged by ``settings`` (None: the defaults)."""
    p = [("p_dps", "bias", "deg/s"), ("q_dps", "bias", "deg/s"), ("r_dps", "bias", "deg/s")]
    p += [(c, e, u) for c in ("theta_deg", "phi_deg") for e, u in (("scale", "-"), ("delay", "s"))]
    p += [(c, "bias", "ft/s^2") for c in ("ax_fps2", "ay_fps2", "az_fps2")]
    p += [(c, "bias", "deg") for c in ("theta_deg", "phi_deg")]
    for c, unit in (("alpha_deg", "deg"), ("beta_deg", "deg"), ("tas_kt", "kt")):
        p += [(c, "bias", unit), (c, "scale", "-"), (c, "delay", "s")]
    p.append(("alpha_deg", "position", "ft"))  # the air-data head's distance ahead of the CG
    kw = {} if settings is None else {"settings": settings}
    return [Parameter(c, e, u, **kw) for c, e, u in p]


@dataclass
class CompatResult:
    """What the data compatibility found.

    Attributes
    ----------
    parameters : list of Parameter
    logs : list of str
        The logs reconstructed.
    segments : int
        One log cut into this many segments, the jackknife's clusters
        (:attr:`~identify.compat.config.CompatSettings.one_log_segment_s`); 0: the logs themselves.
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
    segments: int = 0
    #: channels the reconstruction does not use, and why (an attitude that jumps: :func:`attitude_jumps`)
    unused: dict = field(default_factory=dict)

    def uncertainty(self, plausible_at: float | None = None) -> tuple[list[tuple[str, str]], np.ndarray]:
        """The identifiable biases, scale factors and time shifts, (channel, error), and the
        covariance of their estimates: how wrong the corrected data may still be. Every other error
        applied counts too, with its standard error (alone): one the aerodynamic residuals timed or
        refined (an alpha vane's 77-ms delay, timed 5 ms long (2 standard errors) in turbulence, left a
        "CL vs qhat" that was named on the stock 737 with nothing else hidden; a 4 % vane scale refined
        to 3.8 % left a "CL vs alpha"), and one the residuals chose over the partner the kinematics
        cannot tell it from (a 6.3 % vane scale corrected as 7.0 +- 0.8 % left a "CL vs alpha" with
        nothing hidden, and the reach gave the scale's error no share of it).

        With ``plausible_at``, no error is taken as larger than plausible (its parameter's
        ``settings.plausible``): a
        standard error that would put the plausible bound nearer than ``plausible_at`` standard errors
        is shrunk to it, its correlations kept. The kinematics hardly measure a sideslip vane's bias in
        longitudinal manoeuvres (+- 10 deg): within 2 of those, a -19 deg bias, through the wind axes,
        made all of a 5.9-times-its-floor drag onset with flap, and nothing was named.
        """
        names, blocks = [], []
        ok = {p.name for p in self.parameters if p.identifiable and "residuals" not in p.sources}
        for ns, cov in self.covariance:
            keep = [j for j, n in enumerate(ns) if n.split(".")[1] in ("bias", "scale", "delay") and n in ok]
            names += [tuple(ns[j].split(".")) for j in keep]
            blocks.append(cov[np.ix_(keep, keep)])
        timed = [
            p
            for p in self.parameters
            if p.applied
            and p.se > 0
            and p.name.split(".")[1] in ("bias", "scale", "delay")
            and tuple(p.name.split(".")) not in names
        ]
        total = np.zeros((len(names) + len(timed), len(names) + len(timed)))
        i = 0
        for b in blocks:
            total[i : i + len(b), i : i + len(b)] = b
            i += len(b)
        for p in timed:
            total[i, i] = p.se**2
            i += 1
        names = names + [tuple(p.name.split(".")) for p in timed]
        if plausible_at is not None and len(names):
            se = np.sqrt(np.diag(total))
            cap = np.array([_plausible(self.get(".".join(n))) / plausible_at for n in names])
            shrink = np.where(se > cap, cap / np.where(se > 0, se, 1.0), 1.0)
            total = total * np.outer(shrink, shrink)
        return names, total

    def choose(self, name: str, why: str, beside_aero: bool = False) -> CompatResult:
        """The same result with a confounded parameter applied (its partner held at 0), and why."""
        return replace(
            self,
            parameters=[
                replace(p, chosen=why, beside_aero=beside_aero) if p.name == name else p for p in self.parameters
            ],
        )

    def note(self, name: str, text: str) -> CompatResult:
        """The same result with a note added to one parameter's reason."""
        return replace(
            self,
            parameters=[replace(p, reason=f"{p.reason}; {text}") if p.name == name else p for p in self.parameters],
        )

    @property
    def undecided(self) -> list[Parameter]:
        """Correctable parameters held back: confounded with a partner the kinematics cannot tell
        them from, or short of their ``settings.apply_z`` standard errors. Other evidence may choose them."""
        return [p for p in self.parameters if p.correctable and not p.applied and (p.confounded_with or not p.reason)]

    def without(self, name: str) -> CompatResult:
        """The same result with one parameter's correction not applied."""
        params = [replace(p, identifiable=False, reason="undone") if p.name == name else p for p in self.parameters]
        return replace(self, parameters=params)

    @property
    def unmeasured(self) -> list[tuple[str, str]]:
        """Air-data errors the manoeuvres could have shown but the conditions hid (turbulence), and
        the airspeed's scale that only a turn can tell from a steady wind."""
        return [
            (p.channel, p.error)
            for p in self.parameters
            if not p.identifiable
            and (
                (p.reason.startswith("turbulence") and p.channel == "alpha_deg")
                or (p.name == "tas_kt.scale" and p.reason.startswith(NEEDS_TURN))
            )
        ]

    def get(self, name: str) -> Parameter:
        return next(p for p in self.parameters if p.name == name)

    def left_in_logs(self, names: list[tuple[str, str]]) -> np.ndarray:
        """Each (channel, error)'s error the logs as corrected still hold, as measured: the estimate of
        one not applied (if plausible), 0 for one applied. The errors within the reach are centred
        there: a +0.265 deg vane bias measured as +0.257 +- 0.10 deg (2.5 standard errors, too few to
        apply) stays in the logs, and its drag, which the reach centred at 0 put 2.6 standard errors
        away, was named "CD vs alpha, mach" on a stock-737 null."""
        out = []
        for channel, error in names:
            p = self.get(f"{channel}.{error}")
            ok = not p.applied and p.estimate is not None and np.isfinite(p.estimate)
            out.append(float(p.estimate) if ok and abs(p.estimate) <= _plausible(p) else 0.0)
        return np.array(out)

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
        return {
            "parameters": [p.to_dict() for p in self.parameters],
            "logs": [Path(p).name for p in self.logs],
            "residual_rms": self.residual_rms,
            "documented_positions_ft": self.positions,
            "vertical_gust_rms_fps": self.turbulence_fps,
            "segments": self.segments,
            "unused_channels": dict(self.unused),
        }

    def table(self) -> pd.DataFrame:
        return pd.DataFrame([p.to_dict() for p in self.parameters])

    def summary(self) -> str:
        of = (
            f"1 log cut into {self.segments} segments, the standard errors' clusters; its air-data and "
            "accelerometer errors are not estimated"
            if self.segments
            else f"{len(self.logs)} logs"
        )
        lines = [f"Data compatibility (flight-path reconstruction of {of}):"]
        for c, r in self.positions.items():
            lines.append(f"  {c} sensor documented at {r} ft from the CG: corrected for")
        for c, why in self.unused.items():
            lines.append(f"  {c} not used: {why}")
        why = {p.reason for p in self.parameters if not p.identifiable}
        none = len(why) == 1 and not any(p.identifiable for p in self.parameters)  # one reason for all
        if none:
            lines.append(f"  {'every error':<22} not identifiable ({next(iter(why))})")
        for p in self.parameters:
            if not p.identifiable:
                if none:
                    continue
                lines.append(f"  {p.name:<22} not identifiable ({p.reason})")
                continue
            mark = (
                "  applied" + (f" ({p.chosen})" if p.chosen else "")
                if p.applied
                else f"  {p.reason}"
                if p.reason
                else "  implausible, not applied"
                if abs(p.estimate) > _plausible(p)
                else ""
            )
            how = "; ".join(f"{k} {e:+.4g} +- {se:.2g}" for k, (e, se) in p.sources.items())
            whole = (
                f"  [each log left out, the whole estimate again; one-step jackknife +- {p.se_one_step:.2g}]"
                if np.isfinite(p.se_one_step)
                else ""
            )
            lines.append(
                f"  {p.name:<22} {p.estimate:+11.5g} +- {p.se:.3g} {p.unit:<7} (z {p.z:5.1f}){mark}"
                + (f"  [{how}]" if how else "")
                + whole
            )
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
        meta = {**log.meta, "corrections": {p.name: p.estimate for p in self.applied}, "positions_corrected": positions}
        return replace(log, data=pd.DataFrame(d, index=log.data.index), meta=meta)


def _plausible(p: Parameter) -> float:
    """The largest plausible error of ``p``'s unit (its settings')."""
    return p.settings.plausible[p.unit]


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


def at_cg(
    d: dict[str, np.ndarray], positions: dict, accelerometers_only: bool = False, air_data_only: bool = False
) -> dict[str, np.ndarray]:
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
    uw = np.sqrt(np.maximum(v**2 - vs**2, 1.0))
    a = av.copy()
    for _ in range(4):  # the vane reads atan((w - q x) / u) with u, w of the CG
        u = uw * np.cos(a)
        a = np.arctan2(u * np.tan(av) + q * x_ft, u)
    beta = np.arcsin(np.clip(vb / v, -1.0, 1.0)) if "beta_deg" in d else np.zeros(len(v))
    return a / D2R, beta / D2R
