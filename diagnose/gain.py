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
from diagnose.windows import gear_start_s, quiet_head_s
from identify.logs import Log

#: The channels a replay is compared on.
REPLAY_CHANNELS = ("theta_deg", "alpha_deg", "q_dps", "tas_kt", "alt_ft")
#: The controls a replay's trimmed start is compared on: its own trim against the measured one,
#: averaged over the first :data:`HEAD_S` (where an effect of the flight condition alone, a drag
#: at one Mach, shows), the thrust in percent of the measured one.
TRIM_CHANNELS = ("elevator_deg", "thrust_pct")
HEAD_S = 0.5
#: Every compared quantity: the time histories, then ``trim_<control>``.
COMPARED = REPLAY_CHANNELS + tuple(f"trim_{c}" for c in TRIM_CHANNELS)
#: What a difference of one unit is worth per compared quantity, to say which one an extension
#: moves most, and the tolerances a replay is judged by: Part 60's (gear change 2.c.4: pitch 1.5 deg,
#: airspeed 3 kt, altitude 100 ft; short period 2.c.6 and trim 2.a: alpha 1.5 deg, pitch rate 2 deg/s,
#: pitch control 1 deg, power 5 %).
SCALES = {
    "theta_deg": 1.5,
    "alpha_deg": 1.5,
    "q_dps": 2.0,
    "tas_kt": 3.0,
    "alt_ft": 100.0,
    "trim_elevator_deg": 1.0,
    "trim_thrust_pct": 5.0,
}
#: Replays and data are compared low-passed here [Hz]: the replays fly in the measured wind low-passed
#: at the same frequency (:data:`campaign.diagnosis.run.WIND_CUTOFF_HZ`), and what lies above it in the
#: data (sensor noise, the gusts' fastest part) no replay can follow.
COMPARE_CUTOFF_HZ = 2.0
#: The Part 60 gear-change window: from this long before the gear starts to move to this long after [s].
GEAR_WINDOW_S = (5.0, 15.0)


def on_log_times(flown: pd.DataFrame, t_s: np.ndarray, channels) -> np.ndarray:
    """A replay's channels at the log's sample times (linear between the simulation's steps),
    shape (N, len(channels)); NaN past the replay's end."""
    t = flown["t_s"].to_numpy()
    out = np.column_stack([np.interp(t_s, t, flown[ch].to_numpy()) for ch in channels])
    out[t_s > t[-1] + 1e-9] = np.nan
    return out


def _head(frame: pd.DataFrame, channel: str) -> float:
    """The mean of ``channel`` over the first :data:`HEAD_S` of ``frame``, NaN left out (as pandas has it)."""
    t = frame["t_s"].to_numpy(dtype=float)
    x = frame[channel].to_numpy(dtype=float)[t < t[0] + HEAD_S]
    known = ~np.isnan(x)
    n = int(known.sum())
    return float(np.where(known, x, 0.0).sum() / n) if n else float("nan")


def _trim_difference(flown: pd.DataFrame, measured: pd.DataFrame, c: str) -> float:
    if c == "thrust_pct":
        if "thrust_lbf" not in flown or "thrust_lbf" not in measured:
            return float("nan")
        ref = _head(measured, "thrust_lbf")
        return 100.0 * abs(_head(flown, "thrust_lbf") - ref) / abs(ref) if ref else float("nan")
    return abs(_head(flown, c) - _head(measured, c)) if c in flown and c in measured else float("nan")


def replay_window(measured: pd.DataFrame) -> tuple[float, float, str]:
    """The span a replay is judged over [s of the log's time] and what it is: a gear transition's Part 60
    window (:data:`GEAR_WINDOW_S` about the gear's first movement), else the manoeuvre (from where its
    inputs start, the end of the quiet head, to the end of the log)."""
    t = measured["t_s"].to_numpy(dtype=float)
    g = gear_start_s(measured)
    if g is not None:
        lo, hi = t[0] + g - GEAR_WINDOW_S[0], t[0] + g + GEAR_WINDOW_S[1]
        return (
            float(max(lo, t[0])),
            float(min(hi, t[-1])),
            "Part 60 gear change (5 s before to 15 s after the gear moves)",
        )
    head = quiet_head_s(measured)
    return float(t[0] + (head if head < t[-1] - t[0] else 0.0)), float(t[-1]), "the manoeuvre (from its first input)"


