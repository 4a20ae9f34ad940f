"""The gain of an extension on held-out logs: coefficient residuals and replay errors, before and after.

Computation only: the replays are flown by the caller (``campaign diagnose`` flies both
aircraft from the same trimmed start with the recorded inputs) and handed in as frames.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from diagnose.config import current
from diagnose.residuals import COEFFS
from diagnose.result import Diagnosis
from identify.logs import Log

#: The channels a replay is compared on.
REPLAY_CHANNELS = ("theta_deg", "alpha_deg", "q_dps", "tas_kt", "alt_ft")
#: The controls a replay's trimmed start is compared on: its own trim against the measured one,
#: averaged over the first :data:`HEAD_S` (where an effect of the flight condition alone, a drag
#: at one Mach, shows: the replay re-trims it away from the time histories).
TRIM_CHANNELS = ("elevator_deg", "throttle_norm")
HEAD_S = 0.5
#: Every compared quantity: the time histories, then ``trim_<control>``.
COMPARED = REPLAY_CHANNELS + tuple(f"trim_{c}" for c in TRIM_CHANNELS)
#: What a difference of one unit is worth per compared quantity, to say which one an extension
#: moves most: Part 60's tolerances (gear change 2.c.4: pitch 1.5 deg, airspeed 3 kt, altitude
#: 100 ft; short period 2.c.6 and trim 2.a: alpha 1.5 deg, pitch rate 2 deg/s, pitch control
#: 1 deg, power 5 %).
SCALES = {"theta_deg": 1.5, "alpha_deg": 1.5, "q_dps": 2.0, "tas_kt": 3.0, "alt_ft": 100.0,
          "trim_elevator_deg": 1.0, "trim_throttle_norm": 0.05}


def on_log_times(flown: pd.DataFrame, t_s: np.ndarray, channels) -> np.ndarray:
    """A replay's channels at the log's sample times (linear between the simulation's steps),
    shape (N, len(channels)); NaN past the replay's end."""
    t = flown["t_s"].to_numpy()
    out = np.column_stack([np.interp(t_s, t, flown[ch].to_numpy()) for ch in channels])
    out[t_s > t[-1] + 1e-9] = np.nan
    return out


def _head(frame: pd.DataFrame, channel: str) -> float:
    return float(frame.loc[frame.t_s < frame.t_s.iloc[0] + HEAD_S, channel].mean())


def replay_errors(measured: pd.DataFrame, flown: pd.DataFrame | None) -> dict[str, float]:
    """Max |flown - measured| per :data:`REPLAY_CHANNELS` channel, compared at the log's sample
    times over what both cover, and |flown - measured| of the trimmed start's controls
    (``trim_<control>``, their means over the first :data:`HEAD_S`). NaN if the replay did not
    trim, or a control is not logged."""
    if flown is None:
        return {ch: float("nan") for ch in COMPARED}
    t = measured["t_s"].to_numpy()
    err = np.abs(on_log_times(flown, t, REPLAY_CHANNELS) - measured[list(REPLAY_CHANNELS)].to_numpy())
    out = {ch: float(np.nanmax(err[:, j])) for j, ch in enumerate(REPLAY_CHANNELS)}
    for c in TRIM_CHANNELS:
        out[f"trim_{c}"] = abs(_head(flown, c) - _head(measured, c)) \
            if c in flown and c in measured else float("nan")
    return out


def moved(model: pd.DataFrame | None, extended: pd.DataFrame | None, t_s: np.ndarray) -> dict[str, float]:
    """How far the extension moves a replay, per compared quantity, in units of :data:`SCALES`:
    max |extended - model| over the log's times (the trimmed start's controls for ``trim_``)."""
    if model is None or extended is None:
        return {ch: float("nan") for ch in COMPARED}
    d = np.abs(on_log_times(extended, t_s, REPLAY_CHANNELS) - on_log_times(model, t_s, REPLAY_CHANNELS))
    out = {ch: float(np.nanmax(d[:, j])) / SCALES[ch] for j, ch in enumerate(REPLAY_CHANNELS)}
    for c in TRIM_CHANNELS:
        out[f"trim_{c}"] = abs(_head(extended, c) - _head(model, c)) / SCALES[f"trim_{c}"] \
            if c in model and c in extended else float("nan")
    return out


def replay_table(held: list[Log], flown: dict[str, tuple], extended: bool) -> dict:
    """``{log file: {channel: {"model": max error, "extended": max error or None}}}`` for every
    held-out log (:func:`replay_errors`)."""
    out = {}
    for lg in held:
        fm, fx = flown[lg.path]
        em = replay_errors(lg.data, fm)
        ex = replay_errors(lg.data, fx) if extended else {}
        out[Path(lg.path).name] = {ch: {"model": em[ch], "extended": ex.get(ch)} for ch in COMPARED}
    return out


def exercised(frame: pd.DataFrame, variables: list[str], min_std: dict | None = None) -> list[int]:
    """Held-out logs (``log`` values of a residual frame) in which any of the cause's variables varies, by
    ``min_std`` (variable -> standard deviation in its unit; None: the settings', :func:`diagnose.config.current`;
    a diagnosis's are ``diag.settings.min_std``)."""
    min_std = current().min_std if min_std is None else min_std
    out = [int(i) for i, g in frame.groupby("log") if any(float(g[v].std()) >= min_std[v] for v in variables)]
    return out or sorted(int(i) for i in frame.log.unique())


def largest(frame: pd.DataFrame) -> list[int]:
    """The held-out logs with the largest residual RMS of each coefficient."""
    rms = frame.groupby("log")[[f"r_{c}" for c in COEFFS]].agg(lambda r: float(np.sqrt(np.mean(r ** 2))))
    return sorted({int(rms[col].idxmax()) for col in rms.columns})


def _with_gain(table: dict) -> dict:
    for v in table.values():
        v["gain"] = v["before"] / v["after"] if v["after"] > 0 else (float("nan") if np.isnan(v["after"])
                                                                     else float("inf"))
    return table


def residual_rms(before: pd.DataFrame, after: pd.DataFrame) -> dict:
    """Residual RMS of each coefficient before and after, and their ratio (``gain``)."""
    return _with_gain({c: {"before": float(np.sqrt(np.mean(before[f"r_{c}"] ** 2))),
                           "after": float(np.sqrt(np.mean(after[f"r_{c}"] ** 2)))} for c in COEFFS})


def measure_gain(diag: Diagnosis, held: list[Log], before: pd.DataFrame, after: pd.DataFrame,
                 flown: dict[str, tuple]) -> dict:
    """What ``diagnosis.json`` holds under ``gain``.

    Parameters
    ----------
    diag : Diagnosis
        With at least one aerodynamic cause.
    held : list of Log
        The held-out logs, as corrected.
    before, after : DataFrame
        Their residual data against the model and against the extended model.
    flown : dict
        Log path -> (replay on the model, replay on the extended model), frames or None.
    """
    first = diag.aero_causes[0]
    acting = exercised(before, first.variables, diag.settings.min_std)
    rms_acting = residual_rms(before[before.log.isin(acting)], after[after.log.isin(acting)])
    replays = {}
    for lg in held:
        fb, fa = flown[lg.path]
        eb, ea = replay_errors(lg.data, fb), replay_errors(lg.data, fa)
        replays[Path(lg.path).name] = {ch: {"before": eb[ch], "after": ea[ch]} for ch in COMPARED}
    worst = _with_gain({ch: {"before": _max(r[ch]["before"] for r in replays.values()),
                             "after": _max(r[ch]["after"] for r in replays.values())} for ch in COMPARED})
    where = [replays[Path(held[i].path).name] for i in acting]
    where_acts = _with_gain({ch: {"before": _max(r[ch]["before"] for r in where),
                                  "after": _max(r[ch]["after"] for r in where)} for ch in COMPARED})
    shifts = [moved(*flown[held[i].path], held[i].data["t_s"].to_numpy()) for i in acting]
    shift = {ch: _max(m[ch] for m in shifts) for ch in COMPARED}
    most = max((ch for ch in COMPARED if np.isfinite(shift[ch])), key=shift.get, default=None)
    return {"cause": first.label, "held_out_logs": [Path(lg.path).name for lg in held],
            "cause_exercised_in": [Path(held[i].path).name for i in acting],
            "residual_gain": rms_acting[first.coefficient]["gain"], "coefficient": first.coefficient,
            "residual_rms": rms_acting, "residual_rms_all_held_out": residual_rms(before, after),
            "replay_max_error": worst, "replay_where_acts": where_acts, "replay_per_log": replays,
            "replay_moved": shift, "replay_moved_most": most}


def _max(values) -> float:
    """The largest finite value (NaN if none)."""
    v = [x for x in values if x is not None and np.isfinite(x)]
    return max(v) if v else float("nan")
