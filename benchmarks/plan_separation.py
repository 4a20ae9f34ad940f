"""Does the plan settle what the diagnosis could not? Random gear x alpha effects in a narrow campaign.

    python benchmarks/plan_separation.py [--seeds N] [--seed-base S] [--out DIR]

Each case hides a gear x alpha effect on Cm (tests/hidden.py, a random size and sign; on CL's own
residual CL is no candidate) in a campaign too narrow to tell alpha from CL (flap 5, 5,000 ft, Mach
0.25-0.4, gear extensions without a gear-down 2-3-1-1; the flight-test instruments in 1.5 ft/s
turbulence), diagnoses it against the bare 737, plans with the default budget (a quarter of the
minutes flown), flies the plan on the truth through the same instruments, and diagnoses old and new
data together. Reports, per case:
the first cause before and after, the rivals' separation before, predicted and measured after,
and the flight time added. Cases whose first diagnosis has no open rival are counted and skipped.
Run by hand, outside CI: about 90 s a case on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.validation.hidden import fly_data, make
from campaign.validation.support import NARROW


def case(seed: int, work: Path) -> dict:
    from campaign.cli import main
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from diagnose.config import recorded

    hidden = make("gear_x_alpha", np.random.default_rng(seed), "Cm")
    data, fx = fly_data(work, hidden, seed=seed, matrix=NARROW)
    quiet = ["--no-plots", "--jobs", "2"]
    if main(["diagnose", "--data", str(data), "--model", str(DEFAULT_AIRCRAFT), "--out", str(work / "d1"), *quiet]):
        return {"seed": seed, "effect": hidden.description, "error": "diagnose failed", "open": []}
    d1 = json.loads((work / "d1" / "diagnosis.json").read_text())
    row = {
        "seed": seed,
        "effect": hidden.description,
        "coefficient": hidden.coefficient,
        "before": _first(d1),
        "open": [
            f"{r['rival']} {r['separation_se']:.1f}"
            for r in d1["rivals"]
            if r["separation_se"] < recorded(d1).settled_se
        ],
    }
    if not row["open"]:
        return row
    if main(["plan", "--diagnosis", str(work / "d1"), "--out", str(work / "plan"), "--jobs", "2", "--quiet"]):
        return {**row, "error": "plan failed"}
    plan = json.loads((work / "plan" / "plan.json").read_text())
    row["added_pct"] = 100 * plan["planned_minutes"] / plan["old_minutes"]
    row["predicted"] = [f"{r['rival']} {r['planned_se']:.1f}" for r in plan["rivals"]]
    if not plan["matrix"]:
        return row
    main(
        [
            "run",
            "--matrix",
            plan["matrix"],
            "--aircraft",
            str(DEFAULT_AIRCRAFT),
            "--effects",
            str(fx),
            "--noise",
            "flight-test",
            "--seed",
            str(seed + 1),
            "--out",
            str(work / "new"),
            "--no-identify",
            "--quiet",
        ]
    )
    main(
        [
            "diagnose",
            "--data",
            str(data),
            "--data",
            str(work / "new"),
            "--model",
            str(DEFAULT_AIRCRAFT),
            "--out",
            str(work / "d2"),
            *quiet,
        ]
    )
    d2 = json.loads((work / "d2" / "diagnosis.json").read_text())
    row["after"] = _first(d2)
    first = d2["causes"][0] if d2["causes"] else {}
    row["right_after"] = first.get("coefficient") == hidden.coefficient and first.get("variables", [])[:2] == [
        "gear_norm",
        "alpha_deg",
    ]
    seps = [r["separation_se"] for r in first.get("evidence", {}).get("rivals", [])]
    row["measured"] = [f"{r['rival']} {r['separation_se']:.1f}" for r in first.get("evidence", {}).get("rivals", [])]
    row["settled"] = row["right_after"] and all(s >= recorded(d2).settled_se for s in seps)
    return row


def _first(doc: dict) -> str:
    c = (doc["causes"] or doc.get("unconfirmed") or [{}])[0]
    return f"{c['coefficient']} vs {', '.join(c['variables'])}" if c.get("variables") else "-"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--seed-base", type=int, default=3_100_000)
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "plan-separation")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for s in range(a.seed_base, a.seed_base + a.seeds):
        r = case(s, Path(tempfile.mkdtemp(prefix="plan-")))
        rows.append(r)
        print(json.dumps(r), flush=True)
    (a.out / "plan_separation.json").write_text(json.dumps(rows, indent=1))
    planned = [r for r in rows if r["open"]]
    flown = [r for r in planned if "after" in r]
    print(
        f"\n{len(rows)} cases; {len(planned)} with an open rival; {len(flown)} planned and flown; "
        f"settled (right cause first, every rival >= 5 se): {sum(r['settled'] for r in flown)}; "
        f"right cause first before: {sum(r['before'] == 'Cm vs gear_norm, alpha_deg' for r in planned)}, "
        f"after: {sum(r['right_after'] for r in flown)}; flight time added: "
        + ", ".join(f"{r['added_pct']:.0f} %" for r in planned if "added_pct" in r)
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
