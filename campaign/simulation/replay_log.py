"""Replays of measured logs: the recorded surfaces, the measured thrust and the measured wind flown open loop
on an aircraft, from a start estimated from the log.

What is flown
    The elevator and stabilizer as offsets from their values at the start, the gear command where the
    logged gear moves, and the thrust: the aircraft's own trim thrust plus the measured thrust's change
    from the start, along body x on the thrust line. An aircraft with engines keeps them at their trim
    throttle and gets a force ``external_reactions/replay-thrust/magnitude`` (added to a private copy of
    its XML at the engines' mean thrust line) that makes engines plus force equal that thrust at every
    step; an aircraft written by ``campaign model`` has no engine, and its force
    ``external_reactions/thrust/magnitude`` is set to it. No throttle channel is read: measured data
    carry thrust, and a throttle played open loop through an engine's spool dynamics does not give the
    thrust that was measured.

Where it starts (:func:`estimate_start`)
    The log's first seconds before the inputs move (:func:`diagnose.windows.quiet_head_s`: until the gear moves, else until
    the elevator or the stabilizer steps): altitude, airspeed and Mach at the first sample from
    quadratic least-squares fits over the first second, the flight-path angle from the inertial
    velocity (else from the altitude's slope), the wind at the first sample from the measured wind
    (low-passed), and each control's and the thrust's reference (mean) and spread (standard deviation)
    over the quiet head. The aircraft is trimmed there, in that wind: its own trim angle of attack,
    pitch control and thrust, on the branch of its lift curve the measured angle of attack is on
    (:data:`TRIM_BRANCH_DEG`). An aircraft written by ``campaign model`` is trimmed in the flight the log
    starts in: pitching at the rate of the pitch attitude and with the airspeed changing at the rate the
    quiet head shows (``theta_rate_dps``, ``accel_fps2``): a record cut from a flight starts wherever the
    aeroplane was, a phugoid in progress among them, and its controls and thrust there are that flight's,
    not a steady one's. An aircraft with engines is trimmed by JSBSim's trim in steady flight.

What the controls are (:func:`fly_log`)
    The measured positions and thrust as they are, unless the aircraft's trim differs from the
    measured reference by more than :data:`OFFSET_SPREADS` times its spread (the thrust's, in a measured
    wind, at least :data:`THRUST_SPREAD_GUSTS` times the weight times the gusts' angle): then by that difference,
    an offset per log and control (reported), so that a model whose trim is off by more than the data
    can tell flies its trim plus the measured changes and shows the trim error in the trim comparison
    rather than as a drift of every time history. A hold that is moving the controls from the first
    sample (a closed-loop gear transition) has a wide spread: its controls fly as measured.

Limits: a log with no quiet head gets its references from its first half second; on an aircraft with
engines, a log that does not start in steady flight (a turn, an accelerating climb, a phugoid in progress)
is trimmed in the steady flight nearest to it, and its start says how far it was from it; a turn is
trimmed wings level on every aircraft;
the wind at the first sample carries the vanes' noise (about 0.5 ft/s at 3 ft/s turbulence on our
flight-test profile), which the trim turns into a thrust and an angle-of-attack error; a steady error of
the air data is flown as a steady wind.
"""

from __future__ import annotations

import array
import math
import shutil
import threading
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from multiprocessing.util import Finalize
from pathlib import Path

import numpy as np
import pandas as pd

from campaign.simulation.aircraft import AircraftSource
from campaign.simulation.catalog import GUSTS, R2D
from campaign.simulation.matrix import StatusPoint
from diagnose.windows import STATE_FIT_S, noise_level, quiet_head_s
from infra.pool import owned_tmpdir

