"""The flying engine: build an FDM, trim at a status point, fly a manoeuvre, log.

Each call builds its own ``FGFDMExec`` (it cannot be pickled, and a failed trim
leaves stale state behind), so the functions here run unchanged in local worker
processes or on a Dask cluster.
"""

from __future__ import annotations

import array
import hashlib
import math
import os
import shutil
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from multiprocessing.util import Finalize
from pathlib import Path

os.environ.setdefault("JSBSIM_DEBUG", "0")

import jsbsim  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from campaign.simulation import catalog as cat  # noqa: E402
from campaign.simulation.aircraft import AircraftSource, prepare, thruster_z_in  # noqa: E402
from campaign.errors import UserError  # noqa: E402
from campaign.simulation.matrix import StatusPoint  # noqa: E402
from campaign.simulation.instruments import InstrumentProfile, load_profile, record  # noqa: E402
from campaign.simulation.turbulence import dryden_gusts  # noqa: E402
from infra.model import ModelLoadError, Schedule, captured_stdout, control_schedules, load_fdm  # noqa: E402
from maneuvers.autopilot import HoldAutopilot, HoldGains, bank_hold  # noqa: E402
from maneuvers.library import GearTransition, Maneuver, make_maneuver  # noqa: E402
from maneuvers.signals import Constant  # noqa: E402

DT_S = 1.0 / 120.0
FT_PER_KT = 1.6878098571011957


class TrimError(RuntimeError):
    """A status point that does not trim; the message is the reason."""


@dataclass(frozen=True)
class FlightConfig:
    """Everything a worker needs to fly a point, picklable.

    Attributes
    ----------
    aircraft : AircraftSource
    seed : int
        Campaign seed; each manoeuvre derives its own from it and its name.
    instruments : InstrumentProfile or str
        How the instrumentation records the flight (:mod:`campaign.simulation.instruments`);
        a shipped profile's name or a profile file is loaded.
    maneuver_params : tuple
        ``((manoeuvre name, ((param, value), ...)), ...)`` from the matrix.
    clmax_by_flap : tuple
        ``((flap_deg, CLmax), ...)`` for the stall-margin scaling.
    record_truth : bool
        Add JSBSim's own forces and moments (test logs only).
    """

    aircraft: AircraftSource
    seed: int = 0
    instruments: InstrumentProfile | str = "none"
    maneuver_params: tuple = ()
    clmax_by_flap: tuple = ()
    record_truth: bool = False
    gains: HoldGains = field(default_factory=HoldGains)

    def __post_init__(self) -> None:
        if isinstance(self.instruments, str):
            object.__setattr__(self, "instruments", load_profile(self.instruments))

    def maneuver(self, name: str) -> Maneuver:
        """The named manoeuvre with the matrix's parameters."""
        return make_maneuver(name, **dict(dict(self.maneuver_params).get(name, ())))


def derived_seed(seed: int, *names: str) -> int:
    """A 32-bit seed derived from the campaign seed and names (stable across runs)."""
    h = hashlib.sha256(("/".join([str(seed), *names])).encode()).digest()
    return int.from_bytes(h[:4], "little") & 0x7FFFFFFF


#: The merged aircraft roots a process keeps on disk, the most recently loaded: a long-lived process
#: (a worker, a benchmark) flies one overlay after another.
ROOTS_KEPT = 8
_ROOTS: OrderedDict[AircraftSource, tuple[str, Finalize]] = OrderedDict()
_ROOTS_LOCK = threading.Lock()  # a Dask worker loads in several threads


#: A point's weight that an aircraft without a point mass already has, within this share of it [-].
WEIGHT_TOLERANCE = 1e-4


def new_fdm(source: AircraftSource):
    """Load the aircraft (with its overlay merged) into a fresh FGFDMExec.

    The merged root (:func:`campaign.simulation.aircraft.prepare`) is written once per source and kept for the
    next load; the oldest of more than :data:`ROOTS_KEPT` is removed (a loaded model no longer reads
    its files), and the rest as the process ends (a worker too runs multiprocessing's finalizers
    before it exits).
    """
    with _ROOTS_LOCK:
        held = _ROOTS.get(source)
        if held is None:
            root = str(prepare(source))
            held = _ROOTS[source] = (
                root,
                Finalize(None, shutil.rmtree, args=(root,), kwargs={"ignore_errors": True}, exitpriority=0),
            )
            while len(_ROOTS) > ROOTS_KEPT:
                _ROOTS.popitem(last=False)[1][1]()  # removes the folder, and its exit finalizer with it
        _ROOTS.move_to_end(source)
        try:
            return load_fdm(Path(held[0]), source.name)
        except ModelLoadError as exc:  # what JSBSim said, of the user's folder rather than its copy
            why = exc.reason.replace(str(exc.folder), source.folder)
            raise UserError(
                f"{source.folder}: JSBSim could not load aircraft {source.name}{': ' + why if why else ''}"
            ) from None


