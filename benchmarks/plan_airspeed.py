"""An airspeed scale that needs a turn, settled by the plan.

A ``--scale`` airspeed scale (the pitot's) on our 737 through the flight-test instruments, on the
diagnosis matrix with gear extensions and retractions: diagnosed, planned with the default budget
(a quarter of the minutes flown), the plan flown on the truth, and old and new data diagnosed
together. Per seed: what the first diagnosis says of the Cm vs qhat cause the scale makes, the plan's
flights and predicted measurement, and what the second diagnosis names.

    python benchmarks/plan_airspeed.py --seeds 6 --seed-base 3200000
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.simulation.aircraft import DEFAULT_AIRCRAFT  # noqa: E402
from campaign.cli import main as cli  # noqa: E402
from campaign.validation.hidden import DIAG_MATRIX  # noqa: E402


def label(c: dict) -> str:
    return (
        f"sensor {c['channel']} {c['error']}"
        if c["kind"] == "sensor"
        else f"{c['coefficient']} vs {', '.join(c['variables'])}"
    )


def one(root: Path, seed: int, scale: float) -> dict:
    prof = root / "pitot.toml"
    prof.write_text(f'extends = "flight-test"\n[channels.tas_kt]\nscale = {1.0 + scale!r}\n')
    matrix = root / "m.toml"
    matrix.write_text(
        DIAG_MATRIX.replace(
            'name = "diagnosis"\n',
            'name = "diagnosis"\n[defaults]\nmaneuvers_gear_down = ["doublet", "gear_extension", "gear_retraction"]\n',
        )
    )
    truth = ["--aircraft", str(DEFAULT_AIRCRAFT), "--effects", "none", "--instruments", str(prof)]
    quiet = ["--no-identify", "--no-replay", "--quiet", "--jobs", "2"]
    cli(["run", "--matrix", str(matrix), *truth, "--seed", str(seed), "--out", str(root / "old"), *quiet])
    cli(
        [
            "diagnose",
            "--data",
            str(root / "old"),
            "--model",
            str(DEFAULT_AIRCRAFT),
            "--out",
            str(root / "d1"),
            "--no-plots",
            "--jobs",
            "2",
        ]
    )
    before = json.loads((root / "d1" / "diagnosis.json").read_text())
    out = {
        "seed": seed,
        "named_before": [label(c) for c in before["causes"]],
        "unconfirmed_before": [label(c) for c in before["unconfirmed"]],
        "rival_se": [r["separation_se"] for r in before["rivals"] if r["rival"] == "tas_kt scale"],
    }
    if cli(["plan", "--diagnosis", str(root / "d1"), "--out", str(root / "plan"), "--jobs", "2", "--quiet"]) != 0:
        return {**out, "plan": "none"}
    plan = json.loads((root / "plan" / "plan.json").read_text())
    airspeed = [r for r in plan["rivals"] if r["rival"] == "tas_kt scale"]
    out.update(
        flights=[f"{f['point']} {f['maneuver']}" for f in plan["flights"]],
        share=plan["planned_minutes"] / plan["old_minutes"],
        planned=airspeed[0]["planned_se"] if airspeed else None,
    )
    if plan["matrix"] is None:
        return out
    cli(["run", "--matrix", plan["matrix"], *truth, "--seed", str(seed + 1), "--out", str(root / "new"), *quiet])
    cli(
        [
            "diagnose",
            "--data",
            str(root / "old"),
            "--data",
            str(root / "new"),
            "--model",
            str(DEFAULT_AIRCRAFT),
            "--out",
            str(root / "d2"),
            "--no-plots",
            "--jobs",
            "2",
        ]
    )
    after = json.loads((root / "d2" / "diagnosis.json").read_text())
    sensor = [c for c in after["causes"] if c["kind"] == "sensor" and c["channel"] == "tas_kt"]
    needs = [
        a["needs"]
        for c in before["unconfirmed"]
        for a in c["evidence"].get("sensor_alternatives", [])
        if a["channel"] == "tas_kt"
    ]
    out.update(
        named_after=[label(c) for c in after["causes"]],
        unconfirmed_after=[label(c) for c in after["unconfirmed"]],
        scale=(sensor[0]["estimate"], sensor[0]["se"]) if sensor else None,
        measured=abs(needs[0]) / sensor[0]["se"] if sensor and needs else None,
    )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--seed-base", type=int, default=3200000)
    ap.add_argument("--scale", type=float, default=0.06)
    a = ap.parse_args()
    for k in range(a.seeds):
        with tempfile.TemporaryDirectory() as tmp:
            r = one(Path(tmp), a.seed_base + 10 * k, a.scale)
        print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main()
