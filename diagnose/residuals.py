"""Residuals: the measured coefficients minus the model's, at the measured states.

The model is evaluated by JSBSim at the raw measured states
(:mod:`diagnose.evaluate`), so a model checked against its own noise-free logs
leaves nothing. The measured pitching moment is moved to the model's
aerodynamic reference point (AERORP, where JSBSim applies the aero forces) with
the full x and z offset, so a lift or drag discrepancy does not leak into Cm.
Both sides and the candidate variables then pass through the identification's
zero-phase low-pass filter.
"""

from __future__ import annotations


import numpy as np
import pandas as pd

from identify.coefficients import D2R, FT_PER_KT, coefficient_arrays, thrust_share
from diagnose.evaluate import by_log_chunks, moment_transfer
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
    "CL": "aero/cl-squared",  # the model's lift coefficient at the measured states; exported through CL^2
}
#: The regressor CL is the model's, not the measured one: measured lift carries what turbulence and the
#: vane's view of it leave in the residuals (gust lift the model does not see at the vane's alpha), and a
#: drag or moment residual regressed on it found that leak: "CD vs CL" on stock-737 nulls in 3 ft/s with
#: a 4.6 % vane scale, "Cm vs CL" for a moment change in alpha.
#: Sensor errors the kinematics cannot see, as residual signatures: log column -> (channel, error).
#: ``thrust_CD`` is d(CD measured)/d(relative thrust error): what an engine deck off by a factor
#: (1 + k) adds to the CD residual, per unit k (likewise for CL and Cm).
SIGNATURES = {"thrust": ("thrust_lbf", "scale")}
#: Time step of the delay signature's difference quotient [s].
DELAY_STEP_S = 0.05
#: Channels low-passed before they become variables (the gear and flap are not: they are set, not sensed).
FILTERED = ("alpha_deg", "mach", "elevator_deg", "stabilizer_deg", "qhat_rad", "adothat_rad", "CL")


