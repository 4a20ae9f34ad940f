"""Spans of a measured log that replays are started and judged by: where the gear moves, how long the
log flies before its inputs move, and a channel's noise level. Data only."""

from __future__ import annotations

import numpy as np
import pandas as pd

#: The longest quiet head the references are averaged over, and the shortest [s].
HEAD_MAX_S, HEAD_MIN_S = 5.0, 0.5
#: The states at the first sample come from a fit over this long [s].
STATE_FIT_S = 1.0
#: An input has started once a control leaves its first half second's median by more than this many
#: times its noise, and by this much at least [deg].
ACTIVITY_SIGMAS, ACTIVITY_MIN_DEG = 8.0, 0.1


def noise_level(x: np.ndarray) -> float:
    """White-noise level (1 sigma) of a sampled channel: ``1.4826 MAD(d2x) / sqrt(6)`` (as
    :func:`diagnose.noise_floor.channel_noise`)."""
    d2 = np.diff(np.asarray(x, dtype=float), 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0)) if d2.size else 0.0


def gear_start_s(data: pd.DataFrame) -> float | None:
    """When the logged gear starts to move [s from the first sample], or None."""
    g = data["gear_norm"].to_numpy(dtype=float)
    moving = np.flatnonzero(np.abs(g - round(float(g[0]))) > 1e-6)
    return float(data["t_s"].iloc[moving[0]] - data["t_s"].iloc[0]) if moving.size else None


def quiet_head_s(data: pd.DataFrame) -> float:
    """How long the log flies before its inputs move [s]: until the gear moves or the elevator or the
    stabilizer leaves its first half second's median by more than :data:`ACTIVITY_SIGMAS` noise levels
    (and :data:`ACTIVITY_MIN_DEG`), within :data:`HEAD_MIN_S` .. :data:`HEAD_MAX_S`."""
    t = data["t_s"].to_numpy(dtype=float) - float(data["t_s"].iloc[0])
    end = min(HEAD_MAX_S, float(t[-1]))
    g = gear_start_s(data)
    if g is not None:
        end = min(end, g)
    first = t < HEAD_MIN_S
    for ch in ("elevator_deg", "stabilizer_deg"):
        if ch in data:
            x = data[ch].to_numpy(dtype=float)
            band = max(ACTIVITY_SIGMAS * noise_level(x), ACTIVITY_MIN_DEG)
            out = np.flatnonzero(np.abs(x - np.median(x[first])) > band)
            if out.size:
                end = min(end, float(t[out[0]]))
    return max(end, min(HEAD_MIN_S, float(t[-1])))
