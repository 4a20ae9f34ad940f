"""Replay gain where the cause acts, on the CI's hidden-effect cases (run by hand, ~3 min on 2 cores).

    python benchmarks/replay_gain.py [WORKDIR [FAMILY ...]]

Flies each case of ``tests/test_diagnose.py``'s CASES (flight-test profile, 1.5 ft/s
turbulence, the test's seeds), diagnoses it against the bare model and prints the first
cause's size over its floor, the held-out residual gain and ``gain.replay_where_acts`` per
channel: the held-out replays, flown in the measured wind, before and after the extension, and
the quantity the extension moves most (``gain.replay_moved_most``) with its gain, beside the gain
the truth itself reaches there (the same data diagnosed against the model with the hidden
effect: its replay errors are what no extension can beat).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.validation.hidden import make, score  # noqa: E402
from campaign.validation.hidden import CASES  # noqa: E402


def attainable(workdir: Path, g: dict) -> dict[str, float]:
    """The truth's own replay errors where the cause acts (the data diagnosed against the model
    with the hidden effect): the smallest error any extension could reach, per channel."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.diagnosis.run import run_diagnosis

    truth = workdir / "truth" / DEFAULT_AIRCRAFT.name
    doc = run_diagnosis(workdir / "data", truth, workdir / "truth-report", plots="none")
    where = [doc["replays"][name] for name in g["cause_exercised_in"] if name in doc["replays"]]
    return {ch: max(r[ch]["model"] for r in where) for ch in where[0]} if where else {}


def main(work: Path, only: list[str]) -> None:
    for i, (family, coeff) in enumerate(CASES):
        if only and family not in only:
            continue
        seed = 1000 + i
        r = score(work / f"{family}-{coeff}", make(family, np.random.default_rng(seed), coeff), seed=seed)
        g = r["doc"].get("gain") or {}
        best = attainable(work / f"{family}-{coeff}", g) if g else {}
        causes = r["doc"]["causes"]
        sof = causes[0]["verdict"]["size_over_floor"] if causes else float("nan")
        gains = {k: round(v["gain"], 2) for k, v in g.get("replay_where_acts", {}).items()}
        most = g.get("replay_moved_most")
        on_most = gains.get(most, float("nan"))
        reach = g["replay_where_acts"][most]["before"] / best[most] if most in best and best[most] > 0 else float("nan")
        print(
            f"{family:>20} {str(coeff):>4}  size/floor {sof:5.1f}  residual x{g.get('residual_gain', float('nan')):5.1f}"
            f"  moved most: {most} ({g.get('replay_moved', {}).get(most, float('nan')):.2f} tol) x{on_most:.2f}"
            f" (the truth itself: x{reach:.2f})"
            f"  replay where it acts {gains}",
            flush=True,
        )


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="replay-gain-")), sys.argv[2:])