def compared(measured: pd.DataFrame, flown: pd.DataFrame) -> np.ndarray:
    """|flown - measured| per :data:`REPLAY_CHANNELS` channel at the log's sample times, both low-passed at
    :data:`COMPARE_CUTOFF_HZ` (NaN past the replay's end), shape (N, 5)."""
    from identify.models import lowpass

    t = measured["t_s"].to_numpy(dtype=float)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    m = measured[list(REPLAY_CHANNELS)].to_numpy(dtype=float, copy=True)
    f = on_log_times(flown, t, REPLAY_CHANNELS)
    cover = np.isfinite(f[:, 0])
    if 2.0 * COMPARE_CUTOFF_HZ * dt < 0.9 and cover.sum() > 30:  # the filter only where it cuts
        m[cover] = lowpass(m[cover], dt, COMPARE_CUTOFF_HZ)
        f[cover] = lowpass(f[cover], dt, COMPARE_CUTOFF_HZ)
    return np.abs(f - m)


def replay_errors(
    measured: pd.DataFrame, flown: pd.DataFrame | None, window: tuple | None = None, unmeasured=()
) -> dict[str, float]:
    """Max |flown - measured| per :data:`REPLAY_CHANNELS` channel, compared at the log's sample
    times over what both cover (:func:`compared`; only within ``window``, ``(from_s, to_s)``, if
    given), and |flown - measured| of the trimmed start's controls (``trim_<control>``, their means
    over the first :data:`HEAD_S`; the thrust in percent of the measured). NaN if the replay did not
    fly, or a control is not logged, and for the channels in ``unmeasured`` (:func:`unmeasured`)."""
    if flown is None:
        return {ch: float("nan") for ch in COMPARED}
    err = compared(measured, flown)
    if window is not None:
        t = measured["t_s"].to_numpy(dtype=float)
        err = err[(t >= window[0] - 1e-9) & (t <= window[1] + 1e-9)]
    out = {
        ch: float(np.nanmax(err[:, j])) if np.isfinite(err[:, j]).any() and ch not in unmeasured else float("nan")
        for j, ch in enumerate(REPLAY_CHANNELS)
    }
    for c in TRIM_CHANNELS:
        out[f"trim_{c}"] = _trim_difference(flown, measured, c)
    return out


def moved(model: pd.DataFrame | None, extended: pd.DataFrame | None, t_s: np.ndarray) -> dict[str, float]:
    """How far the extension moves a replay, per compared quantity, in units of :data:`SCALES`:
    max |extended - model| over the log's times (the trimmed start's controls for ``trim_``)."""
    if model is None or extended is None:
        return {ch: float("nan") for ch in COMPARED}
    d = np.abs(on_log_times(extended, t_s, REPLAY_CHANNELS) - on_log_times(model, t_s, REPLAY_CHANNELS))
    out = {ch: float(np.nanmax(d[:, j])) / SCALES[ch] for j, ch in enumerate(REPLAY_CHANNELS)}
    for c in TRIM_CHANNELS:
        out[f"trim_{c}"] = _trim_difference(extended, model, c) / SCALES[f"trim_{c}"]
    return out


def unmeasured(log) -> list[str]:
    """The log's channels an import map gave as constants (``meta["imported"]["constants"]``): a replay is not
    judged against them (the HFB-320's altitude, a constant 4,300 m, would read as a 299 ft miss)."""
    return list(log.meta.get("imported", {}).get("constants", ()))


#: What a Part 60 verdict says of a channel that was not measured.
NOT_MEASURED = "not measured (a constant of the import map)"


def part60(error: float, floor: float | None, tolerance: float, measured: bool = True) -> dict:
    """A Part 60 verdict on measured data: pass or fail, the margin (tolerance - error) and whether it is
    larger than the floor a perfect model leaves on the same log (``conclusive``); none for a channel the
    log does not measure."""
    if not measured:
        return {"pass": None, "margin": None, "conclusive": False, "says": NOT_MEASURED}
    if not np.isfinite(error):
        return {"pass": None, "margin": None, "conclusive": False, "says": "not flown"}
    margin = tolerance - error
    ok = bool(error <= tolerance)
    if floor is None or not np.isfinite(floor):
        return {"pass": ok, "margin": margin, "conclusive": None, "says": ("passes" if ok else "fails") + ", no floor"}
    sure = bool(abs(margin) > floor)
    says = ("passes" if ok else "fails") + (
        " by more than the floor" if sure else ", within the floor: the data cannot tell"
    )
    return {"pass": ok, "margin": margin, "conclusive": sure, "says": says}


