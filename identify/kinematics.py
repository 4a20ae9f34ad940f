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

from functools import lru_cache

import numpy as np
import pandas as pd
from scipy.integrate import cumulative_trapezoid
from scipy.interpolate import make_interp_spline

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
    return {
        "u": u,
        "v": v,
        "w": w,
        "ud0": r * v - q * w + _col(data, "ax_fps2"),
        "udg": -np.sin(th),
        "vd0": p * w - r * u + _col(data, "ay_fps2"),
        "vdg": np.cos(th) * np.sin(ph),
        "wd0": q * u - p * v + _col(data, "az_fps2"),
        "wdg": np.cos(th) * np.cos(ph),
    }


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
    uw2 = u**2 + w**2
    vt = np.sqrt(uw2 + v**2)
    vt_dot = (u * ud + v * vd + w * wd) / vt
    alpha_dot = (u * wd - w * ud) / uw2
    beta_dot = (vd * vt - v * vt_dot) / (vt * np.sqrt(uw2))
    return alpha_dot, beta_dot


#: JSBSim's default frame [s]: it integrates body rates by Euler's rule, so the pitch
#: acceleration it logs at a frame is the rate change over the next frame.
JSBSIM_FRAME_S = 1.0 / 120.0


#: Span of the quadratic fit a signal is reflected about at its ends [s].
ANCHOR_S = 0.25


@lru_cache(maxsize=64)
def _end_weights(m: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights giving, from ``m`` samples, a least-squares quadratic's value at the first and
    at the last of them (the fit is linear in the samples)."""
    v = np.vander(np.arange(m, dtype=float), 3)
    pinv = np.linalg.pinv(v)
    return v[0] @ pinv, v[-1] @ pinv


def odd_extension(x: np.ndarray, pad: int, anchor: int) -> np.ndarray:
    """``x`` with ``pad`` samples reflected oddly at each end, about the value a quadratic
    fitted to its first (last) ``anchor`` samples takes there.

    Reflecting about the end sample itself (scipy's ``padtype="odd"``) pins a
    zero-phase filter's output to that one noisy sample; the fit keeps a ramp a
    ramp (and a curve nearly one) without it. A 2-D ``x`` is extended along axis 0,
    each column on its own.
    """
    x = np.asarray(x, dtype=float)
    pad = min(pad, len(x) - 1)
    if pad <= 0:
        return x
    m = max(min(anchor, len(x)), 3)
    w_first, w_last = _end_weights(m)
    left = w_first @ x[:m]
    right = w_last @ x[-m:]
    return np.concatenate([2 * left - x[pad:0:-1], x, 2 * right - x[-2 : -pad - 2 : -1]])


def smooth_derivative(t: np.ndarray, x: np.ndarray, lead_s: float = 0.0) -> np.ndarray:
    """Derivative of a sampled signal [x units/s]: the interpolating quintic spline's,
    ``lead_s`` after each sample. A 2-D ``x`` gives each column's.

    Flat in gain and phase far above the 3 Hz where the identification's
    zero-phase low-pass cuts: that filter, applied to every coefficient before
    a fit, does the smoothing. The two together are the smoothing differentiator;
    before the filter the derivative holds the sensor noise, amplified. The
    spline runs through the signal extended 0.5 s beyond each end
    (:func:`odd_extension`): an interpolating spline's end conditions would
    amplify the end samples' noise a hundredfold.
    """
    t = np.asarray(t, dtype=float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    pad = min(int(round(0.5 / dt)), len(t) - 1)
    anchor = int(round(ANCHOR_S / dt))
    x = np.asarray(x, dtype=float)
    # columns (one spline solve for all) each extended on its own: the same numbers as one at a time
    xe = (
        odd_extension(x, pad, anchor)
        if x.ndim == 1
        else np.column_stack([odd_extension(np.ascontiguousarray(c), pad, anchor) for c in x.T])
    )
    te = np.concatenate([t[0] - dt * np.arange(pad, 0, -1), t, t[-1] + dt * np.arange(1, pad + 1)])
    k = min(5, len(xe) - 1 - (len(xe) % 2 == 0))
    return make_interp_spline(te, xe, k=k).derivative()(t + lead_s)


def pitch_acceleration(data: pd.DataFrame) -> np.ndarray:
    """Pitch acceleration [deg/s^2]: the ``qdot_dps2`` channel, or the derivative of ``q_dps``
    half a JSBSim frame ahead (:func:`smooth_derivative`)."""
    if "qdot_dps2" in data:
        return data["qdot_dps2"].to_numpy(dtype=float)
    return pitch_rate_derivative(data["t_s"].to_numpy(dtype=float), data["q_dps"].to_numpy(dtype=float))


def pitch_rate_derivative(t_s: np.ndarray, q_dps: np.ndarray) -> np.ndarray:
    """The pitch acceleration :func:`pitch_acceleration` takes from the pitch rate [deg/s^2]:
    ``q_dps`` [deg/s] one record (n,) or several of the same times as columns (n, k)."""
    return smooth_derivative(t_s, q_dps, 0.5 * JSBSIM_FRAME_S)


WIND_CHANNELS = ("vn_fps", "ve_fps", "vd_fps")


def measured_wind(data: pd.DataFrame) -> np.ndarray | None:
    """The wind's time history, north, east, down [ft/s], shape (N, 3); None without a logged
    inertial velocity, true airspeed, alpha or attitude (phi, theta, psi).

    The inertial velocity (``vn_fps``, ``ve_fps``, ``vd_fps``) minus the air-relative
    velocity: true airspeed, alpha and beta (0 if not logged) in the body axes, rotated to
    north-east-down by the logged attitude. The air data should be corrected first (the data
    compatibility: vane positions, biases, scales). What it cannot hold: rotational gusts
    (a gust gradient along the wing or fuselage is not a velocity at the CG), and the vanes'
    and pitot's own noise, which passes straight into it.
    """
    if not set(WIND_CHANNELS) | {"tas_kt", "alpha_deg", "theta_deg", "phi_deg", "psi_deg"} <= set(data.columns):
        return None  # without the whole attitude the air-relative velocity cannot be put in north-east-down
    a, b = _col(data, "alpha_deg", D2R), _col(data, "beta_deg", D2R)
    vt = _col(data, "tas_kt", FT_PER_KT)
    body = np.column_stack([vt * np.cos(a) * np.cos(b), vt * np.sin(b), vt * np.sin(a) * np.cos(b)])
    ph, th, ps = _col(data, "phi_deg", D2R), _col(data, "theta_deg", D2R), _col(data, "psi_deg", D2R)
    cph, sph, cth, sth, cps, sps = np.cos(ph), np.sin(ph), np.cos(th), np.sin(th), np.cos(ps), np.sin(ps)
    # body to north-east-down (the transpose of the 3-2-1 Euler rotation)
    rows = np.stack(
        [
            np.stack([cth * cps, sph * sth * cps - cph * sps, cph * sth * cps + sph * sps], axis=-1),
            np.stack([cth * sps, sph * sth * sps + cph * cps, cph * sth * sps - sph * cps], axis=-1),
            np.stack([-sth, sph * cth, cph * cth], axis=-1),
        ],
        axis=1,
    )
    air = np.einsum("nij,nj->ni", rows, body)
    return data[list(WIND_CHANNELS)].to_numpy(dtype=float) - air