G0 = 32.174049
FT_PER_KT = 1.6878098571011957
#: The force added to an aircraft with engines, and the one ``campaign model`` writes.
ADDED_FORCE, MODEL_FORCE = "replay-thrust", "thrust"
#: A control's trim is taken as differing from the measured reference beyond this many spreads.
OFFSET_SPREADS = 3.0
#: The thrust's spread is at least this many times the weight times the gusts' angle (the measured vertical
#: wind's standard deviation over the quiet head, over the airspeed): a log that starts in turbulence is out of
#: steady flight, its flight-path angle uncertain by about the gusts' angle, and the trim thrust of a model that
#: is the aeroplane lands up to a few times the weight times that from the measured thrust. The head, not the
#: whole log: the wind reconstructed through a manoeuvre carries the air data's errors (2.4 ft/s in still air
#: through a 737 doublet, uncorrected). Calibrated on our 737 flown by itself through the flight-test profile at
#: 1.5 and 3 ft/s (seeds 21-26, 512 held-out logs): the trim thrust differed from the measured by at most 3.41
#: times the weight times the gusts' angle (0.70 % of the weight), and an offset of that size flown as a trim
#: error drifted a perfect model's replay by up to 91 ft; 3 spreads of 1.2 cover it.
THRUST_SPREAD_GUSTS = 1.2
#: A trim whose angle of attack is further than this from the measured one at the log's start [deg] is on another
#: branch of the aircraft's lift curve (JSBSim's trim in a gust can land past the stall, where the lift is the
#: same): the trim is tried again with its alpha bracket ending this far above the measured alpha.
TRIM_BRANCH_DEG = 5.0
#: A replay that leaves these bounds has diverged [deg].
ENVELOPE = {"alpha_deg": (-20.0, 30.0), "theta_deg": (-45.0, 60.0)}


class ReplayError(RuntimeError):
    """A replay that cannot be flown; the message says why."""


@dataclass(frozen=True)
class Start:
    """What a replay starts from, estimated from the log (:func:`estimate_start`).

    Attributes
    ----------
    alt_ft, tas_kt, mach, gamma_deg : float
        Altitude, true airspeed, Mach and flight-path angle (inertial) at the first sample.
    alpha_deg : float
        The logged angle of attack there (a first guess for a trim).
    flap_deg, gear_norm, weight_lb : float
    elevator_deg, stabilizer_deg, thrust_lbf : float
        The references the recorded inputs are taken from (means over the quiet head).
    spread : tuple
        Their standard deviations over the quiet head (noise and any hold's activity), at least
        their noise levels.
    wind_fps : tuple
        North, east, down wind at the first sample [ft/s].
    head_s : float
        The quiet head the references were averaged over [s].
    accel_fps2, theta_rate_dps : float
        How far the aeroplane is from steady flight: the rates of change of the airspeed [ft/s^2] and of
        the pitch attitude [deg/s] (least-squares slopes over the quiet head, at least its first
        ``STATE_FIT_S``; the attitude's, not the gyro's, which a bias would move); 0 and 0 in steady flight.
    """

    alt_ft: float
    tas_kt: float
    mach: float
    gamma_deg: float
    alpha_deg: float
    flap_deg: float
    gear_norm: float
    weight_lb: float
    elevator_deg: float
    stabilizer_deg: float
    thrust_lbf: float
    spread: tuple[float, float, float]
    wind_fps: tuple[float, float, float]
    head_s: float
    accel_fps2: float = 0.0
    theta_rate_dps: float = 0.0

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else float(v)) for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Inputs:
    """The recorded inputs of a log, at its own rate (resampled onto the simulation's step when flown).

    Attributes
    ----------
    dt_s : float
    elevator_deg, stabilizer_deg, thrust_lbf : tuple of float
        Offsets from the :class:`Start` references [deg, deg, lbf].
    gear_cmd : tuple of float
        Gear command per sample [-].
    wind_fps : tuple of tuple, optional
        North, east, down wind per sample [ft/s]; None: still air.
    """

    dt_s: float
    elevator_deg: tuple
    stabilizer_deg: tuple
    thrust_lbf: tuple
    gear_cmd: tuple
    wind_fps: tuple | None = None


def _at_start(t: np.ndarray, x: np.ndarray, span_s: float, degree: int = 2) -> float:
    """The value at ``t = 0`` of a least-squares polynomial through the samples of the first ``span_s``."""
    k = t <= span_s
    if k.sum() <= degree + 2:
        return float(np.mean(x[k])) if k.any() else float(x[0])
    return float(np.polyval(np.polyfit(t[k], x[k], degree), 0.0))