def engine_count(names: set[str]) -> int:
    """The number of engines in a model's property catalog ``names``."""
    n = 0
    while f"propulsion/engine[{n}]/thrust-lbs" in names or (n == 0 and "propulsion/engine/thrust-lbs" in names):
        n += 1
    return max(n, 1)


@lru_cache(maxsize=8)
def model_catalog(source: AircraftSource) -> tuple[cat.PropertyNames, int, dict[str, bool]]:
    """The aircraft's property names, engine count and optional properties present
    (:func:`campaign.simulation.catalog.check_catalog`): the same for every FDM loaded from ``source``.

    Raises
    ------
    UserError
        If a property the engine needs is missing.
    """
    names = cat.catalog_names(new_fdm(source))
    force = thrust_force(source)
    n_eng = 0 if force else engine_count(names)
    return names, n_eng, cat.check_catalog(names, n_eng, source.folder, thrust=force)


#: The throttle at which an aircraft without engines trims: the hold's throttle moves its thrust force
#: from none (0) to twice the trim's (1).
FORCE_TRIM_THROTTLE = 0.5


@lru_cache(maxsize=8)
def thrust_force(source: AircraftSource) -> str | None:
    """The property of the thrust force of an aircraft without engines (``campaign model``'s, its thrust an
    external force), None for an aircraft with engines."""
    from campaign.simulation.replay_log import MODEL_FORCE, ReplayError, thrust_kind  # noqa: PLC0415

    try:
        kind = thrust_kind(source)
    except ReplayError as exc:
        raise UserError(f"{source.folder}: {exc}") from None
    return f"external_reactions/{MODEL_FORCE}/magnitude" if kind == "force" else None


def _force_trim(source: AircraftSource, point: StatusPoint, gear: float, gust_fps, gamma_deg: float):
    """An aircraft without engines trimmed at ``point`` (:func:`campaign.modelling.trim.trim_model`, its
    thrust force for the throttle), in the gust ``gust_fps``: the FDM and its :class:`Trim`."""
    from campaign.modelling.trim import ModelTrimError, trim_model  # noqa: PLC0415
    from campaign.simulation.replay_log import _model_pitch_control  # noqa: PLC0415

    fdm = new_fdm(source)
    fdm["ic/h-sl-ft"], fdm["ic/mach"] = point.alt_ft, point.mach
    with captured_stdout():
        fdm.run_ic()
    tas_kt = float(fdm["velocities/vtrue-kts"])
    for prop, v in zip(cat.GUSTS, gust_fps if gust_fps is not None else (0.0, 0.0, 0.0)):
        fdm[prop] = float(v)
    try:
        mt = trim_model(
            fdm,
            point.alt_ft,
            tas_kt,
            gamma_deg,
            point.flap_deg,
            gear,
            weight_lb=point.weight_lb,
            thrust_lbf=0.1 * float(fdm["inertia/weight-lbs"]),
            pitch_control=_model_pitch_control(source),
        )
    except (ModelTrimError, UserError) as exc:
        raise TrimError(str(exc)) from None
    thrust = float(fdm[thrust_force(source)])
    if not thrust > 0.0:
        raise TrimError(f"trimmed with a thrust force of {thrust:.0f} lbf: the aircraft glides at this point")
    qbar, weight = fdm["aero/qbar-psf"], fdm["inertia/weight-lbs"]
    return fdm, Trim(
        alpha_deg=mt.alpha_deg,
        theta_deg=mt.theta_deg,
        elevator_deg=fdm["fcs/elevator-pos-rad"] * cat.R2D,
        elevator_cmd_norm=fdm["fcs/elevator-cmd-norm"],
        pitch_trim_norm=fdm["fcs/pitch-trim-cmd-norm"],
        throttle=FORCE_TRIM_THROTTLE,
        qbar_psf=qbar,
        cl=weight / (qbar * fdm["metrics/Sw-sqft"]),
        weight_lb=weight,
        thrust_per_throttle_lbf=thrust / FORCE_TRIM_THROTTLE,
    )


#: The time constant of the thrust force's answer to the throttle of an aircraft without engines [s]: an
#: engine's spool-up, without which the hold's speed loop, its damping on the acceleration the force itself
#: makes at once, swings the throttle from stop to stop.
FORCE_LAG_S = 1.0


