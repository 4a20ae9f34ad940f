"""``campaign replay --bands N``: Monte Carlo bands on the identified models' replays.

The identified gear surfaces (eqs. 4 and 9) carry their least-squares covariance
(``identification/gear_surfaces.json``, :meth:`identify.models.GearSurface.draw`). Each model
is drawn ``N + 1`` times; each draw is exported as JSBSim tables, merged into a copy of the
identified aircraft in place of its gear functions, and flies every selected case and loop.
The band is the 2.5 to 97.5 percentile of ``N`` draws at each sample; the pass probability is
the share of them within Part 60's tolerances of the reference replay. One more draw, held back,
checks the band: the share of its samples inside.

Written into ``RESULTS_DIR/replays``: ``bands/<case>__<model>__<loop>.parquet`` (``t_s`` and
``<channel>_lo``, ``<channel>_hi``) and ``bands.json``. Both name the ``gear_surfaces.json``
they were drawn from by its SHA-256: bands of an older identification are not shown.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from campaign.simulation.aircraft import AircraftSource, load_effects
from campaign.errors import UserError
from campaign.replays.replay import LOOPS, ReplayCase, fly_one, aircraft_for
from campaign.replays.report import bands_doc_text, stored_bands_doc, surfaces_file, surfaces_sha
from diagnose.gain import REPLAY_CHANNELS
from diagnose.uncertainty import band, pass_probability
from campaign.orchestration.store import atomic_write, read_log
from identify.export import merge_into_aircraft, write_effects
from identify.models import GearSurface
from infra.pool import pmap

MIN_DRAWS = 20
CHANNELS = REPLAY_CHANNELS
KINDS = ("linear", "nonlinear")


def load_surfaces(results: Path) -> tuple[dict[str, GearSurface], tuple[float, float]]:
    """The identified surfaces with their covariance, and the AERORP arm [ft]."""
    p = surfaces_file(results)
    if not p.exists():
        raise UserError(
            f"{p}: missing (an identification older than the bands); run 'campaign identify {results}' again"
        )
    try:
        doc = json.loads(p.read_text())
        return {k: GearSurface.from_arrays(doc[k]) for k in KINDS if k in doc}, tuple(doc["arm_ft"])
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(
            f"{p}: does not read ({type(exc).__name__}: {exc}); run 'campaign identify {results}' again"
        ) from None


def check_draws(n: int) -> None:
    if n < MIN_DRAWS:
        raise UserError(f"--bands {n}: a band needs {MIN_DRAWS} draws or more")


def _fly_channels(case: ReplayCase, model: str, source: AircraftSource, loop: str) -> np.ndarray | None:
    """One draw's flight: its :data:`CHANNELS` only (float32), None if it did not trim."""
    log, _, _ = fly_one(case, model, source, loop)
    return None if log is None else log[list(CHANNELS)].to_numpy(np.float32)


def replay_bands(
    results: Path, cases: list[ReplayCase], n: int, jobs: int = 1, seed: int = 0, held_back: int = 1
) -> dict:
    """Draw each identified model ``n + held_back`` times, fly every case and loop on each draw, and
    write the bands (of ``n`` draws) and pass probabilities. Returns ``bands.json``'s content.

    ``held_back_inside`` in each entry is the share of the held-back draws' samples inside the band,
    the lowest over the channels.
    """
    check_draws(n)
    results = Path(results)
    surfaces, arm = load_surfaces(results)
    sha = surfaces_sha(surfaces_file(results))
    nominal = aircraft_for(results)
    rep = results / "replays"
    missing = [
        f"{c.name}__{m}__{lp}"
        for c in cases
        for m in ("reference", *surfaces)
        for lp in LOOPS
        if not (rep / f"{c.name}__{m}__{lp}.parquet").exists()
    ]
    if missing:
        raise UserError(f"{rep}: no replay {missing[0]}; run 'campaign replay {results}' first")
    rng = np.random.default_rng(seed)
    work = rep / ".bands-work"
    shutil.rmtree(work, ignore_errors=True)
    try:
        flights = []
        for kind, surface in surfaces.items():
            model = Path(nominal[kind].folder)
            for k in range(n + held_back):
                folder = work / f"{kind}{k}"
                folder.mkdir(parents=True)
                xml = write_effects(surface.draw(rng), kind, arm, folder / f"gear_{kind}.xml")
                src = AircraftSource(str(merge_into_aircraft(model, xml, folder / "aircraft")), load_effects(None))
                flights += [(c, kind, src, lp, k) for c in cases for lp in LOOPS]
        flown = pmap(_fly_channels, [f[:4] for f in flights], jobs)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    runs: dict[tuple, list] = {}
    for (c, kind, _, lp, k), log in zip(flights, flown):
        runs.setdefault((c.name, kind, lp), [None] * (n + held_back))[k] = log
    doc = stored_bands_doc(results, sha)
    doc["surfaces_sha256"] = sha
    (rep / "bands").mkdir(exist_ok=True)
    for (case, kind, lp), logs in runs.items():
        ref = read_log(rep / f"{case}__reference__{lp}.parquet")[0]
        t = ref.t_s.to_numpy()
        ys = np.full((n + held_back, len(t), len(CHANNELS)), np.nan)
        for k, log in enumerate(logs):
            if log is not None:
                m = min(len(t), len(log))
                ys[k, :m] = log[:m]
        held, rest = ys[:held_back], ys[held_back:]
        lo, hi = band(rest)
        held = held[~np.isnan(held).all(axis=(1, 2))]  # a held-back draw that did not trim checks nothing
        inside = (
            np.nanmean((held >= lo - 1e-9) & (held <= hi + 1e-9), axis=(0, 1))
            if len(held)
            else np.full(len(CHANNELS), np.nan)
        )
        probability = pass_probability(
            {ch: rest[:, :, i] for i, ch in enumerate(CHANNELS)}, {ch: ref[ch].to_numpy() for ch in CHANNELS}
        )
        flew = ~np.isnan(rest[:, :, 0]).all(axis=1)
        frame = pd.DataFrame(
            {
                "t_s": t,
                **{f"{ch}_lo": lo[:, i] for i, ch in enumerate(CHANNELS)},
                **{f"{ch}_hi": hi[:, i] for i, ch in enumerate(CHANNELS)},
            }
        )
        name = f"{case}__{kind}__{lp}"
        atomic_write(
            rep / "bands" / f"{name}.parquet", lambda tmp: frame.to_parquet(tmp, index=False, compression="zstd")
        )
        doc["cases"][name] = {
            "draws": n,
            "seed": seed,
            "pass_probability": probability,
            "draws_flown": int(flew.sum()),
            "held_back": held_back,
            "held_back_inside": float(np.min(inside)),  # NaN: none flew
            "width_max": {ch: float(np.nanmax(hi[:, i] - lo[:, i])) for i, ch in enumerate(CHANNELS)},
        }
    text = bands_doc_text(doc)
    atomic_write(rep / "bands.json", lambda tmp: Path(tmp).write_text(text))
    return doc
