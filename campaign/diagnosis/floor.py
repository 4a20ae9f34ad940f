"""The replay floor: what a perfect model leaves on a log, from the data's own noise and the error of the
wind reconstructed from them.

The model's own flight of the log's inputs and measured thrust, in the wind measured in the log taken
unfiltered (its vanes' noise included, so more gust than the aeroplane met: the floor errs high), stands
for the truth. It is recorded at the log's sample times with white noise of each channel's own level
(:func:`diagnose.windows.noise_level` of the log's channel), and that synthetic log is replayed exactly as
the log is (start estimated from it, wind reconstructed from its noisy air data and inertial velocity,
low-passed) on the same model. Its replay errors are what a model that is the truth leaves. The floor, per
channel over the whole log and over the judged window, is an upper bound of them: the larger of
:data:`DRAWS` noise draws times :data:`COVER`.

Limits: the noise is white at each channel's level (a real record's noise may be coloured, and its
instruments may err in ways the data compatibility did not correct); without a logged inertial velocity
there is no measured wind, so the floor holds the instruments' noise only, not turbulence.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from campaign.simulation.aircraft import AircraftSource
from campaign.simulation.replay_log import ReplayError, estimate_start, fly_log, measured_inputs
from diagnose.gain import REPLAY_CHANNELS, replay_errors, replay_window
from diagnose.windows import noise_level
from identify.kinematics import measured_wind
from identify.logs import Log

#: Noise draws per log.
DRAWS = 2
#: The floor is the larger draw times this: a bound a perfect model's own replay error stays within 99 times in
#: 100. One draw is as likely as the real log to be the largest of three, so the larger of two draws alone was
#: exceeded by a perfect model's replay a third of the time (35 % of 1,270 comparisons). Calibrated on our 737
#: replaying its own data through the flight-test instruments, the paper's matrix at 1.5 and 3 ft/s, seeds 21-23
#: (254 held-out logs, 5 channels, judged windows and whole logs; ``benchmarks/replay_floor.py``): the 99th
#: percentile of replay error over the larger draw was 2.51 over the windows and 2.53 over the whole logs.
COVER = 2.5
#: The turbulence seeds :data:`COVER` was calibrated on (``benchmarks/replay_floor.py --seeds``).
COVER_CALIBRATION_SEEDS = (21, 22, 23)
#: How ``diagnosis.json`` and ``diagnosis.txt`` say what the floor is.
FLOOR = (
    f"the error a perfect model leaves on the same log, as a bound it stays within 99 times in 100: the model's "
    f"own flight of the log's inputs (in the unfiltered measured wind) recorded with each channel's own noise "
    f"level and replayed as the log is, the larger of {DRAWS} noise draws times {COVER:g}"
)
#: The channels a synthetic log is made of (those the log has).
SYNTHETIC = (
    "alt_ft",
    "tas_kt",
    "mach",
    "alpha_deg",
    "beta_deg",
    "theta_deg",
    "phi_deg",
    "psi_deg",
    "p_dps",
    "q_dps",
    "r_dps",
    "vn_fps",
    "ve_fps",
    "vd_fps",
    "elevator_deg",
    "stabilizer_deg",
    "thrust_lbf",
)


def synthetic_log(log: Log, truth: pd.DataFrame, rng: np.random.Generator) -> Log:
    """``truth`` as the log's instruments would record it: at its sample times, its channels, each with white
    noise of the log's own level; the gear, flap and mass channels as logged."""
    d = log.data
    t = d["t_s"].to_numpy(dtype=float)
    ts = truth["t_s"].to_numpy(dtype=float) + t[0]
    out = d.copy()
    for c in SYNTHETIC:
        if c in d and c in truth:
            x = np.interp(t, ts, truth[c].to_numpy(dtype=float))
            out[c] = x + rng.normal(0.0, noise_level(d[c].to_numpy(dtype=float)), len(t))
    return Log(log.path, out, log.meta)


def replay_floor(log: Log, source: AircraftSource, seed: int = 0) -> dict:
    """The floor of one log on ``source`` (see the module notes).

    Returns
    -------
    dict
        ``log`` and ``window``: ``{channel: floor}`` [channel units] over the whole log and over the judged
        window (:func:`diagnose.gain.replay_window`); ``drawn``: the same before :data:`COVER`, the larger draw;
        ``draws``; ``note`` (what it holds, or why there is none).
    """
    from campaign.diagnosis.run import log_wind, replay_why  # noqa: PLC0415  (run imports this module)

    d = log.data
    raw = measured_wind(d)
    wind = raw if raw is not None and log_wind(log) is not None else None
    note = (
        "instrument noise and the measured wind's reconstruction"
        if wind is not None
        else "instrument noise only: " + ("no inertial velocity logged" if raw is None else "still air")
    )
    start = estimate_start(d, None if wind is None else log_wind(log))
    nan = {ch: float("nan") for ch in REPLAY_CHANNELS}
    try:
        truth = fly_log(source, start, measured_inputs(d, start, wind))
    except ReplayError as exc:
        return {"log": nan, "window": dict(nan), "draws": 0, "note": f"no floor: {exc}"}
    win = replay_window(d)[:2]
    floor_log, floor_win = dict.fromkeys(REPLAY_CHANNELS, 0.0), dict.fromkeys(REPLAY_CHANNELS, 0.0)
    rng = np.random.default_rng(seed)
    for _ in range(DRAWS):
        syn = synthetic_log(log, truth, rng)
        flown = replay_why(syn, source)
        if isinstance(flown, str):
            return {"log": nan, "window": dict(nan), "draws": 0, "note": f"no floor: {flown}"}
        e_log, e_win = replay_errors(syn.data, flown), replay_errors(syn.data, flown, win)
        for ch in REPLAY_CHANNELS:
            floor_log[ch] = max(floor_log[ch], e_log[ch])
            floor_win[ch] = max(floor_win[ch], e_win[ch])
    return {
        "log": {ch: COVER * v for ch, v in floor_log.items()},
        "window": {ch: COVER * v for ch, v in floor_win.items()},
        "drawn": {"log": floor_log, "window": floor_win},
        "draws": DRAWS,
        "note": note,
    }