def _slope(t: np.ndarray, x: np.ndarray) -> float:
    """The least-squares slope of ``x`` over ``t`` (0 with fewer than three samples)."""
    return float(np.polyfit(t, x, 1)[0]) if len(t) >= 3 else 0.0


def estimate_start(data: pd.DataFrame, wind: np.ndarray | None = None) -> Start:
    """Where a replay of ``data`` starts (see the module notes).

    Parameters
    ----------
    data : DataFrame
        The log (schema columns; ``stabilizer_deg`` 0 and ``thrust_lbf`` 0 where absent).
    wind : ndarray, optional
        The measured wind, north, east, down per sample [ft/s] (:func:`campaign.diagnosis.run.log_wind`).
    """
    t = data["t_s"].to_numpy(dtype=float) - float(data["t_s"].iloc[0])
    head = quiet_head_s(data)
    quiet = t <= head

    def col(name: str, default: float = 0.0) -> np.ndarray:
        return data[name].to_numpy(dtype=float) if name in data else np.full(len(t), default)

    alt = _at_start(t, col("alt_ft"), STATE_FIT_S)
    tas = _at_start(t, col("tas_kt"), STATE_FIT_S)
    mach = _at_start(t, col("mach"), STATE_FIT_S) if "mach" in data else float("nan")
    if {"vn_fps", "ve_fps", "vd_fps"} <= set(data.columns):
        ground = np.hypot(col("vn_fps"), col("ve_fps"))
        gamma = np.degrees(np.arctan2(-_at_start(t, col("vd_fps"), head, 1), _at_start(t, ground, head, 1)))
    else:  # the altitude's slope over the quiet head
        k = quiet if quiet.sum() > 3 else slice(None)
        climb = float(np.polyfit(t[k], col("alt_ft")[k], 1)[0])
        gamma = float(np.degrees(np.arcsin(np.clip(climb / max(tas * FT_PER_KT, 1.0), -1.0, 1.0))))
    w0 = (0.0, 0.0, 0.0) if wind is None else tuple(float(v) for v in np.asarray(wind, dtype=float)[0])
    mass = col("mass_slug")
    refs = [col(c)[quiet] for c in ("elevator_deg", "stabilizer_deg", "thrust_lbf")]
    weight = float(np.mean(mass[quiet])) * G0
    calm = t <= max(head, STATE_FIT_S)
    gusts = 0.0 if wind is None else float(np.std(np.asarray(wind, dtype=float)[calm, 2])) / max(tas * FT_PER_KT, 1.0)
    spread = tuple(
        max(float(np.std(r)), noise_level(col(c)), THRUST_SPREAD_GUSTS * weight * gusts if c == "thrust_lbf" else 0.0)
        for r, c in zip(refs, ("elevator_deg", "stabilizer_deg", "thrust_lbf"))
    )
    return Start(
        alt,
        tas,
        mach,
        float(gamma),
        float(np.mean(col("alpha_deg")[t <= STATE_FIT_S])),
        round(float(np.mean(col("flap_deg")[quiet])), 3),
        float(round(float(col("gear_norm")[0]))),
        weight,
        *(float(np.mean(r)) for r in refs),
        spread,
        w0,
        head,
        _slope(t[calm], col("tas_kt")[calm] * FT_PER_KT),
        _slope(t[calm], col("theta_deg")[calm]),
    )


def measured_inputs(data: pd.DataFrame, start: Start, wind: np.ndarray | None = None) -> Inputs:
    """The log's inputs as offsets from ``start``'s references, the gear command, and the wind."""
    g = data["gear_norm"].to_numpy(dtype=float)
    g0 = round(float(g[0]))
    moving = np.flatnonzero(np.abs(g - g0) > 1e-6)
    gear_cmd = np.full(len(g), float(g0))
    if moving.size:  # the command set before step k moves the gear in row k
        gear_cmd[moving[0] :] = round(float(g[-1]))

    def offsets(name: str, ref: float) -> tuple:
        return tuple(data[name].to_numpy(dtype=float) - ref) if name in data else (0.0,) * len(g)

    return Inputs(
        float(np.median(np.diff(data["t_s"].to_numpy(dtype=float)))),
        offsets("elevator_deg", start.elevator_deg),
        offsets("stabilizer_deg", start.stabilizer_deg),
        offsets("thrust_lbf", start.thrust_lbf),
        tuple(gear_cmd),
        None if wind is None else tuple(map(tuple, np.asarray(wind, dtype=float))),
    )