def replay_table(held: list[Log], flown: dict[str, tuple], extended: bool, floors: dict | None = None) -> dict:
    """``{log file: {channel: {"model": max error, "extended": max error or None, ...}}}`` for every held-out
    log (:func:`replay_errors`), over the whole log; the time-history channels also carry ``window`` (the
    same over :func:`replay_window`: ``model``, ``extended``, ``floor``, ``tolerance`` and the ``part60``
    verdicts of the model and of the extended model), and ``floor``, the error a perfect model leaves on the
    log over the whole log (``floors``: ``{log file: {"log": {channel: floor}, "window": {...}}}``)."""
    out = {}
    for lg in held:
        name = Path(lg.path).name
        fm, fx = flown[lg.path]
        win, off = replay_window(lg.data), unmeasured(lg)
        em, wm = replay_errors(lg.data, fm, unmeasured=off), replay_errors(lg.data, fm, win[:2], off)
        ex, wx = (
            (replay_errors(lg.data, fx, unmeasured=off), replay_errors(lg.data, fx, win[:2], off))
            if extended
            else ({}, {})
        )
        fl = (floors or {}).get(name) or {}
        row = {}
        for ch in COMPARED:
            row[ch] = {"model": em[ch], "extended": ex.get(ch)}
            if ch in REPLAY_CHANNELS:
                f_log, f_win = (fl.get(k, {}).get(ch) for k in ("log", "window"))
                row[ch]["floor"] = f_log
                w = {
                    "model": wm[ch],
                    "extended": wx.get(ch),
                    "floor": f_win,
                    "tolerance": SCALES[ch],
                    "part60": part60(wm[ch], f_win, SCALES[ch], ch not in off),
                }
                if extended:
                    w["part60_extended"] = part60(wx[ch], f_win, SCALES[ch], ch not in off)
                row[ch]["window"] = w
        out[name] = row
    return out


def window_table(held: list[Log]) -> dict:
    """``{log file: {"from_s", "to_s", "kind"}}``: the span each held-out replay is judged over."""
    return {Path(lg.path).name: dict(zip(("from_s", "to_s", "kind"), replay_window(lg.data))) for lg in held}


def replay_lines(doc: dict) -> list[str]:
    """The held-out replays in ``diagnosis.txt``: worst error per channel over the judged windows and over the
    whole logs, model (-> extended model), beside the floor, and the Part 60 verdicts."""
    reps = doc.get("replays", {})
    if not reps:
        return []
    ext = bool(doc.get("extension"))
    lines = [
        "  channel: worst over the judged windows (whole logs) [floor of a perfect model, windows (logs)]"
        + (", model -> extended model" if ext else "")
    ]

    def worst(values) -> float:
        v = [x for x in values if x is not None and np.isfinite(x)]
        return max(v) if v else float("nan")

    for ch in next(iter(reps.values())):
        rs = list(reps.values())
        m, x = worst(r[ch]["model"] for r in rs), worst(r[ch]["extended"] for r in rs)
        if "window" in rs[0][ch] and all(r[ch]["window"]["part60"]["says"] == NOT_MEASURED for r in rs):
            lines.append(f"  {ch}: {NOT_MEASURED} in every held-out log")
            continue
        if "window" not in rs[0][ch]:
            lines.append(f"  {ch}: {m:.3g}" + (f" -> {x:.3g}" if ext else ""))
            continue
        wm, wx = worst(r[ch]["window"]["model"] for r in rs), worst(r[ch]["window"]["extended"] for r in rs)
        fw, fl = worst(r[ch]["window"]["floor"] for r in rs), worst(r[ch]["floor"] for r in rs)
        lines.append(
            f"  {ch}: {wm:.3g} ({m:.3g})"
            + (f" -> {wx:.3g} ({x:.3g})" if ext else "")
            + f" [floor {fw:.3g} ({fl:.3g}); tolerance {SCALES[ch]:g}]"
        )
    verdicts = [
        (n, ch, r[ch]["window"]["part60"])
        for n, r in reps.items()
        for ch in ("theta_deg", "tas_kt", "alt_ft")
        if r[ch]["window"]["part60"]["says"] != NOT_MEASURED
    ]
    fails = [f"{n} {ch} ({v['says']})" for n, ch, v in verdicts if v["pass"] is False]
    unsure = [f"{n} {ch}" for n, ch, v in verdicts if v["pass"] and v["conclusive"] is False]
    lines.append(
        f"  Part 60 gear-change tolerances (pitch, airspeed, altitude) over the judged windows, model: "
        f"{sum(v['pass'] is True for *_, v in verdicts)} of {len(verdicts)} pass, "
        f"{sum(v['pass'] is True and v['conclusive'] is True for *_, v in verdicts)} by more than the floor"
    )
    if fails:
        lines.append("    fail: " + "; ".join(fails[:8]) + (" ..." if len(fails) > 8 else ""))
    if unsure:
        lines.append(
            "    pass within the floor (the data cannot tell): "
            + "; ".join(unsure[:8])
            + (" ..." if len(unsure) > 8 else "")
        )
    return lines