class _ThrottleForce:
    """A throttle command for an aircraft without engines: its thrust force follows it with the lag
    :data:`FORCE_LAG_S`, one step of ``dt_s`` per command."""

    def __init__(self, node, per_throttle_lbf: float, dt_s: float) -> None:
        self.node, self.per, self.k = node, per_throttle_lbf, dt_s / (FORCE_LAG_S + dt_s)
        self.force = node.get_double_value()

    def set_double_value(self, throttle: float) -> None:
        self.force += self.k * (throttle * self.per - self.force)
        self.node.set_double_value(self.force)


@lru_cache(maxsize=8)
def flap_schedule(source: AircraftSource) -> Schedule:
    """The aircraft's own flap schedule: ``fcs/flap-pos-deg`` against ``fcs/flap-cmd-norm``."""
    return control_schedules(new_fdm(source), set())["flap_deg"]


def flap_problem(source: AircraftSource, flap_deg: float) -> str:
    """Why the aircraft cannot fly at a flap angle ("" if it can)."""
    s = flap_schedule(source)
    if not s.moves:
        return (
            ""
            if flap_deg == 0
            else (
                f"aircraft {source.name} has no flap angle (its flight controls never "
                f"write {s.position}): only flap_deg = 0 can be flown"
            )
        )
    lo, hi = s.range
    if not lo - 1e-6 <= flap_deg <= hi + 1e-6:
        return f"flap {flap_deg:g} deg is outside aircraft {source.name}'s flap range {lo:g}..{hi:g} deg"
    return ""


def check_flaps(source: AircraftSource, flaps: list[tuple[str, float]]) -> None:
    """Refuse, naming the place, the first flap angle the aircraft cannot fly.

    Parameters
    ----------
    flaps : list of (where, flap_deg)
        ``where`` names the input field, e.g. ``"m.toml: points[3].flap_deg"``.
    """
    for where, flap in flaps:
        why = flap_problem(source, flap)
        if why:
            raise UserError(f"{where}: {why}")


def _set(fdm, names: set[str], prop: str, value: float) -> None:
    if prop not in names:
        raise UserError(f"property {prop} not in the JSBSim property catalog")
    fdm[prop] = value


@dataclass
class Trim:
    """A trimmed state: controls and the figures the logs' metadata keeps."""

    alpha_deg: float
    theta_deg: float
    elevator_deg: float
    elevator_cmd_norm: float
    pitch_trim_norm: float
    throttle: float
    qbar_psf: float
    cl: float
    weight_lb: float
    #: an aircraft without engines (``campaign model``'s): the thrust force per unit throttle [lbf]
    thrust_per_throttle_lbf: float = 0.0


#: Upper alpha bounds tried in turn [deg]: JSBSim's trim brackets alpha between
#: ``aero/alpha-min-rad`` and ``aero/alpha-max-rad`` and fails when the bracket
#: reaches the post-stall branch of the lift curve.
TRIM_ALPHA_MAX_DEG = (30.0, 18.0, 15.0, 12.0)


def trimmed_fdm(
    source: AircraftSource,
    point: StatusPoint,
    gear: float,
    gust_fps=None,
    gamma_deg: float = 0.0,
    alpha_max_deg: tuple[float, ...] = TRIM_ALPHA_MAX_DEG,
):
    """A fresh FDM trimmed at ``point`` (in the gust ``gust_fps``, if given, on the flight path
    ``gamma_deg``: :func:`trim`), retrying narrower alpha brackets (their upper bounds ``alpha_max_deg``
    [deg], tried in turn); an aircraft without engines by its thrust force (:func:`_force_trim`).

    Returns
    -------
    fdm, names, n_engines, optional, Trim
    """
    why = flap_problem(source, point.flap_deg)
    if why:
        raise TrimError(why)
    names, n_eng, optional = model_catalog(source)
    if thrust_force(source):
        fdm, tr = _force_trim(source, point, gear, gust_fps, gamma_deg)
        return fdm, names, n_eng, optional, tr
    flap_cmd = flap_schedule(source).command_for(point.flap_deg)
    reason = ""
    for alpha_max in alpha_max_deg:
        fdm = new_fdm(source)
        try:
            return (
                fdm,
                names,
                n_eng,
                optional,
                trim(fdm, point, gear, flap_cmd, n_eng, names, alpha_max, gust_fps, gamma_deg),
            )
        except TrimError as exc:
            reason = reason or str(exc)
    raise TrimError(reason)


