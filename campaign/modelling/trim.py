"""Steady straight flight of an aircraft written by ``campaign model``, its thrust an external force.

JSBSim's own trim moves throttles, and these aircraft have none: their thrust is
``external_reactions/thrust/magnitude``. This trim solves for the angle of attack, the pitch
control and the thrust that zero the body accelerations (``udot``, ``wdot``, ``qdot``) at a given
altitude, true airspeed and flight-path angle, wings level, by Newton's method on JSBSim's own
accelerations after ``run_ic()``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from infra.model import captured_stdout

THRUST = "external_reactions/thrust/magnitude"
PAYLOAD = "inertia/pointmass-weight-lbs[0]"
#: The pitch controls: command and position [deg] properties.
PITCH = {
    "elevator": ("fcs/elevator-cmd-norm", "fcs/elevator-pos-deg"),
    "stabilizer": ("fcs/pitch-trim-cmd-norm", "fcs/stabilizer-pos-deg"),
}
#: Converged when the body accelerations are below these [ft/s^2, ft/s^2, rad/s^2].
TOLERANCE = np.array([1e-7, 1e-7, 1e-9])
ACCELERATIONS = ("accelerations/udot-ft_sec2", "accelerations/wdot-ft_sec2", "accelerations/qdot-rad_sec2")


class ModelTrimError(RuntimeError):
    """The trim did not converge; the message says how far it got."""


@dataclass(frozen=True)
class ModelTrim:
    """A steady straight flight.

    Attributes
    ----------
    alpha_deg, theta_deg : float
    pitch_control : str
        ``elevator`` or ``stabilizer``: the surface the trim moved (the other held).
    elevator_deg, stabilizer_deg : float
    thrust_lbf : float
    residual : tuple
        udot, wdot [ft/s^2] and qdot [rad/s^2] left.
    """

    alpha_deg: float
    theta_deg: float
    pitch_control: str
    elevator_deg: float
    stabilizer_deg: float
    thrust_lbf: float
    residual: tuple[float, float, float]


def _ranges(fdm) -> dict[str, float]:
    """Surface deflection per unit command [deg] of the aircraft's pitch controls (its FCS is linear)."""
    out = {}
    for name, (cmd, pos) in PITCH.items():
        fdm[cmd] = 1.0
        with captured_stdout():
            fdm.run_ic()
        out[name] = fdm[pos]
        fdm[cmd] = 0.0
    return out


