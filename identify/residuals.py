"""Residuals: the measured coefficients minus the model's, at the measured states.

The model is evaluated by JSBSim at the raw measured states
(:mod:`identify.evaluate`), so a model checked against its own noise-free logs
leaves nothing. The measured pitching moment is moved to the model's
aerodynamic reference point (AERORP, where JSBSim applies the aero forces) with
the full x and z offset, so a lift or drag discrepancy does not leak into Cm.
Both sides and the candidate variables then pass through the identification's
zero-phase low-pass filter.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from identify.coefficients import D2R, FT_PER_KT, coefficients, thrust_share
from identify.evaluate import evaluator_for, in_chunks, moment_transfer
from identify.kinematics import angle_rates
from identify.logs import Log
from identify.models import EDGE_S, lowpass

COEFFS = ("CL", "CD", "Cm")
#: Candidate variables: log column (or derived quantity) -> JSBSim property of the model it maps to.
VARIABLES = {
    "gear_norm": "gear/gear-pos-norm",
    "alpha_deg": "aero/alpha-deg",
    "mach": "velocities/mach",
    "flap_deg": "fcs/flap-pos-deg",
    "elevator_deg": "fcs/elevator-pos-deg",
    "stabilizer_deg": "fcs/stabilizer-pos-deg",
    "qhat_rad": None,  # q cbar / 2V: aero/ci2vel * velocities/q-aero-rad_sec
    "adothat_rad": None,  # alpha-dot cbar / 2V: aero/ci2vel * aero/alphadot-rad_sec
    "CL": "aero/cl-squared",  # the measured lift coefficient; exported through CL^2
}
#: Sensor errors the kinematics cannot see, as residual signatures: log column -> (channel, error).
#: ``thrust_CD`` is d(CD measured)/d(relative thrust error): what an engine deck off by a factor
#: (1 + k) adds to the CD residual, per unit k (likewise for CL and Cm).
SIGNATURES = {"thrust": ("thrust_lbf", "scale")}
#: Time step of the delay signature's difference quotient [s].
DELAY_STEP_S = 0.05
#: Channels low-passed before they become variables (the gear and flap are not: they are set, not sensed).
FILTERED = ("alpha_deg", "mach", "elevator_deg", "stabilizer_deg", "qhat_rad", "adothat_rad", "CL")


def variables(data: pd.DataFrame, meta: dict, cl: np.ndarray, columns=VARIABLES) -> pd.DataFrame:
    """The candidate variables of one log, unfiltered: :func:`variable_arrays` as a frame indexed
    like ``data``."""
    return pd.DataFrame(variable_arrays(data, meta, cl, columns), index=data.index)


def variable_arrays(data: pd.DataFrame, meta: dict, cl: np.ndarray, columns=VARIABLES) -> dict[str, np.ndarray]:
    """The candidate variables of one log, unfiltered, one array each.

    Parameters
    ----------
    data : DataFrame
        A log in the schema.
    meta : dict
        Its metadata (``geometry.cbar_ft``).
    cl : ndarray
        Its measured lift coefficient [-].
    columns : iterable of str
        The variables wanted (default all of :data:`VARIABLES`).
    """
    half_chord_over_v = meta["geometry"]["cbar_ft"] / (2.0 * data["tas_kt"].to_numpy() * FT_PER_KT)
    out = {v: data[v].to_numpy(dtype=float) for v in columns if v in data.columns}
    if "qhat_rad" in columns:
        out["qhat_rad"] = data["q_dps"].to_numpy() * D2R * half_chord_over_v
    if "adothat_rad" in columns:
        out["adothat_rad"] = angle_rates(data)[0] * half_chord_over_v
    if "CL" in columns:
        out["CL"] = np.asarray(cl, dtype=float)
    return out


def measured_about(coef: pd.DataFrame, meta: dict, evaluator) -> pd.DataFrame:
    """Measured CL, CD and Cm in the model's reference, Cm about the model's AERORP
    (:func:`measured_arrays` as a frame indexed like ``coef``)."""
    return pd.DataFrame(measured_arrays(coef, meta, evaluator), index=coef.index)


def measured_arrays(coef, meta: dict, evaluator) -> dict[str, np.ndarray]:
    """Measured CL, CD and Cm in the model's reference, Cm about the model's AERORP, one array each.

    ``coef`` maps ``CL``, ``CD``, ``Cm``, ``Cx``, ``Cz`` to arrays or columns
    (:func:`identify.coefficients.coefficient_arrays`). The log's own area and chord are
    converted to the model's; the moment moves from the log's CG (the model's CG if the log
    does not give one) to the model's AERORP, with the full x and z offset.
    """
    g = meta["geometry"]
    k = g["S_ft2"] / evaluator.S
    cg_x, cg_z = g.get("cg_x_in", evaluator.cg_in[0]), g.get("cg_z_in", evaluator.cg_in[2])
    cm = np.asarray(coef["Cm"]) * k * g["cbar_ft"] / evaluator.cbar
    cm = moment_transfer(cm, np.asarray(coef["Cx"]) * k, np.asarray(coef["Cz"]) * k,
                         evaluator.aerorp_in[0] - cg_x, evaluator.aerorp_in[2] - cg_z, evaluator.cbar)
    return {"CL": np.asarray(coef["CL"]) * k, "CD": np.asarray(coef["CD"]) * k, "Cm": cm}


def signatures(data: pd.DataFrame, meta: dict, evaluator) -> pd.DataFrame:
    """What a relative thrust error adds to each measured coefficient, per unit error.

    Eq. (1) is linear in the thrust: the thrust's own share is exactly that.
    """
    moved = measured_about(thrust_share(data, meta), meta, evaluator)
    return pd.DataFrame({f"thrust_{c}": moved[c].to_numpy() for c in COEFFS}, index=data.index)


def delay_signature(data: pd.DataFrame, evaluator, cl: np.ndarray, model: pd.DataFrame,
                    channel: str = "alpha_deg") -> pd.DataFrame:
    """What a time shift of ``channel`` adds to each residual, per second of delay [1/s].

    A vane ``tau`` late reads ``x(t - tau)``; the model evaluated there misses
    ``C(x(t)) - C(x(t - tau))``, about ``tau`` times the model's change when the
    channel is read :data:`DELAY_STEP_S` earlier, over that step.
    """
    t = data["t_s"].to_numpy(dtype=float)
    early = data.copy()
    early[channel] = np.interp(t + DELAY_STEP_S, t, data[channel].to_numpy(dtype=float))
    moved = evaluator.predict(early, cl)
    head = channel.split("_")[0] + "delay"
    return pd.DataFrame({f"{head}_{c}": (moved[c].to_numpy() - model[c].to_numpy()) / DELAY_STEP_S for c in COEFFS},
                        index=data.index)


def smooth(frame: pd.DataFrame, dt: float, columns) -> pd.DataFrame:
    out = frame.copy()
    cols = [c for c in columns if c in out]
    if cols:
        out[cols] = lowpass(out[cols].to_numpy(dtype=float), dt)
    return out


#: Residual data keep about this many samples per second (the filter leaves nothing above 3 Hz).
KEEP_HZ = 60.0


def kept(n: int, dt: float, step: int | None = None) -> np.ndarray:
    """Indices of the samples residual data keep: 0.25 s dropped at both ends (the filter's
    start-up), then every ``step``-th (default: about :data:`KEEP_HZ` per second)."""
    step = step or max(1, int(round(1.0 / (KEEP_HZ * dt))))
    edge = int(round(EDGE_S / dt))
    return np.arange(edge, n - edge, step)


def residual_data(logs: list[Log], evaluator, step: int | None = None, delays: tuple = ()) -> pd.DataFrame:
    """Measured minus model coefficients at the measured states, for every log.

    The logs are spread over ``evaluator.jobs`` worker processes, each with its own
    JSBSim evaluation of the same model (:func:`identify.evaluate.evaluator_for`);
    see :func:`_residual_data` for the rest.
    """
    if getattr(evaluator, "jobs", 1) <= 1:
        return _residual_data(logs, evaluator, step, delays)
    return pd.concat(in_chunks(_remote_residual_data, list(enumerate(logs)), evaluator.jobs, evaluator.model_dir,
                               step, delays), ignore_index=True)


def _remote_residual_data(numbered: list[tuple[int, Log]], model_dir: Path, step: int | None,
                          delays: tuple) -> list[pd.DataFrame]:
    return [_residual_data([lg for _, lg in numbered], evaluator_for(model_dir), step, delays, numbered[0][0])]


def _residual_data(logs: list[Log], evaluator, step: int | None = None, delays: tuple = (),
                   offset: int = 0) -> pd.DataFrame:
    """Measured minus model coefficients at the measured states, for every log.

    The model is evaluated at the raw measured states (exact on noise-free
    data); the measured and model coefficients and the variables then pass
    through the zero-phase low-pass filter of the identification, 0.25 s is
    dropped at both ends, and every ``step``-th sample is kept (:func:`kept`).

    Returns
    -------
    DataFrame
        One row per sample: ``log`` (index into ``logs``, plus ``offset``), ``t_s``, the
        variables, measured ``CL``/``CD``/``Cm``, the model's ``model_CL``...
        and residuals ``r_CL``/``r_CD``/``r_Cm`` (Cm about the model's AERORP); for each
        channel in ``delays``, its time-shift signature (:func:`delay_signature`).
    """
    frames = []
    for i, log in enumerate(logs):
        d = log.data
        dt = float(np.median(np.diff(d["t_s"])))
        meas = measured_about(coefficients(d, log.meta), log.meta, evaluator)
        cl = meas["CL"].to_numpy()
        pred = evaluator.predict(d, cl)
        both = pd.concat([meas, pred.add_prefix("model_")], axis=1)
        both = smooth(both, dt, both.columns)
        var = smooth(variables(d, log.meta, cl), dt, FILTERED)
        sig = signatures(d, log.meta, evaluator)
        for ch in delays:
            sig = pd.concat([sig, delay_signature(d, evaluator, cl, pred, ch)], axis=1)
        sig = smooth(sig, dt, sig.columns)
        keep = kept(len(d), dt, step)
        out = pd.DataFrame({"log": offset + i, "t_s": d["t_s"].to_numpy()[keep], "maneuver": log.maneuver, "point": log.point})
        for v in VARIABLES:
            out[v] = var[v].to_numpy()[keep]
        for c in sig.columns:
            out[c] = sig[c].to_numpy()[keep]
        for c in COEFFS:
            out[f"model_{c}"] = both[f"model_{c}"].to_numpy()[keep]
            out[f"meas_{c}"] = both[c].to_numpy()[keep]
            out[f"r_{c}"] = out[f"meas_{c}"] - out[f"model_{c}"]
        frames.append(out)
    return pd.concat(frames, ignore_index=True)