def variable_arrays(data: pd.DataFrame, meta: dict, cl: np.ndarray, columns=VARIABLES) -> dict[str, np.ndarray]:
    """The candidate variables of one log, unfiltered, one array each.

    Parameters
    ----------
    data : DataFrame
        A log in the schema.
    meta : dict
        Its metadata (``geometry.cbar_ft``).
    cl : ndarray
        The model's lift coefficient at its measured states [-] (the regressor CL).
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
    cm = moment_transfer(
        cm,
        np.asarray(coef["Cx"]) * k,
        np.asarray(coef["Cz"]) * k,
        evaluator.aerorp_in[0] - cg_x,
        evaluator.aerorp_in[2] - cg_z,
        evaluator.cbar,
    )
    return {"CL": np.asarray(coef["CL"]) * k, "CD": np.asarray(coef["CD"]) * k, "Cm": cm}


def signature_arrays(data: pd.DataFrame, meta: dict, evaluator) -> dict[str, np.ndarray]:
    """What a relative thrust error adds to each measured coefficient, per unit error:
    ``thrust_CL``, ``thrust_CD``, ``thrust_Cm``, one array each.

    Eq. (1) is linear in the thrust: the thrust's own share is exactly that.
    """
    moved = measured_arrays(thrust_share(data, meta), meta, evaluator)
    return {f"thrust_{c}": moved[c] for c in COEFFS}


def delay_signature(
    data: pd.DataFrame, evaluator, cl: np.ndarray, model: np.ndarray, channel: str = "alpha_deg"
) -> dict[str, np.ndarray]:
    """What a time shift of ``channel`` adds to each residual, per second of delay [1/s].

    A vane ``tau`` late reads ``x(t - tau)``; the model evaluated there misses
    ``C(x(t)) - C(x(t - tau))``, about ``tau`` times the model's change when the
    channel is read :data:`DELAY_STEP_S` earlier, over that step.

    Parameters
    ----------
    data : DataFrame
        A log in the schema.
    evaluator : ModelEvaluator
    cl : ndarray
        The model's lift coefficient at its measured states [-] (the regressor CL).
    model : ndarray
        The model's CL, CD, Cm at its rows, (n, 3) [-].
    channel : str

    Returns
    -------
    dict
        ``<head>delay_CL``, ``_CD``, ``_Cm`` [1/s] (head: the channel's name up to its first ``_``).
    """
    t = data["t_s"].to_numpy(dtype=float)
    early = data.copy(deep=False)
    early[channel] = np.interp(t + DELAY_STEP_S, t, data[channel].to_numpy(dtype=float))
    moved = evaluator.evaluate_array(evaluator.inputs(early, cl))
    head = channel.split("_")[0] + "delay"
    return {f"{head}_{c}": (moved[:, j] - model[:, j]) / DELAY_STEP_S for j, c in enumerate(COEFFS)}


def _lowpassed(arrays: dict[str, np.ndarray], names, dt: float) -> dict[str, np.ndarray]:
    """``arrays[name]`` of each of ``names`` through :func:`lowpass`, in one call. The columns are
    stacked column-major, as a frame's ``to_numpy`` gives them: the filter's last bits depend on it."""
    names = list(names)
    return dict(zip(names, lowpass(np.array([arrays[v] for v in names], dtype=float).T, dt).T)) if names else {}


#: Residual data keep about this many samples per second (the filter leaves nothing above 3 Hz).
KEEP_HZ = 60.0


def kept(n: int, dt: float, step: int | None = None) -> np.ndarray:
    """Indices of the samples residual data keep: 0.25 s dropped at both ends (the filter's
    start-up), then every ``step``-th (default: about :data:`KEEP_HZ` per second)."""
    step = step or max(1, int(round(1.0 / (KEEP_HZ * dt))))
    edge = int(round(EDGE_S / dt))
    return np.arange(edge, n - edge, step)


def residual_data(
    logs: list[Log], evaluator, step: int | None = None, delays: tuple = (), wait: bool = True, correct=None
):
    """Measured minus model coefficients at the measured states, for every log.

    The logs are evaluated in chunks spread over ``evaluator.jobs`` worker processes, each
    with its own JSBSim evaluation of the same model (:func:`diagnose.evaluate.by_log_chunks`:
    the numbers do not depend on how many); see :func:`_residual_data` for the rest. With ``wait=False`` a callable that returns
    the frame comes back instead: the workers start at once and the caller goes on meanwhile
    (with one job the frame is computed when it is called). ``correct`` (a log -> log
    callable that pickles, such as :meth:`identify.compat.CompatResult.correct`), if given,
    is applied to each log first, where its residuals are computed.
    """
    if not logs:
        raise ValueError("no logs to compute residuals of")
    parts = by_log_chunks(
        _chunk_residual_data,
        list(enumerate(logs)),
        evaluator,
        getattr(evaluator, "jobs", 1),
        step,
        delays,
        correct,
        wait=wait,
    )
    return pd.concat(parts, ignore_index=True) if wait else (lambda: pd.concat(parts(), ignore_index=True))


def _chunk_residual_data(
    numbered: list[tuple[int, Log]], evaluator, step: int | None, delays: tuple, correct
) -> list[pd.DataFrame]:
    return [_residual_data([lg for _, lg in numbered], evaluator, step, delays, numbered[0][0], correct)]


def _residual_data(
    logs: list[Log], evaluator, step: int | None = None, delays: tuple = (), offset: int = 0, correct=None
) -> pd.DataFrame:
    """Measured minus model coefficients at the measured states, for every log
    (each through ``correct`` first, if given).

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
    parts: dict[str, list[np.ndarray]] = {}
    for i, log in enumerate(logs):
        log = correct(log) if correct is not None else log
        d = log.data
        t = d["t_s"].to_numpy()
        dt = float(np.median(np.diff(t)))
        meas = measured_arrays(coefficient_arrays(d, log.meta), log.meta, evaluator)
        cl = meas["CL"]
        pred = evaluator.evaluate_array(evaluator.inputs(d, cl))
        both = _lowpassed(
            {**meas, **{f"model_{c}": pred[:, j] for j, c in enumerate(COEFFS)}},
            [*COEFFS, *(f"model_{c}" for c in COEFFS)],
            dt,
        )
        var = variable_arrays(d, log.meta, pred[:, 0])
        var.update(_lowpassed(var, [v for v in FILTERED if v in var], dt))
        sig = signature_arrays(d, log.meta, evaluator)
        for ch in delays:
            sig.update(delay_signature(d, evaluator, cl, pred, ch))
        sig = _lowpassed(sig, sig, dt)
        keep = kept(len(d), dt, step)
        row = {
            "log": np.full(len(keep), offset + i),
            "t_s": t[keep],
            "maneuver": np.full(len(keep), log.maneuver, dtype=object),
            "point": np.full(len(keep), log.point, dtype=object),
        }
        row.update((v, var[v][keep]) for v in VARIABLES)
        row.update((c, x[keep]) for c, x in sig.items())
        for c in COEFFS:
            row[f"model_{c}"] = both[f"model_{c}"][keep]
            row[f"meas_{c}"] = both[c][keep]
            row[f"r_{c}"] = row[f"meas_{c}"] - row[f"model_{c}"]
        for c, x in row.items():
            parts.setdefault(c, []).append(x)
    if not parts:
        raise ValueError("no logs to compute residuals of")
    return pd.DataFrame({c: np.concatenate(xs) for c, xs in parts.items()})
