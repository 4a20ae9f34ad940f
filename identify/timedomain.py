"""Eq. (3) point models by output error or filter error: ``campaign identify --method oe|fe``.

The equation-error fit of a 2-3-1-1 (:func:`identify.models.fit_baseline`) gives the
regressors that were excited and the starting values. The same parameters are then
estimated by integrating the rigid-body longitudinal equations (states V, alpha, theta, q;
elevator, stabilizer and thrust as inputs) against the measured V, alpha, theta, q, ax and az
(:mod:`identify.estimators`). The physics are eq. (1)'s: thrust along the body x axis on its
documented line, the aerodynamic moment about the CG, the log's mass and inertia. The
record is low-passed as eq. (3)'s data are and resampled to 10 Hz.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from identify.coefficients import FT_PER_KT, coefficients
from identify.estimators import OutputError, Record
from identify.estimators.filtererror import FilterError
from identify.estimators.models import Airframe, longitudinal
from identify.kinematics import effective_gravity
from identify.logs import Log
from identify.models import COEFFS, EDGE_S, PointFit, sample_interval, filtered_frame, lowpass, regressors

METHODS = ("ee", "oe", "fe")
RATE_HZ = 10.0
D2R = np.pi / 180.0
#: eq. (3) regressors as the longitudinal model names them
MODEL_REGRESSOR = {"const": "1", "dalpha_rad": "alpha", "qhat_rad": "qhat_v", "delevator_rad": "elevator_rad",
                   "dstabilizer_rad": "stabilizer_rad", "dmach": "mach", "dalpha2_rad2": "alpha2"}
OUTPUTS = ("V", "alpha_rad", "theta_rad", "q_rps", "ax", "az")
#: starting process-noise standard deviations of V [ft/s^1.5], alpha, theta [rad/s^0.5], q [rad/s^1.5]
F0 = (0.5, 0.002, 0.0005, 0.002)


def _record(log: Log) -> tuple[Record, dict]:
    d = log.data
    dt = sample_interval(log)
    step = max(1, int(round(1.0 / (RATE_HZ * dt))))
    cols = {"V": d["tas_kt"] * FT_PER_KT, "alpha_rad": d["alpha_deg"] * D2R, "theta_rad": d["theta_deg"] * D2R,
            "q_rps": d["q_dps"] * D2R, "ax": d["ax_fps2"], "az": d["az_fps2"],
            "elevator_rad": d["elevator_deg"] * D2R, "stabilizer_rad": d["stabilizer_deg"] * D2R,
            "thrust": d["thrust_lbf"]}
    frame = pd.DataFrame({k: np.asarray(v, dtype=float) for k, v in cols.items()})
    smooth = pd.DataFrame(lowpass(frame.to_numpy(), dt), columns=frame.columns).iloc[::step]
    rho = float(np.median(2.0 * d["qbar_psf"] / (d["tas_kt"] * FT_PER_KT) ** 2))
    sound = float(np.median(d["tas_kt"] * FT_PER_KT / d["mach"]))
    u = np.column_stack([smooth["elevator_rad"], smooth["stabilizer_rad"], smooth["thrust"],
                         np.full(len(smooth), sound)])
    z = smooth[list(OUTPUTS)].to_numpy()
    rec = Record(u, z, dt * step, z[0, :4], name=log.point, t_s=d["t_s"].to_numpy()[::step])
    return rec, {"rho": rho, "sound_fps": sound}


def point_model(log: Log, fit: PointFit):
    """The longitudinal model of one log and the eq. (3) regressors its equation-error fit kept."""
    rec, atm = _record(log)
    g, inertia = log.meta["geometry"], log.meta["inertia_slugft2"]
    ref = fit.reference
    airframe = Airframe(mass=float(log.data["mass_slug"].mean()), area=g["S_ft2"], chord=g["cbar_ft"],
                        iyy=inertia["iyy"], v0=float(rec.z[:, 0].mean()), thrust_angle_rad=0.0,
                        thrust_arm=-g.get("thrust_z_arm_ft", 0.0), g=effective_gravity(log.data))
    terms = {c: [MODEL_REGRESSOR[r] for r in fit.fits[c].params.index] for c in COEFFS}
    offsets = {"alpha_rad": ref.alpha_deg * D2R, "elevator_rad": ref.elevator_deg * D2R,
               "stabilizer_rad": ref.stabilizer_deg * D2R, "mach": ref.mach, "rho": atm["rho"]}
    model = longitudinal(airframe, terms, inputs=("elevator_rad", "stabilizer_rad", "thrust", "a"),
                         offsets=offsets, outputs=OUTPUTS)
    start = {f"{c}{'0' if MODEL_REGRESSOR[r] == '1' else MODEL_REGRESSOR[r]}": float(v)
             for c in COEFFS for r, v in fit.fits[c].params.items()}
    return model, rec, start


def refine_point(log: Log, fit: PointFit, method: str) -> PointFit:
    """The eq. (3) fit of ``log`` re-estimated by output error (``oe``) or filter error (``fe``).

    The per-coefficient results keep the equation-error shape (so the linear and nonlinear
    gear models follow from these estimates unchanged): parameters, ``bse`` the bound
    corrected for coloured residuals, ``bse_white`` the Cramér-Rao bound, and the
    coefficient residuals the estimates leave on the measured eq. (1) coefficients. When the
    estimator fails outright the equation-error fit is kept, marked ``method="ee"`` and not
    converged.
    """
    if method == "ee":
        return fit
    model, rec, start = point_model(log, fit)
    # a record can start slightly off trim: the initial states are estimated, and the
    # accelerometers may keep a bias the data compatibility left
    if method == "oe":
        est = OutputError(model, [rec], start, x0_free=model.states, biases=("ax", "az"))
    elif method == "fe":
        est = FilterError(model, [rec], start, F0)
    else:
        raise ValueError(f"method must be one of {METHODS}, not {method!r}")
    try:
        res = est.fit()
    except (ValueError, np.linalg.LinAlgError):  # the integration left the model's domain from the start
        res = None
    if res is None or not np.all(np.isfinite(res.params)):
        return replace(fit, fits={c: replace(r, converged=False) for c, r in fit.fits.items()})
    edge = int(round(EDGE_S / sample_interval(log)))
    inner = slice(edge, len(log.data) - edge)
    y = filtered_frame(log, coefficients(log.data, log.meta)).iloc[inner]
    x = filtered_frame(log, regressors(log, fit.reference)).iloc[inner]
    fits = {}
    for c in COEFFS:
        old = fit.fits[c]
        names = [f"{c}{'0' if MODEL_REGRESSOR[r] == '1' else MODEL_REGRESSOR[r]}" for r in old.params.index]
        params = pd.Series(res.params[names].to_numpy(), index=old.params.index)
        fitted = x[old.params.index].to_numpy() @ params.to_numpy()
        resid = y[c].to_numpy() - fitted
        ss_tot = float(np.sum((y[c] - y[c].mean()) ** 2))
        bse = pd.Series(res.bse_coloured[names].to_numpy(), index=old.params.index)
        # C0 is about the reference state, itself a mean of measured samples (as fit_baseline has it)
        extra = sum((params[r] * se) ** 2 for r, se in fit.reference.se if r in params.index)
        bse["const"] = float(np.sqrt(bse["const"] ** 2 + extra))
        fits[c] = replace(old, params=params,
                          bse=bse,
                          bse_white=pd.Series(res.bse[names].to_numpy(), index=old.params.index),
                          resid=resid, fitted=fitted, y=y[c].to_numpy(),
                          rsquared=1.0 - float(resid @ resid) / ss_tot if ss_tot > 0 else float("nan"),
                          cov=None, method=method, converged=res.converged)
    return replace(fit, fits=fits)