def trim(
    fdm,
    point: StatusPoint,
    gear: float,
    flap_cmd: float,
    n_engines: int,
    names: set[str],
    alpha_max_deg: float = 30.0,
    gust_fps=None,
    gamma_deg: float = 0.0,
) -> Trim:
    """Set the initial condition and run JSBSim's full trim.

    ``flap_cmd`` is the ``fcs/flap-cmd-norm`` that gives the point's flap angle
    (:func:`flap_schedule`); JSBSim's trim moves the flaps there at once. With ``gust_fps``
    (north, east, down [ft/s]) the aircraft trims in that wind, at the point's Mach relative
    to the air: a flight in turbulence starts in equilibrium with its first gust. ``gamma_deg`` is the
    flight-path angle relative to the Earth [deg] (a replay of a log that starts climbing or descending).

    Raises
    ------
    TrimError
        With the reason (JSBSim's failure or a saturated control).
    """
    ic = {
        "ic/h-sl-ft": point.alt_ft,
        "ic/mach": point.mach,
        "ic/gamma-deg": gamma_deg,
        "ic/beta-deg": 0.0,
        "ic/phi-deg": 0.0,
        "ic/psi-true-deg": 0.0,
    }
    for k, v in ic.items():
        _set(fdm, names, k, v)
    _set(fdm, names, cat.CONTROLS["fuel_freeze"], 1)
    _set(fdm, names, cat.CONTROLS["flap_cmd"], flap_cmd)
    _set(fdm, names, cat.CONTROLS["gear_cmd"], gear)
    _set(fdm, names, cat.CONTROLS["gear_pos"], gear)
    _set(fdm, names, cat.CONTROLS["alpha_max"], np.radians(alpha_max_deg))
    _set(fdm, names, cat.CONTROLS["alpha_min"], np.radians(-20.0))
    if point.weight_lb is not None:
        fdm.run_ic()  # sums the mass items into inertia/weight-lbs
        own = fdm["inertia/weight-lbs"]
        if cat.POINTMASS_WEIGHT in names:
            pm = fdm[cat.POINTMASS_WEIGHT] + point.weight_lb - own
            if pm < 0:
                raise TrimError(f"weight {point.weight_lb:.0f} lb is below the aircraft's empty weight and fuel")
            fdm[cat.POINTMASS_WEIGHT] = pm
        elif abs(own - point.weight_lb) > WEIGHT_TOLERANCE * own:  # a log flown as loaded replays as it was
            raise TrimError(
                f"aircraft has no point mass to set the weight with (it weighs {own:.0f} lb, "
                f"the point {point.weight_lb:.0f} lb)"
            )
    fdm.run_ic()
    _set(fdm, names, cat.CONTROLS["set_running"], -1)
    cl_needed = fdm["inertia/weight-lbs"] / (fdm["aero/qbar-psf"] * fdm["metrics/Sw-sqft"])
    messages: list[str] = []
    passes = 4 if gust_fps is not None else 1
    for attempt in range(passes):
        if gust_fps is not None:
            for prop, v in zip(cat.GUSTS, gust_fps):
                _set(fdm, names, prop, float(v))
        try:
            with captured_stdout(messages):
                fdm.do_trim(1)
        except jsbsim.TrimFailureError:
            said = "; ".join(
                sorted(
                    {
                        m.replace("Sorry, ", "").replace(" doesn't appear to be trimmable", " not trimmable")
                        for m in messages
                        if "trimmable" in m
                    }
                )
            )
            raise TrimError(
                f"trim failed with alpha in [-20, {alpha_max_deg:.0f}] deg: "
                f"{said or 'no solution'} (level flight needs CL {cl_needed:.2f})"
            ) from None
        if gust_fps is None or abs(fdm["velocities/mach"] - point.mach) < 1e-5:
            break
        if attempt == passes - 1:
            raise TrimError(
                f"trim in the gust {tuple(round(float(g), 2) for g in gust_fps)} ft/s left Mach "
                f"{fdm['velocities/mach']:.4f} through the air, asked {point.mach:.4f}"
            )
        # the initial condition's speed is inertial: move it until the speed through the air is the point's
        _set(fdm, names, "ic/mach", fdm["ic/mach"] + point.mach - fdm["velocities/mach"])
        fdm.run_ic()
    if abs(fdm[cat.FLAP_DEG] - point.flap_deg) > 1e-6:
        raise TrimError(f"flaps at {fdm[cat.FLAP_DEG]:g} deg after the trim, asked {point.flap_deg:g} deg")
    if point.weight_lb is not None and abs(fdm["inertia/weight-lbs"] - point.weight_lb) > 1.0:
        raise TrimError(f"weight {fdm['inertia/weight-lbs']:.0f} lb, asked {point.weight_lb:.0f} lb")
    qbar = fdm["aero/qbar-psf"]
    weight = fdm["inertia/weight-lbs"]
    return Trim(
        alpha_deg=fdm["aero/alpha-deg"],
        theta_deg=fdm["attitude/theta-deg"],
        elevator_deg=fdm["fcs/elevator-pos-rad"] * cat.R2D,
        elevator_cmd_norm=fdm["fcs/elevator-cmd-norm"],
        pitch_trim_norm=fdm["fcs/pitch-trim-cmd-norm"],
        throttle=fdm[cat.CONTROLS["throttle"].format(i=0)],
        qbar_psf=qbar,
        cl=weight / (qbar * fdm["metrics/Sw-sqft"]),
        weight_lb=weight,
    )