# ---- the aircraft: engines or a thrust force ------------------------------------------------------------

_TO_IN = {"IN": 1.0, "FT": 12.0, "M": 39.37007874015748, "CM": 0.3937007874015748, "MM": 0.03937007874015748}
_SOURCES: dict[AircraftSource, tuple[str, AircraftSource]] = {}
_LOCK = threading.Lock()


def _inches(loc) -> list[float]:
    scale = _TO_IN.get((loc.get("unit") or "IN").upper(), 1.0)
    return [float(loc.find(a).text) * scale if loc.find(a) is not None else 0.0 for a in "xyz"]


def thrust_kind(source: AircraftSource) -> str:
    """``engines`` (an aircraft with engines), ``force`` (one whose thrust is the external force
    ``thrust``, as ``campaign model`` writes); :class:`ReplayError` for neither."""
    root = ET.parse(Path(source.folder) / f"{source.name}.xml").getroot()
    if root.find("propulsion/engine") is not None:
        return "engines"
    if any(f.get("name") == MODEL_FORCE for f in root.findall("external_reactions/force")):
        return "force"
    raise ReplayError(
        f"aircraft {source.name} has no engine and no external force '{MODEL_FORCE}': nothing "
        "to fly the measured thrust with"
    )


def flying_source(source: AircraftSource) -> tuple[str, AircraftSource]:
    """The aircraft a replay flies: ``("force", source)`` for one with a thrust force, or ``("engines",
    copy)`` with the force :data:`ADDED_FORCE` added along body x at its thrusters' mean location (a
    private copy, kept for the process)."""
    with _LOCK:
        if source in _SOURCES:
            return _SOURCES[source]
        kind = thrust_kind(source)
        if kind == "force":
            out = (kind, source)
        else:
            folder = owned_tmpdir("replay-aircraft")
            Finalize(None, shutil.rmtree, args=(folder,), kwargs={"ignore_errors": True}, exitpriority=0)
            dest = folder / source.name
            shutil.copytree(source.folder, dest, ignore=shutil.ignore_patterns("effects", "__pycache__"))
            xml = dest / f"{source.name}.xml"
            tree = ET.parse(xml)
            root = tree.getroot()
            locs = [_inches(loc) for loc in root.findall("propulsion/engine/thruster/location")]
            if not locs:
                locs = [_inches(loc) for loc in root.findall("mass_balance/location")] or [[0.0, 0.0, 0.0]]
            x, _, z = np.mean(locs, axis=0)
            ext = root.find("external_reactions")
            if ext is None:
                ext = ET.SubElement(root, "external_reactions")
            force = ET.SubElement(ext, "force", name=ADDED_FORCE, frame="BODY")
            loc = ET.SubElement(force, "location", unit="IN")
            for a, v in zip("xyz", (x, 0.0, z)):
                ET.SubElement(loc, a).text = repr(float(v))
            direction = ET.SubElement(force, "direction")
            for a, v in zip("xyz", (1.0, 0.0, 0.0)):
                ET.SubElement(direction, a).text = repr(v)
            tree.write(xml, encoding="unicode", xml_declaration=True)
            out = (kind, AircraftSource(str(dest), source.effects))
        _SOURCES[source] = out
        return out


# ---- flying ----------------------------------------------------------------------------------------------

