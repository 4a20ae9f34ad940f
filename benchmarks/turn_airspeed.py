"""The data compatibility's airspeed error from one full-circle level turn (branch turns2, not landed).

The diagnosis matrix's gear-up 2-3-1-1s plus one 360-deg level turn at Mach 0.3 and 10,000 ft,
our 737, the flight-test profile at ``--sigma-fps`` of turbulence, with none or a ``--scale``
airspeed scale hidden. Prints the estimated airspeed error along the track (tas_kt.bias holds
the scale at one speed) against the truth, and its standard error.

    python benchmarks/turn_airspeed.py --seeds 2 3 4 5
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.simulation.aircraft import DEFAULT_AIRCRAFT  # noqa: E402
from campaign.diagnosis.run import load_data  # noqa: E402
from identify.compat import estimate  # noqa: E402
from campaign.validation.support import TURN_MATRIX as MATRIX, run_matrix  # noqa: E402


def one(root: Path, scale: float, sigma: float, seed: int) -> tuple[float, float, float]:
    """(estimate, standard error, truth) of the airspeed error along the turn's track [kt]."""
    prof = root / "p.toml"
    prof.write_text(
        f'extends = "flight-test"\n[turbulence]\nsigma_fps = {sigma}\n[channels.tas_kt]\nscale = {1.0 + scale}\n'
    )
    logs = load_data(run_matrix(root, MATRIX, str(DEFAULT_AIRCRAFT), noise=str(prof), seed=seed))
    turn = next(lg for lg in logs if lg.maneuver == "level_turn").read()
    tas = float(np.median(turn.data.tas_kt)) / (1.0 + scale)
    by = {p.name: p for p in estimate(logs).parameters}
    b, s = by["tas_kt.bias"], by["tas_kt.scale"]
    if b.identifiable and not b.confounded_with and s.identifiable and not s.confounded_with:
        return b.estimate + s.estimate * tas, float(np.hypot(b.se, s.se * tas)), scale * tas
    held = b if b.confounded_with == "tas_kt.scale" else s
    k = 1.0 if held is b else tas
    return held.estimate * k, held.se * k, scale * tas


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4, 5])
    ap.add_argument("--scale", type=float, default=0.03)
    ap.add_argument("--sigma-fps", type=float, default=1.5)
    a = ap.parse_args()
    print("seed  hidden  estimate [kt]  se [kt]  truth [kt]  error/se")
    for seed in a.seeds:
        for scale in (0.0, a.scale):
            with tempfile.TemporaryDirectory() as tmp:
                est, se, truth = one(Path(tmp), scale, a.sigma_fps, seed)
            print(f"{seed:4d}  {scale:6.3f}  {est:+13.3f}  {se:7.3f}  {truth:+10.3f}  {(est - truth) / se:+8.1f}")


if __name__ == "__main__":
    main()
