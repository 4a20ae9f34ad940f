"""Replays after the extension where the cause acts, on the CI's hidden-effect cases, against their floor
(run by hand, about 5 min on 2 cores).

    python benchmarks/replay_gain.py [--work DIR] [--family F ...] [--json FILE]

Flies each case of ``campaign.validation.hidden.CASES`` (the cases ``tests/test_diagnose.py`` flies:
flight-test profile, 1.5 ft/s turbulence, each case's own seed), diagnoses it against the bare model, and
for every held-out log where the first cause acts (``gain.cause_exercised_in``) and each replay channel
gives, over its judged window, the extended model's error beside the floor of a perfect model on that log
(``replays[log][channel]["window"]``): the extension is *within its floor plus 10 %* when its error is at
most 1.1 times the floor. The truth itself (the same data diagnosed against the model with the hidden
effect) is replayed beside it: its errors are what no extension can beat, and the floor is meant to
cover them. A case counts at "10x or more" when its first cause's size over its floor
(``verdict.size_over_floor``) is at least 10.

``--json`` writes the rows (default ``benchmarks/results/replay_gain.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from campaign.validation.hidden import CASES, make, score  # noqa: E402
from provenance import provenance  # noqa: E402  (this folder is the script's first path)

#: The Part 60 channels and the two the diagnosis replays beside them.
CHANNELS = ("theta_deg", "tas_kt", "alt_ft", "alpha_deg", "q_dps")
#: An extension is within its floor when its error is at most this times the floor.
WITHIN = 1.1


def truth_replays(workdir: Path) -> dict:
    """The replays of the same data diagnosed against the model with the hidden effect (the truth)."""
    from campaign.diagnosis.run import run_diagnosis
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    truth = workdir / "truth" / DEFAULT_AIRCRAFT.name
    return run_diagnosis(workdir / "data", truth, workdir / "truth-report", plots="none")["replays"]


def rows_of(doc: dict, truth: dict) -> list[dict]:
    """One row per held-out log where the first cause acts and channel: window errors and floor."""
    out = []
    for name in (doc.get("gain") or {}).get("cause_exercised_in", []):
        for ch in CHANNELS:
            w = doc["replays"].get(name, {}).get(ch, {}).get("window")
            if not w:
                continue
            t = truth.get(name, {}).get(ch, {}).get("window", {})
            floor = w.get("floor", float("nan"))
            out.append(
                {
                    "log": name,
                    "channel": ch,
                    "model": w["model"],
                    "extended": w.get("extended", float("nan")),
                    "truth": t.get("model", float("nan")),
                    "floor": floor,
                    "extended_over_floor": w.get("extended", float("nan")) / floor if floor > 0 else float("nan"),
                    "truth_over_floor": t.get("model", float("nan")) / floor if floor > 0 else float("nan"),
                }
            )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--family", nargs="*", default=[])
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "replay_gain.json")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="replay-gain-"))
    cases = []
    for family, coeff, seed in CASES:
        if a.family and family not in a.family:
            continue
        where = work / f"{family}-{coeff or 'any'}"
        hidden = make(family, np.random.default_rng(seed), coeff)
        r = score(where, hidden, seed=seed)
        doc = r["doc"]
        causes = doc["causes"]
        sof = causes[0]["verdict"]["size_over_floor"] if causes else float("nan")
        truth = truth_replays(where) if doc.get("extension") else {}
        rows = rows_of(doc, truth)
        g = doc.get("gain") or {}
        most = g.get("replay_moved_most")
        acts = [truth[n] for n in g.get("cause_exercised_in", []) if n in truth]
        best = max((r[most]["model"] for r in acts if most in r), default=float("nan")) if most else float("nan")
        before = g.get("replay_where_acts", {}).get(most, {})
        worst = max((x["extended_over_floor"] for x in rows), default=float("nan"))
        within = all(x["extended_over_floor"] <= WITHIN for x in rows)
        cases.append(
            {
                "family": family,
                "coefficient": coeff,
                "seed": seed,
                "effect": f"{family.replace('_', ' ')}, {hidden.coefficient}",
                "first_cause": f"{causes[0]['coefficient']} vs {' x '.join(causes[0]['variables'])}"
                if causes
                else None,
                "size_over_floor": sof,
                "moved_most": most,
                "gain": before.get("gain", float("nan")),
                "truth_gain": before.get("before", float("nan")) / best if best > 0 else float("nan"),
                "extended": bool(doc.get("extension")),
                "logs_where_acts": len({x["log"] for x in rows}),
                "worst_extended_over_floor": worst,
                "within_floor_plus_10pct": within if rows else None,
                "rows": rows,
            }
        )
        print(
            f"{family:>20} {str(coeff):>4}  size/floor {sof:6.1f}  logs {cases[-1]['logs_where_acts']:2d}  "
            f"worst extended/floor {worst:5.2f}  within floor+10 %: {within if rows else '-'}",
            flush=True,
        )
        for x in sorted(rows, key=lambda x: -x["extended_over_floor"])[:3]:
            print(
                f"    {x['log']} {x['channel']}: extended {x['extended']:.3g}, truth {x['truth']:.3g}, "
                f"floor {x['floor']:.3g}",
                flush=True,
            )
    doc = {
        **provenance("replay_gain"),
        "setup": (
            "the hidden-effect cases of tests/test_diagnose.py (flight-test profile, 1.5 ft/s, each case's seed), "
            "diagnosed against the bare model; per held-out log where the first cause acts and channel, over the "
            "judged window: the model's, the extended model's and the truth's replay errors and the floor of a "
            f"perfect model; within its floor plus 10 %: extended <= {WITHIN} x floor"
        ),
        "cases": cases,
    }
    a.json.parent.mkdir(parents=True, exist_ok=True)
    a.json.write_text(json.dumps(doc, indent=1, default=float) + "\n")
    print(f"written {a.json}")


if __name__ == "__main__":
    main()