#: Log column -> (JSBSim property, scale) of what a replay records.
RECORDED = {
    "alt_ft": ("atmosphere/pressure-altitude", 1.0),
    "tas_kt": ("velocities/vtrue-kts", 1.0),
    "mach": ("velocities/mach", 1.0),
    "alpha_deg": ("aero/alpha-deg", 1.0),
    "beta_deg": ("aero/beta-deg", 1.0),
    "theta_deg": ("attitude/theta-deg", 1.0),
    "phi_deg": ("attitude/phi-deg", 1.0),
    "psi_deg": ("attitude/psi-deg", 1.0),
    "p_dps": ("velocities/pi-rad_sec", R2D),
    "q_dps": ("velocities/qi-rad_sec", R2D),
    "r_dps": ("velocities/ri-rad_sec", R2D),
    "elevator_deg": ("fcs/elevator-pos-rad", R2D),
    "gear_norm": ("gear/gear-pos-norm", 1.0),
    "flap_deg": ("fcs/flap-pos-deg", 1.0),
    "vn_fps": ("velocities/v-north-fps", 1.0),
    "ve_fps": ("velocities/v-east-fps", 1.0),
    "vd_fps": ("velocities/v-down-fps", 1.0),
    "mass_slug": ("inertia/mass-slugs", 1.0),
}
STABILIZER = "fcs/stabilizer-pos-deg"


def _on_step(inputs: Inputs, dt: float) -> tuple[np.ndarray, ...]:
    """The inputs resampled onto the simulation's step (linear; the gear command held)."""
    t_rec = np.arange(len(inputs.elevator_deg)) * inputs.dt_s
    t_sim = np.arange(int(round(t_rec[-1] / dt)) + 1) * dt
    held = np.searchsorted(t_rec, t_sim + 1e-9 * dt, side="right") - 1
    out = [
        np.interp(t_sim, t_rec, np.asarray(s, dtype=float))
        for s in (inputs.elevator_deg, inputs.stabilizer_deg, inputs.thrust_lbf)
    ]
    out.append(np.asarray(inputs.gear_cmd, dtype=float)[held])
    w = (
        np.zeros((len(t_sim), 3))
        if inputs.wind_fps is None
        else np.column_stack([np.interp(t_sim, t_rec, c) for c in np.asarray(inputs.wind_fps, dtype=float).T])
    )
    return (*out, w)


def _model_pitch_control(source: AircraftSource) -> str:
    """The surface a ``campaign model`` aircraft trims with (its ``model.json``), else the elevator."""
    import json

    try:
        trims = json.loads((Path(source.folder) / "model.json").read_text()).get("trims", [])
        return next(t["pitch_control"] for t in trims if "pitch_control" in t)
    except (OSError, ValueError, StopIteration, AttributeError):
        return "elevator"


