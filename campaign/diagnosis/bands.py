"""``campaign diagnose --bands N``: Monte Carlo bands on the held-out replays of the extended model.

The extension's fitted terms are drawn ``N`` times from their covariance
(:mod:`diagnose.uncertainty`); each draw is written as an extension, merged into a copy of the
model, and the held-out logs where the cause acts are replayed on it, in the measured wind. The
band is the 2.5 to 97.5 percentile of the draws at each sample; the pass probability is the
share of draws within Part 60's tolerances of the measurement. One more draw, held back from
the band, checks it: the share of its samples inside.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from campaign.simulation.aircraft import AircraftSource, load_effects
from diagnose.extension import write_extension
from diagnose.gain import REPLAY_CHANNELS, on_log_times
from diagnose.result import Diagnosis
from diagnose.uncertainty import band, draws, pass_probability
from identify.export import merge_into_aircraft
from identify.logs import Log
from infra.pool import pmap


def replay_bands(
    diag: Diagnosis, model: Path, out: Path, logs: list[Log], n: int, replay, jobs: int = 1
) -> tuple[dict, dict]:
    """Bands and pass probabilities of the extended model's replays of ``logs``.

    Returns
    -------
    summary : dict
        ``{log file: {"draws", "pass_probability", "held_back_draw_inside", "width_max"}}`` for
        ``diagnosis.json``.
    arrays : dict
        ``{log path: {channel: (t_s, lo, hi)}}`` for the plots.
    """
    work = out / ".bands"
    try:
        sources = []
        for k, d in enumerate(draws(diag, n + 1, seed=n)):
            folder = work / f"draw{k}"
            folder.mkdir(parents=True)
            xml = write_extension(d, folder / "extension.xml")
            sources.append(
                AircraftSource(
                    str(merge_into_aircraft(model, xml, folder / "aircraft", replace_gear=False)), load_effects(None)
                )
            )
        flown = pmap(replay, [(lg, src) for src in sources for lg in logs], jobs)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    summary, arrays = {}, {}
    for j, lg in enumerate(logs):
        t = lg.data["t_s"].to_numpy()
        runs = [flown[k * len(logs) + j] for k in range(n + 1)]
        ys = np.stack(
            [
                on_log_times(f, t, REPLAY_CHANNELS)
                if f is not None
                else np.full((len(t), len(REPLAY_CHANNELS)), np.nan)
                for f in runs
            ]
        )
        per = {ch: ys[:, :, i] for i, ch in enumerate(REPLAY_CHANNELS)}
        held, rest = {ch: v[0] for ch, v in per.items()}, {ch: v[1:] for ch, v in per.items()}
        lims = {ch: band(v) for ch, v in rest.items()}
        inside = [np.nanmean((held[ch] >= lo - 1e-9) & (held[ch] <= hi + 1e-9)) for ch, (lo, hi) in lims.items()]
        measured = {ch: lg.data[ch].to_numpy() for ch in REPLAY_CHANNELS}
        summary[Path(lg.path).name] = {
            "draws": n,
            "pass_probability": pass_probability(rest, measured),
            "held_back_draw_inside": float(np.min(inside)),
            "width_max": {ch: float(np.nanmax(hi - lo)) for ch, (lo, hi) in lims.items()},
        }
        arrays[lg.path] = {ch: (t, lo, hi) for ch, (lo, hi) in lims.items()}
    return summary, arrays