def trim_model(  # noqa: PLR0913
    fdm,
    alt_ft: float,
    tas_kt: float,
    gamma_deg: float = 0.0,
    flap_deg: float = 0.0,
    gear_norm: float = 0.0,
    elevator_deg: float = 0.0,
    stabilizer_deg: float = 0.0,
    thrust_lbf: float = 0.0,
    alpha_deg: float = 2.0,
    weight_lb: float | None = None,
    pitch_control: str = "elevator",
    iterations: int = 30,
    q_dps: float = 0.0,
    accel_fps2: float = 0.0,
) -> ModelTrim:
    """Trim a ``campaign model`` aircraft in straight flight, wings level: steady, or pitching at ``q_dps`` with
    its airspeed changing at ``accel_fps2``.

    Parameters
    ----------
    fdm : jsbsim.FGFDMExec
        The aircraft, loaded (:func:`infra.model.load_fdm`).
    alt_ft, tas_kt, gamma_deg : float
        Altitude [ft], true airspeed [kt], flight-path angle [deg].
    flap_deg, gear_norm : float
        Flap angle [deg] and gear position [-], held.
    elevator_deg, stabilizer_deg : float
        Surface positions [deg]: the ``pitch_control`` one is the first guess, the other held.
    thrust_lbf, alpha_deg : float
        First guesses.
    weight_lb : float, optional
        The weight to fly at (the point mass ``payload`` takes the difference from the empty weight).
    pitch_control : {"elevator", "stabilizer"}
        The surface that trims the pitching moment.
    q_dps, accel_fps2 : float
        A pitch rate [deg/s] and a rate of change of the airspeed [ft/s^2] held at the trim (a pull-up of
        load factor ``1 + q V / g`` and an along-path acceleration): the controls and thrust that give the
        flight a log starts in, out of steady flight. 0 and 0: steady flight.

    Returns
    -------
    ModelTrim

    Raises
    ------
    ModelTrimError
        If Newton's method does not bring the accelerations below :data:`TOLERANCE`.
    """
    per_cmd = _ranges(fdm)
    other = "stabilizer" if pitch_control == "elevator" else "elevator"
    fdm[PITCH[other][0]] = (stabilizer_deg if other == "stabilizer" else elevator_deg) / per_cmd[other]
    flap_full = _flap_range(fdm)
    fdm["fcs/flap-cmd-norm"] = flap_deg / flap_full if flap_full else 0.0
    fdm["gear/gear-cmd-norm"] = gear_norm
    if weight_lb is not None:
        fdm[PAYLOAD] = 0.0
        with captured_stdout():
            fdm.run_ic()
        fdm[PAYLOAD] = max(weight_lb - fdm["inertia/weight-lbs"], 0.0)
    first = (stabilizer_deg if pitch_control == "stabilizer" else elevator_deg) / per_cmd[pitch_control]
    x = np.array([alpha_deg, first, thrust_lbf], dtype=float)
    steps = np.array([1e-3, 1e-4, 1.0])

    def accelerations(v: np.ndarray) -> np.ndarray:
        for prop, value in (
            ("ic/h-sl-ft", alt_ft),
            ("ic/vt-kts", tas_kt),
            ("ic/beta-deg", 0.0),
            ("ic/phi-deg", 0.0),
            ("ic/p-rad_sec", 0.0),
            ("ic/q-rad_sec", np.radians(q_dps)),
            ("ic/r-rad_sec", 0.0),
            ("ic/alpha-deg", v[0]),
            ("ic/gamma-deg", gamma_deg),
        ):
            fdm[prop] = value
        fdm[PITCH[pitch_control][0]] = v[1]
        fdm[THRUST] = v[2]
        with captured_stdout():
            fdm.run_ic()
        alpha = np.radians(v[0])
        held = np.array([accel_fps2 * np.cos(alpha), accel_fps2 * np.sin(alpha), 0.0]) if accel_fps2 else 0.0
        return np.array([fdm[a] for a in ACCELERATIONS]) - held

    fdm.set_trim_status(True)  # the gear's kinematic at its command at once
    try:
        r = accelerations(x)
        for _ in range(iterations):
            if np.all(np.abs(r) < TOLERANCE):
                break
            jac = np.column_stack([(accelerations(x + np.eye(3)[k] * steps[k]) - r) / steps[k] for k in range(3)])
            x = x - np.linalg.lstsq(jac, r, rcond=None)[0]
            r = accelerations(x)
    finally:
        fdm.set_trim_status(False)
    if not np.all(np.abs(r) < TOLERANCE) or abs(x[1]) > 1.0:
        why = (
            f"the {pitch_control} would need {x[1] * per_cmd[pitch_control]:.1f} deg, beyond its "
            f"{per_cmd[pitch_control]:g} deg"
            if abs(x[1]) > 1.0
            else f"accelerations left: udot {r[0]:.2g} ft/s^2, wdot {r[1]:.2g} ft/s^2, qdot {r[2]:.2g} rad/s^2"
        )
        raise ModelTrimError(f"no steady flight at {alt_ft:.0f} ft, {tas_kt:.1f} kt: {why}")
    return ModelTrim(
        float(fdm["aero/alpha-deg"]),
        float(fdm["attitude/theta-deg"]),
        pitch_control,
        float(fdm["fcs/elevator-pos-deg"]),
        float(fdm["fcs/stabilizer-pos-deg"]),
        float(fdm[THRUST]),
        tuple(float(v) for v in r),
    )


def _flap_range(fdm) -> float:
    """The flap angle at full command [deg]."""
    fdm.set_trim_status(True)
    try:
        fdm["fcs/flap-cmd-norm"] = 1.0
        with captured_stdout():
            fdm.run_ic()
        return float(fdm["fcs/flap-pos-deg"])
    finally:
        fdm["fcs/flap-cmd-norm"] = 0.0
        fdm.set_trim_status(False)
