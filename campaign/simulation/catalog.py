"""The one catalog of JSBSim properties this project reads and writes.

Every name is checked against ``fdm.get_property_catalog()`` when a model is
loaded, because writing a misspelled property silently creates it.
"""

from __future__ import annotations

import math

from campaign.errors import UserError

R2D = 180.0 / math.pi

#: Log column -> (JSBSim property, scale). Rates are inertial (what gyros sense).
STATE_CHANNELS: dict[str, tuple[str, float]] = {
    "alt_ft": ("atmosphere/pressure-altitude", 1.0),
    "tas_kt": ("velocities/vtrue-kts", 1.0),
    "ias_kt": ("velocities/vc-kts", 1.0),
    "mach": ("velocities/mach", 1.0),
    "alpha_deg": ("aero/alpha-deg", 1.0),
    "beta_deg": ("aero/beta-deg", 1.0),
    "theta_deg": ("attitude/theta-deg", 1.0),
    "phi_deg": ("attitude/phi-deg", 1.0),
    "psi_deg": ("attitude/psi-deg", 1.0),
    "p_dps": ("velocities/pi-rad_sec", R2D),
    "q_dps": ("velocities/qi-rad_sec", R2D),
    "r_dps": ("velocities/ri-rad_sec", R2D),
    "qdot_dps2": ("accelerations/qidot-rad_sec2", R2D),
    "qbar_psf": ("aero/qbar-psf", 1.0),
    "thrust_lbf": ("forces/fbx-prop-lbs", 1.0),
    "elevator_deg": ("fcs/elevator-pos-rad", R2D),
    "gear_norm": ("gear/gear-pos-norm", 1.0),
    "mass_slug": ("inertia/mass-slugs", 1.0),
    "xcg_in": ("inertia/cg-x-in", 1.0),
    # the inertial/GPS unit's velocity relative to the Earth, north-east-down
    "vn_fps": ("velocities/v-north-fps", 1.0),
    "ve_fps": ("velocities/v-east-fps", 1.0),
    "vd_fps": ("velocities/v-down-fps", 1.0),
}

#: Body-axis non-gravitational force [lbf]; divided by mass it is the specific
#: force an accelerometer at the CG senses, aligned in time with the states
#: (``accelerations/N[xyz]`` lag one step behind).
FORCE_CHANNELS: dict[str, str] = {
    "ax_fps2": "forces/fbx-total-lbs",
    "ay_fps2": "forces/fby-total-lbs",
    "az_fps2": "forces/fbz-total-lbs",
}

#: Channels an aircraft may lack; the log then holds the stated constant.
OPTIONAL_CHANNELS: dict[str, tuple[str, float]] = {
    "stabilizer_deg": ("fcs/stabilizer-pos-deg", 0.0),
}

#: The aircraft's own flap angle (JSBSim keeps it at 0 if the FCS never writes it).
FLAP_DEG = "fcs/flap-pos-deg"
THROTTLE_POS = "fcs/throttle-pos-norm[{i}]"

#: Log columns in file order (the DESIGN.md log schema).
LOG_COLUMNS: tuple[str, ...] = (
    "t_s",
    "alt_ft",
    "tas_kt",
    "ias_kt",
    "mach",
    "alpha_deg",
    "beta_deg",
    "theta_deg",
    "phi_deg",
    "psi_deg",
    "p_dps",
    "q_dps",
    "r_dps",
    "qdot_dps2",
    "ax_fps2",
    "ay_fps2",
    "az_fps2",
    "qbar_psf",
    "thrust_lbf",
    "elevator_deg",
    "stabilizer_deg",
    "flap_deg",
    "gear_norm",
    "throttle_norm",
    "mass_slug",
    "xcg_in",
    "vn_fps",
    "ve_fps",
    "vd_fps",
)

#: What the autopilot hold reads (not logged).
HOLD_INPUTS: dict[str, str] = {
    "hdot_fps": "velocities/h-dot-fps",
    # the speed hold holds inertial speed (body velocity relative to the Earth), which gusts do not move
    "u_fps": "velocities/u-fps",
    "v_fps": "velocities/v-fps",
    "w_fps": "velocities/w-fps",
}

#: Lateral controls, written only by the bank hold of a level turn (not required otherwise).
LATERAL_CONTROLS: dict[str, str] = {"aileron": "fcs/aileron-cmd-norm", "rudder": "fcs/rudder-cmd-norm"}

