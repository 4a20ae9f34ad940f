"""Aerodynamic coefficients from measured channels (paper eq. 1).

CL follows eq. (1a). CD is eq. (1b) taken into wind axes: the drag along the
airspeed, as JSBSim's ``DRAG`` axis holds it, so with sideslip it has the side
force's share and the ``cos(beta)`` of the others (without a logged sideslip
and lateral acceleration it is eq. (1b)). Cm follows eq. (1c), less the thrust
line's moment, so it is the aerodynamic pitching moment about the CG. The
body-axis force coefficients Cx and Cz come along: a moment transfer needs them.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from identify.kinematics import pitch_acceleration

D2R = np.pi / 180.0
FT_PER_KT = 1.6878098571011957


def coefficients(data: pd.DataFrame, meta: dict) -> pd.DataFrame:
    """CL, CD, Cm at the CG from a log (eq. 1): :func:`coefficient_arrays` as a frame indexed like
    ``data``."""
    return pd.DataFrame(coefficient_arrays(data, meta), index=data.index)


def coefficient_arrays(data: pd.DataFrame, meta: dict, qdot_dps2: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """CL, CD, Cm at the CG from a log (eq. 1).

    Parameters
    ----------
    data : DataFrame
        A log in the schema (accelerations [ft/s^2], rates [deg/s], thrust [lbf]...).
        Without ``qdot_dps2``, the pitch acceleration is the smoothing derivative of
        ``q_dps`` (:func:`identify.kinematics.pitch_acceleration`).
    meta : dict
        Log metadata with ``inertia_slugft2`` [slug ft^2] and ``geometry`` (S [ft^2],
        cbar [ft], thrust_z_arm_ft [ft], thrust line height above the CG).
    qdot_dps2 : ndarray, optional
        The pitch acceleration [deg/s^2] if already known (default:
        :func:`identify.kinematics.pitch_acceleration` of ``data``).

    Returns
    -------
    dict
        ``CL``, ``CD``, ``Cm`` and the body-axis aero force coefficients ``Cx`` (forward),
        ``Cz`` (down) [-], one array each.
    """
    g = meta["geometry"]
    inertia = meta["inertia_slugft2"]
    cbar = g["cbar_ft"]
    a, qs, fx, fz = _aero_forces(data, meta)
    cl = _lift(a, qs, fx, fz)
    b, fy = _sideslip(data)
    cd = (-(fx * np.cos(a) + fz * np.sin(a)) * np.cos(b) - fy * np.sin(b)) / qs
    p, q, r = (data[c].to_numpy() * D2R for c in ("p_dps", "q_dps", "r_dps"))
    qdot = (pitch_acceleration(data) if qdot_dps2 is None else qdot_dps2) * D2R
    moment = inertia["iyy"] * qdot + (inertia["ixx"] - inertia["izz"]) * p * r + inertia["ixz"] * (p**2 - r**2)
    # thrust along body x, its line thrust_z_arm_ft above the CG: M = -z * T
    moment_thrust = -g.get("thrust_z_arm_ft", 0.0) * data["thrust_lbf"].to_numpy()
    cm = (moment - moment_thrust) / (qs * cbar)
    return {"CL": cl, "CD": cd, "Cm": cm, "Cx": fx / qs, "Cz": fz / qs}


def _aero_forces(data: pd.DataFrame, meta: dict) -> tuple[np.ndarray, ...]:
    """Alpha [rad], qbar S [lbf] and the body-axis aero forces fx (forward), fz (down) [lbf]."""
    a = data["alpha_deg"].to_numpy() * D2R
    qs = data["qbar_psf"].to_numpy() * meta["geometry"]["S_ft2"]
    m = data["mass_slug"].to_numpy()
    fx = m * data["ax_fps2"].to_numpy() - data["thrust_lbf"].to_numpy()
    fz = m * data["az_fps2"].to_numpy()
    return a, qs, fx, fz


def _sideslip(data: pd.DataFrame) -> tuple[np.ndarray | float, np.ndarray | float]:
    """Sideslip [rad] and the body-axis side force (right) [lbf]; both zero unless the log has
    ``beta_deg`` and ``ay_fps2``."""
    if "beta_deg" not in data or "ay_fps2" not in data:
        return 0.0, 0.0
    return (data["beta_deg"].to_numpy() * D2R, data["mass_slug"].to_numpy() * data["ay_fps2"].to_numpy())


def lift_coefficient(data: pd.DataFrame, meta: dict) -> np.ndarray:
    """CL alone (eq. 1a), as :func:`coefficients` gives it, without the pitch acceleration's cost [-]."""
    return _lift(*_aero_forces(data, meta))


def _lift(a: np.ndarray, qs: np.ndarray, fx: np.ndarray, fz: np.ndarray) -> np.ndarray:
    """Eq. (1a): the aero force normal to the airspeed over qbar S [-]."""
    return (-fz * np.cos(a) + fx * np.sin(a)) / qs


def thrust_share(data: pd.DataFrame, meta: dict) -> pd.DataFrame:
    """What the logged thrust contributes to each eq. (1) coefficient (same columns as
    :func:`coefficients`): eq. (1) is linear in the thrust, so this is also the change a
    relative thrust error of 1 makes."""
    g = meta["geometry"]
    a = data["alpha_deg"].to_numpy() * D2R
    qs = data["qbar_psf"].to_numpy() * g["S_ft2"]
    t = data["thrust_lbf"].to_numpy()
    b = _sideslip(data)[0]
    return pd.DataFrame(
        {
            "CL": -t * np.sin(a) / qs,
            "CD": t * np.cos(a) * np.cos(b) / qs,
            "Cm": g.get("thrust_z_arm_ft", 0.0) * t / (qs * g["cbar_ft"]),
            "Cx": -t / qs,
            "Cz": np.zeros(len(t)),
        },
        index=data.index,
    )


def qhat(data: pd.DataFrame, meta: dict) -> np.ndarray:
    """Normalized pitch rate q cbar / (2 V) [rad]."""
    v = data["tas_kt"].to_numpy() * FT_PER_KT
    return data["q_dps"].to_numpy() * D2R * meta["geometry"]["cbar_ft"] / (2.0 * v)
