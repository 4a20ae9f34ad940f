"""The data compatibility of one log alone, in segments, on perfect instruments: how often it corrects an error
that is not there (run by hand, about 3 min on 2 cores).

    python benchmarks/one_log_compat.py [--seeds FIRST LAST] [--json FILE]

For each seed, our 737 flies three single-log data sets through the flight-test instrument profile (its
turbulence and noise, no instrument error): a doublet at 10,000 ft and Mach 0.3 (22 s, two segments), a
multisine at 20,000 ft and Mach 0.5 (28 s, three) and a level turn at 15,000 ft and Mach 0.4 (190 s,
twelve). Each log's reconstruction is made alone (:func:`identify.compat.estimate` of one log, cut into
segments of ``compat.one_log_segment_s``), and every correction it applies is recorded: on these data any
is a false one.

``--json`` writes the rows (default ``benchmarks/results/one_log_compat.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from campaign.diagnosis.run import load_data  # noqa: E402
from campaign.simulation.aircraft import DEFAULT_AIRCRAFT  # noqa: E402
from campaign.validation.support import run_matrix  # noqa: E402
from identify.compat import CompatSettings, estimate  # noqa: E402
from provenance import provenance  # noqa: E402  (this folder is the script's first path)

#: (manoeuvre, Mach, altitude [ft]) of the three single-log data sets.
FLIGHTS = (("doublet", 0.3, 10000), ("multisine", 0.5, 20000), ("level_turn", 0.4, 15000))
MATRIX = (
    'name = "one"\n[maneuvers.doublet]\ntail_s = 2.0\n'
    '[[points]]\ngear = "up"\nflap_deg = 0\nmach = {mach}\nalt_ft = {alt}\nmaneuvers = ["{maneuver}"]\n'
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", nargs=2, type=int, default=[100, 110], metavar=("FIRST", "LAST"))
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "one_log_compat.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for seed in range(*args.seeds):
            for maneuver, mach, alt in FLIGHTS:
                where = Path(work) / f"{maneuver}-{seed}"
                text = MATRIX.format(mach=mach, alt=alt, maneuver=maneuver)
                (log,) = load_data(run_matrix(where, text, str(DEFAULT_AIRCRAFT), noise="flight-test", seed=seed))
                res = estimate([log])
                rows.append(
                    {
                        "seed": seed,
                        "maneuver": maneuver,
                        "duration_s": round(float(log.data.t_s.iloc[-1]), 2),
                        "segments": res.segments,
                        "applied": {p.name: {"estimate": p.estimate, "z": p.z} for p in res.applied},
                    }
                )
                print(seed, maneuver, res.segments, sorted(rows[-1]["applied"]), flush=True)
    doc = {
        **provenance("one_log_compat"),
        "segment_s": CompatSettings().one_log_segment_s,
        "logs": len(rows),
        "logs_with_a_correction": sum(bool(r["applied"]) for r in rows),
        "rows": rows,
    }
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{doc['logs_with_a_correction']} of {doc['logs']} single logs corrected for an error not there")


if __name__ == "__main__":
    main()