def elevator_gain_deg(source: AircraftSource) -> float:
    """Elevator deflection per unit ``fcs/elevator-cmd-norm`` [deg], measured."""
    return _elevator_gain(source)


@lru_cache(maxsize=8)
def _elevator_gain(source: AircraftSource) -> float:
    return _surface_gain(source, cat.CONTROLS["elevator"], "fcs/elevator-pos-rad", cat.R2D)


def stabilizer_gain_deg(source: AircraftSource) -> float | None:
    """Stabilizer deflection per unit ``fcs/pitch-trim-cmd-norm`` [deg], or None
    if the aircraft has no separate stabilizer."""
    return _stabilizer_gain(source)


@lru_cache(maxsize=8)
def _stabilizer_gain(source: AircraftSource) -> float | None:
    prop = cat.OPTIONAL_CHANNELS["stabilizer_deg"][0]
    if prop not in cat.catalog_names(new_fdm(source)):
        return None
    return _surface_gain(source, cat.CONTROLS["pitch_trim"], prop, 1.0)


def _surface_gain(source: AircraftSource, command: str, position: str, scale: float) -> float:
    fdm = new_fdm(source)
    fdm["ic/h-sl-ft"] = 10000.0
    fdm["ic/mach"] = 0.3
    fdm.run_ic()
    fdm[command] = 0.1
    for _ in range(240):
        fdm.run()
    gain = fdm[position] * scale / 0.1
    if not gain:
        raise UserError(f"{source.folder}: {command} does not move {position}")
    return gain


@dataclass
class Flight:
    """One flown manoeuvre: the measured log and its metadata."""

    log: pd.DataFrame
    meta: dict


