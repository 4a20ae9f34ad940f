"""Flight-path kinematics from measured channels.

The body-axis velocity follows from true airspeed, alpha and beta (still air),
and its rate from the specific forces, the body rates and gravity:

    u' = r v - q w + ax - g sin(theta)
    v' = p w - r u + ay + g cos(theta) sin(phi)
    w' = q u - p v + az + g cos(theta) cos(phi)

so the rates of alpha and beta need no numerical differentiation of the
noisy vanes (Jategaonkar, Flight Vehicle System Identification, 2nd ed.,
sec. 10.2). ``g`` is the effective gravity of the data, which includes the
centrifugal part of the Earth's rotation: it is fitted so that the integrated
alpha rate follows the measured alpha.
"""
from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.integrate import cumulative_trapezoid

D2R = np.pi / 180.0
FT_PER_KT = 1.6878098571011957
G0_FPS2 = 32.174049


def _col(data: pd.DataFrame, name: str, scale: float = 1.0) -> np.ndarray:
    return data[name].to_numpy(dtype=float) * scale if name in data else np.zeros(len(data))


def _terms(data: pd.DataFrame) -> dict[str, np.ndarray]:
    """Body velocity [ft/s] and the parts of its rate without and per unit gravity."""
    a, b = _col(data, "alpha_deg", D2R), _col(data, "beta_deg", D2R)
    vt = _col(data, "tas_kt", FT_PER_KT)
    u, v, w = vt * np.cos(a) * np.cos(b), vt * np.sin(b), vt * np.sin(a) * np.cos(b)
    p, q, r = _col(data, "p_dps", D2R), _col(data, "q_dps", D2R), _col(data, "r_dps", D2R)
    th, ph = _col(data, "theta_deg", D2R), _col(data, "phi_deg", D2R)
    return {"u": u, "v": v, "w": w,
            "ud0": r * v - q * w + _col(data, "ax_fps2"), "udg": -np.sin(th),
            "vd0": p * w - r * u + _col(data, "ay_fps2"), "vdg": np.cos(th) * np.sin(ph),
            "wd0": q * u - p * v + _col(data, "az_fps2"), "wdg": np.cos(th) * np.cos(ph)}


def effective_gravity(data: pd.DataFrame) -> float:
    """Gravity that makes the kinematic alpha rate integrate to the measured alpha [ft/s^2].

    Least squares of ``alpha(t) = alpha0 + int(A) + g int(B)`` where the alpha
    rate is ``A + g B``; returns the standard 32.174 ft/s^2 when the record
    cannot tell (too short, or no usable airspeed).
    """
    k = _terms(data)
    uw2 = k["u"] ** 2 + k["w"] ** 2
    t = _col(data, "t_s")
    if len(t) < 10 or np.any(uw2 <= 0):
        return G0_FPS2
    rate0 = (k["u"] * k["wd0"] - k["w"] * k["ud0"]) / uw2
    rate_g = (k["u"] * k["wdg"] - k["w"] * k["udg"]) / uw2
    x = np.column_stack([np.ones(len(t)), cumulative_trapezoid(rate_g, t, initial=0.0)])
    y = _col(data, "alpha_deg", D2R) - cumulative_trapezoid(rate0, t, initial=0.0)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    g = float(coef[1])
    return g if 0.9 * G0_FPS2 < g < 1.1 * G0_FPS2 else G0_FPS2


def angle_rates(data: pd.DataFrame, lag_s: float = 0.0, g_fps2: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Alpha and beta rates [rad/s] from the flight-path kinematics.

    Parameters
    ----------
    data : DataFrame
        A log in the schema (time order).
    lag_s : float
        Take the velocity rate this long before each sample (JSBSim computes
        ``aero/alphadot-rad_sec`` from the previous frame's accelerations) [s].
    g_fps2 : float, optional
        Gravity [ft/s^2]; fitted to the data by :func:`effective_gravity` if None.

    Returns
    -------
    alpha_dot, beta_dot : ndarray
        As JSBSim defines them (``aero/alphadot-rad_sec``, ``aero/betadot-rad_sec``).
    """
    g = effective_gravity(data) if g_fps2 is None else g_fps2
    k = _terms(data)
    t = _col(data, "t_s")
    rates = [k[f"{c}d0"] + g * k[f"{c}dg"] for c in "uvw"]
    if lag_s:
        rates = [np.interp(t - lag_s, t, x) for x in rates]
    ud, vd, wd = rates
    u, v, w = k["u"], k["v"], k["w"]
    uw2 = u ** 2 + w ** 2
    vt = np.sqrt(uw2 + v ** 2)
    vt_dot = (u * ud + v * vd + w * wd) / vt
    alpha_dot = (u * wd - w * ud) / uw2
    beta_dot = (vd * vt - v * vt_dot) / (vt * np.sqrt(uw2))
    return alpha_dot, beta_dot
