"""Replay gain where the cause acts, on the CI's hidden-effect cases (run by hand, ~3 min on 2 cores).

    python benchmarks/replay_gain.py [WORKDIR]

Flies each case of ``tests/test_diagnose.py``'s CASES (flight-test profile, 1.5 ft/s
turbulence, the test's seeds), diagnoses it against the bare model and prints the first
cause's size over its floor, the held-out residual gain and ``gain.replay_where_acts`` per
channel: the held-out replays, flown in the measured wind, before and after the extension.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.hidden import make, score  # noqa: E402
from tests.test_diagnose import CASES  # noqa: E402


def main(work: Path) -> None:
    for i, (family, coeff) in enumerate(CASES):
        seed = 1000 + i
        r = score(work / f"{family}-{coeff}", make(family, np.random.default_rng(seed), coeff), seed=seed)
        g = r["doc"].get("gain") or {}
        causes = r["doc"]["causes"]
        sof = causes[0]["verdict"]["size_over_floor"] if causes else float("nan")
        gains = {k: round(v["gain"], 2) for k, v in g.get("replay_where_acts", {}).items()}
        print(f"{family:>20} {str(coeff):>4}  size/floor {sof:5.1f}  residual x{g.get('residual_gain', float('nan')):5.1f}"
              f"  replay where it acts {gains}", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="replay-gain-")))