def fly(point: StatusPoint, maneuver_name: str | Maneuver, config: FlightConfig) -> Flight:  # noqa: C901
    """Trim at ``point`` and fly one manoeuvre.

    Parameters
    ----------
    point : StatusPoint
    maneuver_name : str or Maneuver
        A manoeuvre name of :data:`maneuvers.library.MANEUVERS` (parameters from
        the config), or a manoeuvre object.
    config : FlightConfig

    Returns
    -------
    Flight

    Raises
    ------
    TrimError
        If the point does not trim.
    """
    maneuver = config.maneuver(maneuver_name) if isinstance(maneuver_name, str) else maneuver_name
    gear0 = maneuver.gear_initial(point.gear_down)
    fdm, names, n_eng, optional, tr = trimmed_fdm(config.aircraft, point, gear0)

    clmax = dict(config.clmax_by_flap).get(point.flap_deg)
    margin = 1.0 - tr.cl / clmax if clmax else None
    scale = 1.0 if margin is None else float(np.clip(margin / 0.35, 0.2, 1.0))
    maneuver = maneuver.at_trim(float(fdm["velocities/vt-fps"]), _gravity(fdm))
    prog = maneuver.program(DT_S, scale)
    de_gain = elevator_gain_deg(config.aircraft)
    dh_gain = stabilizer_gain_deg(config.aircraft)

    seed = derived_seed(config.seed, point.id, maneuver.name)
    profile = config.instruments
    if prog.wind_fps is not None:  # a replay in the wind measured in the data
        gusts = prog.wind_fps[np.minimum(np.arange(prog.max_steps), len(prog.wind_fps) - 1)]
    else:
        gusts = dryden_gusts(
            prog.max_steps,
            DT_S,
            fdm["velocities/vt-fps"],
            point.alt_ft,
            profile.sigma_fps,
            np.random.default_rng(derived_seed(seed, "turbulence")),
        )
    if gusts.size and np.any(gusts[0] != 0.0):  # start in equilibrium with the first gust
        fdm, names, n_eng, optional, tr = trimmed_fdm(config.aircraft, point, gear0, gusts[0])

    pm = fdm.get_property_manager()
    node = lambda p: pm.get_node(p, False)  # noqa: E731
    force = thrust_force(config.aircraft)  # an aircraft without engines: its thrust force, along body x
    state_nodes = [node(force if force and c == "thrust_lbf" else p) for c, (p, _) in cat.STATE_CHANNELS.items()]
    state_scale = np.array([s for _, s in cat.STATE_CHANNELS.values()])
    force_nodes = [node(p) for p in cat.FORCE_CHANNELS.values()]
    stab = cat.OPTIONAL_CHANNELS["stabilizer_deg"]
    stab_node = node(stab[0]) if optional[stab[0]] else None
    flap_node = node(cat.FLAP_DEG)
    thr_nodes = [node(cat.THROTTLE_POS.format(i=i)) for i in range(n_eng)] if not force else [node(force)]
    truth_nodes = [node(p) for p in cat.TRUTH_CHANNELS.values()] if config.record_truth else []
    hdot_node = node(cat.HOLD_INPUTS["hdot_fps"])
    uvw_nodes = [node(cat.HOLD_INPUTS[c]) for c in ("u_fps", "v_fps", "w_fps")]

    get_u, get_v, get_w = (n.get_double_value for n in uvw_nodes)

    def speed() -> float:
        return math.sqrt(get_u() ** 2 + get_v() ** 2 + get_w() ** 2)

    elev_cmd = node(cat.CONTROLS["elevator"])
    trim_cmd = node(cat.CONTROLS["pitch_trim"])
    thr_cmd = (
        [node(cat.CONTROLS["throttle"].format(i=i)) for i in range(n_eng)]
        if not force
        else [_ThrottleForce(node(force), tr.thrust_per_throttle_lbf, DT_S)]
    )
    gear_cmd = node(cat.CONTROLS["gear_cmd"])
    gust_nodes = [node(p) for p in cat.GUSTS] if profile.sigma_fps > 0 or prog.wind_fps is not None else []
    rot_nodes = (
        [node(p) for p in cat.ANGULAR_ACCELERATIONS.values()]
        if any(any(s.position_ft) for c, s in profile.sensors if c[0] == "a")
        else []
    )
    idx = {name: i for i, name in enumerate(cat.STATE_CHANNELS)}
    i_alt, i_theta, i_q = idx["alt_ft"], idx["theta_deg"], idx["q_dps"]
    i_gear = idx["gear_norm"]

    hold = None
    if prog.hold:
        hold = HoldAutopilot(
            config.gains,
            DT_S,
            fdm["atmosphere/pressure-altitude"],
            speed(),
            tr.theta_deg,
            tr.elevator_deg,
            tr.throttle,
            tr.qbar_psf,
        )
    gear_final = maneuver.gear_final if isinstance(maneuver, GearTransition) else None
    bank_in = None
    if prog.bank_deg is not None:
        lateral = [node(cat.LATERAL_CONTROLS[c]) for c in ("aileron", "rudder")]
        if any(n is None for n in lateral):
            raise TrimError(
                f"{maneuver.name}: aircraft {config.aircraft.name} has no "
                f"{' or '.join(cat.LATERAL_CONTROLS.values())}: no bank hold"
            )
        set_aileron, set_rudder = (n.set_double_value for n in lateral)
        bank_in = prog.bank_deg.series(0, prog.max_steps).tolist()
        i_phi, i_p, i_beta = idx["phi_deg"], idx["p_dps"], idx["beta_deg"]
        s_phi, s_p, s_beta = state_scale[i_phi], state_scale[i_p], state_scale[i_beta]
        phi = p_roll = beta = 0.0

    n_state = len(state_nodes)
    read_nodes = (
        state_nodes
        + force_nodes
        + ([stab_node] if stab_node else [])
        + [flap_node]
        + thr_nodes
        + truth_nodes
        + rot_nodes
    )
    # the inputs as plain floats, evaluated once (a transition's tail only if it is flown)
    signals = [
        prog.elevator_deg,
        prog.stabilizer_deg if dh_gain else None,
        prog.gear_cmd or Constant(gear0),
        prog.throttle,
    ]
    inputs = [[] if f is not None else None for f in signals]

    def evaluate_inputs(upto: int) -> None:
        for f, values in zip(signals, inputs):
            if f is not None:
                values.extend(f.series(len(values), min(upto, prog.max_steps)).tolist())

    evaluate_inputs(prog.n_steps)
    elev_in, stab_in, gear_in, thr_in = inputs
    gust_n, gust_e, gust_d = gusts.T.tolist() if gust_nodes else (None, None, None)
    set_gust_n, set_gust_e, set_gust_d = (n.set_double_value for n in gust_nodes) if gust_nodes else (None,) * 3
    sc = state_scale.tolist()
    i_mass = idx["mass_slug"]
    s_alt, s_theta, s_q, s_mass, s_gear = sc[i_alt], sc[i_theta], sc[i_q], sc[i_mass], sc[i_gear]
    stab_const = stab[1]
    # every step's row appended to one flat buffer: no Python list per step for the collector to track
    buf = array.array("d")
    append_row = buf.extend
    get = type(read_nodes[0]).get_double_value
    n_read = len(read_nodes)
    elevator_deg = tr.elevator_deg
    throttle = tr.throttle
    h, theta, q = fdm["atmosphere/pressure-altitude"], tr.theta_deg, 0.0
    end = prog.n_steps if gear_final is None else prog.max_steps
    k = 0
    while k < end:
        if k == len(elev_in):
            evaluate_inputs(k + 120)
        if hold is not None:
            elevator_deg, throttle = hold.step(h, hdot_node.get_double_value(), speed(), theta, q)
            if thr_in is not None:  # the hold flies the elevator, the manoeuvre the throttle
                throttle = min(max(tr.throttle + thr_in[k], 0.0), 1.0)
            for t in thr_cmd:
                t.set_double_value(throttle)
        elif thr_in is not None:
            for t in thr_cmd:
                t.set_double_value(min(max(tr.throttle + thr_in[k], 0.0), 1.0))
        elev_cmd.set_double_value(tr.elevator_cmd_norm + (elevator_deg - tr.elevator_deg + elev_in[k]) / de_gain)
        if dh_gain:
            trim_cmd.set_double_value(tr.pitch_trim_norm + stab_in[k] / dh_gain)
        gear_cmd.set_double_value(gear_in[k])
        if bank_in is not None:
            aileron, rudder = bank_hold(config.gains, bank_in[k], phi, p_roll, beta)
            set_aileron(aileron)
            set_rudder(rudder)
        if gust_n is not None:
            set_gust_n(gust_n[k])
            set_gust_e(gust_e[k])
            set_gust_d(gust_d[k])
        fdm.run()
        append_row(map(get, read_nodes))  # scaled, divided and averaged after the loop
        row = k * n_read
        if hold is not None:
            h, theta, q = buf[row + i_alt] * s_alt, buf[row + i_theta] * s_theta, buf[row + i_q] * s_q
        if bank_in is not None:
            phi, p_roll, beta = buf[row + i_phi] * s_phi, buf[row + i_p] * s_p, buf[row + i_beta] * s_beta
        if (
            gear_final is not None
            and end == prog.max_steps
            and gear_in[k] == gear_final
            and abs(buf[row + i_gear] * s_gear - gear_final) < 1e-9
        ):
            end = k + 1 + prog.post_travel_steps
        k += 1
    raw = np.frombuffer(buf, dtype=float).reshape(-1, n_read)
    n_force, n_stab = len(force_nodes), int(stab_node is not None)
    mass = raw[:, i_mass] * s_mass
    at = n_state + n_force + n_stab + 1  # the engines' throttle positions (without engines, the thrust force)
    n_thr = len(thr_nodes)
    rows = np.column_stack(
        [
            raw[:, :n_state] * state_scale,
            raw[:, n_state : n_state + n_force] / mass[:, None],
            raw[:, n_state + n_force] if n_stab else np.full(len(raw), stab_const),
            raw[:, at - 1],
            sum(raw[:, at + e] for e in range(n_thr)) / n_thr / (tr.thrust_per_throttle_lbf if force else 1.0),
            raw[:, at + n_thr :],
        ]
    )
    if gear_final is not None and abs(rows[-1, i_gear] - gear_final) > 1e-9:
        raise TrimError(f"gear did not complete its travel within {maneuver.max_travel_s:.0f} s")
    _check_envelope(rows, idx, tr)

    cols = list(cat.STATE_CHANNELS) + list(cat.FORCE_CHANNELS) + ["stabilizer_deg", "flap_deg", "throttle_norm"]
    cols += list(cat.TRUTH_CHANNELS) if config.record_truth else []
    cols += list(cat.ANGULAR_ACCELERATIONS) if rot_nodes else []
    columns = dict(zip(cols, np.ascontiguousarray(rows.T)))
    columns["t_s"] = np.arange(end) * DT_S
    columns["psi_deg"] = np.degrees(np.unwrap(np.radians(columns["psi_deg"])))  # no jump through north
    truth = [c for c in cols if c.startswith("truth_")]
    extra = {c: columns[c] for c in cat.ANGULAR_ACCELERATIONS} if rot_nodes else None
    df = record({c: columns[c] for c in [*cat.LOG_COLUMNS, *truth]}, extra, profile, DT_S, np.random.default_rng(seed))

    meta = {
        "point": point.id,
        "status_point": {
            "alt_ft": point.alt_ft,
            "mach": point.mach,
            "flap_deg": point.flap_deg,
            "gear": "down" if point.gear_down else "up",
            "weight_lb": point.weight_lb,
        },
        "maneuver": maneuver.name,
        "maneuver_params": {k: v for k, v in vars(maneuver).items() if not isinstance(v, tuple)},
        "seed": seed,
        "campaign_seed": config.seed,
        "noise": profile.name,
        "instruments": {"name": profile.name, "sha256": profile.sha256},
        "omitted_channels": list(profile.omit),
        # documented installation geometry, as a flight-test data package gives it (never the errors)
        "sensor_positions_ft": {c: list(s.position_ft) for c, s in profile.sensors if any(s.position_ft)},
        "dt_s": 1.0 / profile.rate_hz if profile.rate_hz else DT_S,
        "gravity_fps2": _gravity(fdm),
        "latitude_deg": float(fdm["position/lat-geod-deg"]),
        "aircraft": config.aircraft.name,
        "aircraft_sha256": config.aircraft.sha256,
        "effects_sha256": config.aircraft.effects.sha256,
        "inertia_slugft2": {
            "ixx": fdm["inertia/ixx-slugs_ft2"],
            "iyy": fdm["inertia/iyy-slugs_ft2"],
            "izz": fdm["inertia/izz-slugs_ft2"],
            "ixz": fdm["inertia/ixz-slugs_ft2"],
        },
        "geometry": {
            "S_ft2": fdm["metrics/Sw-sqft"],
            "cbar_ft": fdm["metrics/cbarw-ft"],
            "b_ft": fdm["metrics/bw-ft"],
            "aerorp_x_in": fdm["metrics/aero-rp-x-in"],
            "aerorp_z_in": fdm["metrics/aero-rp-z-in"],
            "cg_x_in": fdm["inertia/cg-x-in"],
            "cg_z_in": fdm["inertia/cg-z-in"],
            "thrust_z_arm_ft": _thrust_arm_ft(fdm, config.aircraft),
        },
        "trim": {
            "alpha_deg": tr.alpha_deg,
            "theta_deg": tr.theta_deg,
            "elevator_deg": tr.elevator_deg,
            "pitch_trim_norm": tr.pitch_trim_norm,
            "throttle": tr.throttle,
            "cl": tr.cl,
            "weight_lb": tr.weight_lb,
        },
        "stall_margin": margin,
        "amplitude_scale": scale,
        "hold": prog.hold,
        "absent_channels": [] if stab_node else ["stabilizer_deg"],
    }
    return Flight(df, meta)