def fly_log(source: AircraftSource, start: Start, inputs: Inputs) -> pd.DataFrame:
    """Fly the recorded inputs on ``source`` from ``start``.

    Returns
    -------
    DataFrame
        :data:`RECORDED` channels plus ``stabilizer_deg`` and ``thrust_lbf`` (engines plus force) and
        ``t_s``, at the simulation's step; ``attrs["trim"]`` the aircraft's trim elevator, stabilizer
        [deg] and thrust [lbf] at the start, ``attrs["offsets"]`` the offsets flown (0: as measured).

    Raises
    ------
    ReplayError
        If the aircraft cannot trim at the start, or the replay diverges (the reason in the message).
    """
    from campaign.errors import UserError
    from campaign.simulation.engine import DT_S, TrimError, elevator_gain_deg, new_fdm, stabilizer_gain_deg

    kind, src = flying_source(source)
    de, dh, dthrust, gear, wind = _on_step(inputs, DT_S)
    try:
        if kind == "engines":
            fdm, tr = _trim_engines(src, start)
            de_gain, dh_gain = elevator_gain_deg(src), stabilizer_gain_deg(src)
            e0, h0 = tr.elevator_cmd_norm, tr.pitch_trim_norm
            force_prop = f"external_reactions/{ADDED_FORCE}/magnitude"
            trim_deg = (tr.elevator_deg, tr.pitch_trim_norm * dh_gain if dh_gain else start.stabilizer_deg)
        else:
            fdm, de_gain, dh_gain, e0, h0 = _trim_force_aircraft(src, start, new_fdm)
            force_prop = f"external_reactions/{MODEL_FORCE}/magnitude"
            trim_deg = (fdm["fcs/elevator-pos-rad"] * R2D, fdm[STABILIZER])
    except (TrimError, UserError) as exc:
        raise ReplayError(f"no trim at the log's start ({start.alt_ft:.0f} ft, {start.tas_kt:.1f} kt): {exc}") from None
    pm = fdm.get_property_manager()
    node = lambda p: pm.get_node(p, False)  # noqa: E731
    elev, stab, gcmd, force = (
        node(p) for p in ("fcs/elevator-cmd-norm", "fcs/pitch-trim-cmd-norm", "gear/gear-cmd-norm", force_prop)
    )
    prop = node("forces/fbx-prop-lbs") if kind == "engines" else None
    gusts = [node(p) for p in GUSTS]
    names = list(RECORDED) + (["stabilizer_deg"] if node(STABILIZER) is not None else [])
    reads = [node(p) for p, _ in RECORDED.values()] + ([node(STABILIZER)] if node(STABILIZER) is not None else [])
    scale = np.array([s for _, s in RECORDED.values()] + [1.0] * (len(reads) - len(RECORDED)))
    thrust0 = (prop.get_double_value() if prop is not None else 0.0) + force.get_double_value()
    engines = prop.get_double_value() if prop is not None else 0.0
    trims = (*trim_deg, thrust0)
    refs = (start.elevator_deg, start.stabilizer_deg, start.thrust_lbf)
    offsets = tuple(tm - r if abs(tm - r) > OFFSET_SPREADS * s else 0.0 for tm, r, s in zip(trims, refs, start.spread))
    # the trimmed commands take the trim's surfaces: the measured ones differ by (reference + offset - trim)
    shift = [r + o - tm for tm, r, o in zip(trims, refs, offsets)]
    de, dh, dthrust = de + shift[0], dh + shift[1], dthrust + shift[2]
    n = len(de)
    # each step's commands as Python floats, computed as the loop would: indexing a list and Python float
    # arithmetic cost a fraction of numpy scalars'
    elev_cmd = (e0 + de / de_gain).tolist()
    stab_cmd = (h0 + dh / dh_gain).tolist() if dh_gain else None
    gear_cmd, winds, targets = gear.tolist(), wind.tolist(), (thrust0 + dthrust).tolist()
    # still air: the gusts stay at the trim's 0; a gear command is set when it changes
    still = inputs.wind_fps is None and all(g.get_double_value() == 0.0 for g in gusts)
    sets = [] if still else [(g.set_double_value, i) for i, g in enumerate(gusts)]
    get = type(reads[0]).get_double_value
    width = len(reads)
    rows, thrust = array.array("d"), array.array("d")
    i_alpha, i_theta = names.index("alpha_deg"), names.index("theta_deg")
    (a_lo, a_hi), (th_lo, th_hi) = ENVELOPE["alpha_deg"], ENVELOPE["theta_deg"]
    prop_get = prop.get_double_value if prop is not None else None
    set_elev, set_gear, set_force, force_get = (
        elev.set_double_value,
        gcmd.set_double_value,
        force.set_double_value,
        force.get_double_value,
    )
    set_stab, run = (stab.set_double_value if stab_cmd is not None else None), fdm.run
    gear_now = None
    for k in range(n):
        set_elev(elev_cmd[k])
        if stab_cmd is not None:
            set_stab(stab_cmd[k])
        if gear_cmd[k] != gear_now:
            gear_now = gear_cmd[k]
            set_gear(gear_now)
        w = winds[k]
        for put, i in sets:
            put(w[i])
        set_force(targets[k] - engines)
        run()
        rows.extend(map(get, reads))
        if prop_get is not None:
            engines = prop_get()
        thrust.append(engines + force_get())
        a, th = rows[k * width + i_alpha], rows[k * width + i_theta]
        if not (math.isfinite(a) and a_lo < a < a_hi and th_lo < th < th_hi):
            raise ReplayError(f"the replay diverged at t = {k * DT_S:.1f} s (alpha {a:.1f} deg, pitch {th:.1f} deg)")
    rows = np.frombuffer(rows, dtype=float).reshape(n, width)
    thrust = np.frombuffer(thrust, dtype=float)
    out = pd.DataFrame(rows * scale, columns=names)
    if "stabilizer_deg" not in out:
        out["stabilizer_deg"] = 0.0
    out["thrust_lbf"] = thrust
    out["psi_deg"] = np.degrees(np.unwrap(np.radians(out["psi_deg"].to_numpy())))  # no jump through north
    out.insert(0, "t_s", np.arange(n) * DT_S)
    out.attrs["offsets"] = dict(zip(("elevator_deg", "stabilizer_deg", "thrust_lbf"), map(float, offsets)))
    out.attrs["trim"] = dict(zip(("elevator_deg", "stabilizer_deg", "thrust_lbf"), map(float, trims)))
    return out


