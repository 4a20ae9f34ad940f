"""The gain of an extension on held-out logs: coefficient residuals and replay errors, before and after.

Computation only: the replays are flown by the caller (``campaign diagnose`` flies both
aircraft from the same trimmed start with the recorded inputs) and handed in as frames.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from diagnose.residuals import COEFFS
from diagnose.result import Diagnosis
from diagnose.terms import MIN_STD
from identify.logs import Log

#: The channels a replay is compared on.
REPLAY_CHANNELS = ("theta_deg", "alpha_deg", "q_dps", "tas_kt", "alt_ft")


def on_log_times(flown: pd.DataFrame, t_s: np.ndarray, channels) -> np.ndarray:
    """A replay's channels at the log's sample times (linear between the simulation's steps),
    shape (N, len(channels)); NaN past the replay's end."""
    t = flown["t_s"].to_numpy()
    out = np.column_stack([np.interp(t_s, t, flown[ch].to_numpy()) for ch in channels])
    out[t_s > t[-1] + 1e-9] = np.nan
    return out


def replay_errors(measured: pd.DataFrame, flown: pd.DataFrame | None) -> dict[str, float]:
    """Max |flown - measured| per :data:`REPLAY_CHANNELS` channel, compared at the log's sample
    times over what both cover (NaN if the replay did not trim)."""
    if flown is None:
        return {ch: float("nan") for ch in REPLAY_CHANNELS}
    t = measured["t_s"].to_numpy()
    err = np.abs(on_log_times(flown, t, REPLAY_CHANNELS) - measured[list(REPLAY_CHANNELS)].to_numpy())
    return {ch: float(np.nanmax(err[:, j])) for j, ch in enumerate(REPLAY_CHANNELS)}


def replay_table(held: list[Log], flown: dict[str, tuple], extended: bool) -> dict:
    """``{log file: {channel: {"model": max error, "extended": max error or None}}}`` for every
    held-out log (:func:`replay_errors`)."""
    out = {}
    for lg in held:
        fm, fx = flown[lg.path]
        em = replay_errors(lg.data, fm)
        ex = replay_errors(lg.data, fx) if extended else {}
        out[Path(lg.path).name] = {ch: {"model": em[ch], "extended": ex.get(ch)} for ch in REPLAY_CHANNELS}
    return out


def exercised(frame: pd.DataFrame, variables: list[str]) -> list[int]:
    """Held-out logs (``log`` values of a residual frame) in which any of the cause's variables varies."""
    out = [int(i) for i, g in frame.groupby("log") if any(float(g[v].std()) >= MIN_STD[v] for v in variables)]
    return out or sorted(int(i) for i in frame.log.unique())


def largest(frame: pd.DataFrame) -> list[int]:
    """The held-out logs with the largest residual RMS of each coefficient."""
    rms = frame.groupby("log")[[f"r_{c}" for c in COEFFS]].agg(lambda r: float(np.sqrt(np.mean(r ** 2))))
    return sorted({int(rms[col].idxmax()) for col in rms.columns})


def _with_gain(table: dict) -> dict:
    for v in table.values():
        v["gain"] = v["before"] / v["after"] if v["after"] > 0 else float("inf")
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
    acting = exercised(before, first.variables)
    rms_acting = residual_rms(before[before.log.isin(acting)], after[after.log.isin(acting)])
    replays = {}
    for lg in held:
        fb, fa = flown[lg.path]
        eb, ea = replay_errors(lg.data, fb), replay_errors(lg.data, fa)
        replays[Path(lg.path).name] = {ch: {"before": eb[ch], "after": ea[ch]} for ch in REPLAY_CHANNELS}
    worst = _with_gain({ch: {"before": max(r[ch]["before"] for r in replays.values()),
                             "after": max(r[ch]["after"] for r in replays.values())} for ch in REPLAY_CHANNELS})
    where = [replays[Path(held[i].path).name] for i in acting]
    where_acts = _with_gain({ch: {"before": max(r[ch]["before"] for r in where),
                                  "after": max(r[ch]["after"] for r in where)} for ch in REPLAY_CHANNELS})
    return {"cause": first.label, "held_out_logs": [Path(lg.path).name for lg in held],
            "cause_exercised_in": [Path(held[i].path).name for i in acting],
            "residual_gain": rms_acting[first.coefficient]["gain"], "coefficient": first.coefficient,
            "residual_rms": rms_acting, "residual_rms_all_held_out": residual_rms(before, after),
            "replay_max_error": worst, "replay_where_acts": where_acts, "replay_per_log": replays}