#: A flight leaving these bounds is reported as failed, not logged as a valid test point.
ENVELOPE = {"alpha_deg": (-15.0, 25.0), "phi_deg": (-30.0, 30.0), "theta_deg": (-30.0, 40.0)}


def _check_envelope(rows: np.ndarray, idx: dict, tr: Trim) -> None:
    for ch, (lo, hi) in ENVELOPE.items():
        v = rows[:, idx[ch]]
        k = np.flatnonzero((v < lo) | (v > hi))
        if k.size:
            raise TrimError(
                f"left the test envelope: {ch} {v[k[0]]:.1f} at t = {k[0] * DT_S:.1f} s "
                f"(allowed {lo:g}..{hi:g}; trimmed alpha {tr.alpha_deg:.1f} deg)"
            )


from identify.compat import EARTH_RATE  # noqa: E402  (JSBSim's planet rotates at the WGS84 rate)


def _gravity(fdm) -> float:
    """Local effective gravity: gravitation less the Earth's centrifugal acceleration [ft/s^2]."""
    r = fdm["position/radius-to-vehicle-ft"] * np.cos(fdm["position/lat-geod-rad"])
    return float(fdm["accelerations/gravity-ft_sec2"] - EARTH_RATE**2 * r * np.cos(fdm["position/lat-geod-rad"]))


def _thrust_arm_ft(fdm, source: AircraftSource) -> float:
    """Height of the thrust line above the CG [ft] (negative: below), from the XML."""
    z = thruster_z_in(source)
    return 0.0 if z is None else (z - fdm["inertia/cg-z-in"]) / 12.0