def _trim_engines(src: AircraftSource, start: Start):
    """An aircraft with engines trimmed at ``start`` in its wind (in the horizontal wind if JSBSim's trim in the
    gust fails), on the branch of its lift curve the measured alpha is on (:data:`TRIM_BRANCH_DEG`); the FDM and
    its trim. :class:`ReplayError` if the only trim found is on another branch."""
    from campaign.simulation.engine import TRIM_ALPHA_MAX_DEG, TrimError, trimmed_fdm

    point = StatusPoint(start.alt_ft, start.mach, start.flap_deg, start.gear_norm == 1.0, start.weight_lb)
    winds = [np.asarray(start.wind_fps) if any(start.wind_fps) else None]
    if start.wind_fps[2]:
        winds.append(np.array([*start.wind_fps[:2], 0.0]))
    measured = start.alpha_deg
    brackets = [TRIM_ALPHA_MAX_DEG] + ([(measured + TRIM_BRANCH_DEG,)] if np.isfinite(measured) else [])
    found, failure = None, None
    for bracket in brackets:
        for wind in winds:
            try:
                fdm, *_, tr = trimmed_fdm(src, point, start.gear_norm, wind, start.gamma_deg, bracket)
            except TrimError as exc:  # JSBSim's trim in a gust fails near its alpha limits: then in the horizontal wind
                failure = failure or exc
                continue
            if not np.isfinite(measured) or abs(tr.alpha_deg - measured) <= TRIM_BRANCH_DEG:
                return fdm, tr
            found = found or tr
            break
    if found is None:
        raise failure
    raise ReplayError(
        f"the aircraft trims at the log's start only at alpha {found.alpha_deg:.1f} deg, "
        f"{found.alpha_deg - measured:+.1f} deg from the measured {measured:.1f} deg: on another branch of its "
        "lift curve"
    )


def _trim_force_aircraft(src: AircraftSource, start: Start, new_fdm):
    """A ``campaign model`` aircraft trimmed at ``start`` (:func:`campaign.modelling.trim.trim_model`), in
    the start's wind; returns the FDM, the surfaces' degrees per unit command and their trim commands."""
    from campaign.errors import UserError
    from campaign.modelling.trim import ModelTrimError, _ranges, trim_model
    from campaign.simulation.engine import TrimError

    fdm = new_fdm(src)
    per_cmd = _ranges(fdm)
    for p, v in zip(GUSTS, start.wind_fps):
        fdm[p] = v
    try:
        trim_model(
            fdm,
            start.alt_ft,
            start.tas_kt,
            start.gamma_deg,
            start.flap_deg,
            start.gear_norm,
            start.elevator_deg,
            start.stabilizer_deg,
            start.thrust_lbf,
            start.alpha_deg,
            start.weight_lb,
            _model_pitch_control(src),
            q_dps=start.theta_rate_dps,
            accel_fps2=start.accel_fps2,
        )
    except (ModelTrimError, UserError) as exc:
        raise TrimError(str(exc)) from None
    return fdm, per_cmd["elevator"], per_cmd["stabilizer"], fdm["fcs/elevator-cmd-norm"], fdm["fcs/pitch-trim-cmd-norm"]