def exercised(frame: pd.DataFrame, variables: list[str], min_std: dict | None = None) -> list[int]:
    """Held-out logs (``log`` values of a residual frame) in which any of the cause's variables varies, by
    ``min_std`` (variable -> standard deviation in its unit; None: the settings', :func:`diagnose.config.current`;
    a diagnosis's are ``diag.settings.min_std``)."""
    min_std = current().min_std if min_std is None else min_std
    out = [int(i) for i, g in frame.groupby("log") if any(float(g[v].std()) >= min_std[v] for v in variables)]
    return out or sorted(int(i) for i in frame.log.unique())


def largest(frame: pd.DataFrame) -> list[int]:
    """The held-out logs with the largest residual RMS of each coefficient."""
    rms = frame.groupby("log")[[f"r_{c}" for c in COEFFS]].agg(lambda r: float(np.sqrt(np.mean(r**2))))
    return sorted({int(rms[col].idxmax()) for col in rms.columns})


def _with_gain(table: dict) -> dict:
    for v in table.values():
        v["gain"] = (
            v["before"] / v["after"] if v["after"] > 0 else (float("nan") if np.isnan(v["after"]) else float("inf"))
        )
    return table


def residual_rms(before: pd.DataFrame, after: pd.DataFrame) -> dict:
    """Residual RMS of each coefficient before and after, and their ratio (``gain``)."""
    return _with_gain(
        {
            c: {
                "before": float(np.sqrt(np.mean(before[f"r_{c}"] ** 2))),
                "after": float(np.sqrt(np.mean(after[f"r_{c}"] ** 2))),
            }
            for c in COEFFS
        }
    )


def measure_gain(
    diag: Diagnosis, held: list[Log], before: pd.DataFrame, after: pd.DataFrame, flown: dict[str, tuple]
) -> dict:
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
        eb, ea = (
            replay_errors(lg.data, fb, unmeasured=unmeasured(lg)),
            replay_errors(lg.data, fa, unmeasured=unmeasured(lg)),
        )
        replays[Path(lg.path).name] = {ch: {"before": eb[ch], "after": ea[ch]} for ch in COMPARED}
    worst = _with_gain(
        {
            ch: {
                "before": _max(r[ch]["before"] for r in replays.values()),
                "after": _max(r[ch]["after"] for r in replays.values()),
            }
            for ch in COMPARED
        }
    )
    where = [replays[Path(held[i].path).name] for i in acting]
    where_acts = _with_gain(
        {
            ch: {"before": _max(r[ch]["before"] for r in where), "after": _max(r[ch]["after"] for r in where)}
            for ch in COMPARED
        }
    )
    shifts = [moved(*flown[held[i].path], held[i].data["t_s"].to_numpy()) for i in acting]
    shift = {ch: _max(m[ch] for m in shifts) for ch in COMPARED}
    most = max((ch for ch in COMPARED if np.isfinite(shift[ch])), key=shift.get, default=None)
    return {
        "cause": first.label,
        "held_out_logs": [Path(lg.path).name for lg in held],
        "cause_exercised_in": [Path(held[i].path).name for i in acting],
        "residual_gain": rms_acting[first.coefficient]["gain"],
        "coefficient": first.coefficient,
        "residual_rms": rms_acting,
        "residual_rms_all_held_out": residual_rms(before, after),
        "replay_max_error": worst,
        "replay_where_acts": where_acts,
        "replay_per_log": replays,
        "replay_moved": shift,
        "replay_moved_most": most,
    }


def _max(values) -> float:
    """The largest finite value (NaN if none)."""
    v = [x for x in values if x is not None and np.isfinite(x)]
    return max(v) if v else float("nan")