#: Properties written by the engine.
CONTROLS: dict[str, str] = {
    "elevator": "fcs/elevator-cmd-norm",
    "pitch_trim": "fcs/pitch-trim-cmd-norm",
    "throttle": "fcs/throttle-cmd-norm[{i}]",
    "gear_cmd": "gear/gear-cmd-norm",
    "gear_pos": "gear/gear-pos-norm",
    "flap_cmd": "fcs/flap-cmd-norm",
    "fuel_freeze": "propulsion/fuel_freeze",
    "set_running": "propulsion/set-running",
    "alpha_max": "aero/alpha-max-rad",
    "alpha_min": "aero/alpha-min-rad",
}

INITIAL_CONDITIONS = (
    "ic/h-sl-ft",
    "ic/mach",
    "ic/gamma-deg",
    "ic/beta-deg",
    "ic/phi-deg",
    "ic/psi-true-deg",
)

#: Gust inputs (NED) the turbulence of an instrument profile flies through (:mod:`campaign.simulation.turbulence`).
GUSTS = ("atmosphere/gust-north-fps", "atmosphere/gust-east-fps", "atmosphere/gust-down-fps")

#: Body angular accelerations, for accelerometers away from the CG (not logged).
ANGULAR_ACCELERATIONS = {
    "pdot_rps2": "accelerations/pidot-rad_sec2",
    "qdot_rps2": "accelerations/qidot-rad_sec2",
    "rdot_rps2": "accelerations/ridot-rad_sec2",
}

#: Used only to set weight when the status point asks for one.
POINTMASS_WEIGHT = "inertia/pointmass-weight-lbs[0]"

#: Test-only truth channels (never in a campaign log): JSBSim's own aero forces
#: and moments, so eq. (1) can be checked against them, and the wind it flies in.
TRUTH_CHANNELS: dict[str, str] = {
    "truth_fx_aero_lbf": "forces/fbx-aero-lbs",
    "truth_fz_aero_lbf": "forces/fbz-aero-lbs",
    "truth_fwx_aero_lbf": "forces/fwx-aero-lbs",
    "truth_fwz_aero_lbf": "forces/fwz-aero-lbs",
    "truth_m_aero_lbfft": "moments/m-aero-lbsft",
    "truth_m_prop_lbfft": "moments/m-prop-lbsft",
    "truth_m_total_lbfft": "moments/m-total-lbsft",
    "truth_wind_north_fps": "atmosphere/total-wind-north-fps",
    "truth_wind_east_fps": "atmosphere/total-wind-east-fps",
    "truth_wind_down_fps": "atmosphere/total-wind-down-fps",
}


def canonical(name: str) -> str:
    """A property path with every ``[0]`` index dropped (JSBSim treats them alike)."""
    return name.replace("[0]", "")


class PropertyNames(set):
    """Catalog names; membership ignores ``[0]`` indices."""

    def __contains__(self, name: object) -> bool:
        return set.__contains__(self, canonical(str(name)))


def catalog_names(fdm) -> PropertyNames:
    """Property names of a loaded FDM, without the ``(RW)`` suffixes."""
    return PropertyNames(canonical(entry.split(" ")[0]) for entry in fdm.get_property_catalog())


def check_catalog(names: set[str], n_engines: int, aircraft: str, thrust: str | None = None) -> dict[str, bool]:
    """Check every property we need exists in a model's catalog ``names``
    (:func:`catalog_names`); report which optional ones do. ``thrust``: the thrust force of an aircraft
    without engines (its throttle, fuel and engines' properties are not needed).

    Returns
    -------
    dict
        ``{optional property: present}``.

    Raises
    ------
    UserError
        Naming the aircraft and the first missing property.
    """
    required = [thrust if thrust and c == "thrust_lbf" else p for c, (p, _) in STATE_CHANNELS.items()]
    required += list(FORCE_CHANNELS.values()) + list(HOLD_INPUTS.values()) + [FLAP_DEG]
    required += [THROTTLE_POS.format(i=i) for i in range(n_engines)]
    for key, prop in CONTROLS.items():
        if key == "throttle":
            required += [prop.format(i=i) for i in range(n_engines)]
        elif not (thrust and key in ("fuel_freeze", "set_running")):
            required.append(prop)
    required += list(INITIAL_CONDITIONS) + list(GUSTS) + list(ANGULAR_ACCELERATIONS.values())
    for prop in required:
        if prop not in names:
            raise UserError(f"{aircraft}: property {prop} not in the JSBSim property catalog")
    optional = [p for p, _ in OPTIONAL_CHANNELS.values()] + [POINTMASS_WEIGHT]
    optional += list(TRUTH_CHANNELS.values())
    return {p: p in names for p in optional}
