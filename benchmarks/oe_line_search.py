"""What the output error's fits cost on real flight records, their line searches' trials simulated one by one
or as one batch (run by hand, about 10 min on 2 cores).

    python benchmarks/oe_line_search.py [--json FILE]

DLR's records (``tests/data/``: the ATTAS elevator record fAttasElv1, the HFB-320 record, and the ATTAS
aileron-rudder record fAttasAilRud2 cut at its gap into its two manoeuvres) are imported with their maps
(``docs/examples/``) and identified by output error (``campaign identify --method oe``), which makes every
output-error fit the identification asks for (its structure checks included). Each of those fits is then made
again in this process, two ways in turn, three rounds: with the trials of each line search simulated as one
batch (:attr:`identify.estimators.outputerror.OutputError.batched_trials`) and one by one. Each row gives the
least CPU-seconds of each way, the model simulations each asked for (a batch is one), and whether the
estimates and their standard errors are the same, bit for bit.

``--json`` writes the rows (default ``benchmarks/results/oe_line_search.json``).
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import identify.estimators.outputerror as oe  # noqa: E402
from campaign.cli import main as campaign  # noqa: E402
from provenance import provenance  # noqa: E402  (this folder is the script's first path)

DATA, EXAMPLES = ROOT / "tests" / "data", ROOT / "docs" / "examples"
#: Each fit is made this many times, the two ways in turn; a row gives the least CPU time of each.
ROUNDS = 3
#: Record, its map, and what is added to the map.
RECORDS = (
    ("fAttasElv1.mat", "attas-map.toml", ""),
    ("hfb320_1_10.asc", "hfb320-map.toml", ""),
    ("fAttasAilRud2.mat", "attas-map.toml", "\n[records]\nsplit_s = [45.0]\n"),
)


def _fits(work: Path, record: str, map_name: str, extra: str) -> list:
    """The output-error estimators ``campaign identify --method oe`` makes for ``record``, as each was before
    it was fitted."""
    made = []
    fit = oe.OutputError.fit

    def kept(self):
        made.append(copy.deepcopy(self))
        return fit(self)

    (work / "map.toml").write_text((EXAMPLES / map_name).read_text() + extra)
    folder = work / Path(record).stem
    campaign(["import", str(DATA / record), "--map", str(work / "map.toml"), "--out", str(folder)])
    oe.OutputError.fit = kept
    try:
        campaign(["identify", str(folder), "--plots", "none", "--method", "oe"])
    finally:
        oe.OutputError.fit = fit
    return [e for e in made if type(e) is oe.OutputError]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "oe_line_search.json")
    args = ap.parse_args()
    rows = []
    simulate = oe.OutputError.predict
    with tempfile.TemporaryDirectory() as work:
        for record, map_name, extra in RECORDS:
            fits = _fits(Path(work), record, map_name, extra)
            row, results = {"record": record, "fits": len(fits)}, {}
            for _ in range(ROUNDS):
                for batched in (False, True):
                    sims = [0]

                    def counted(self, thetas, sims=sims):
                        sims[0] += 1
                        return simulate(self, thetas)

                    oe.OutputError.predict, oe.OutputError.batched_trials = counted, batched
                    t = time.process_time()
                    results[batched] = [copy.deepcopy(e).fit() for e in fits]
                    cpu = time.process_time() - t
                    key = "batched" if batched else "one_by_one"
                    best = row.get(key, {}).get("cpu_s", float("inf"))
                    row[key] = {"cpu_s": round(min(cpu, best), 2), "simulations": sims[0]}
            oe.OutputError.predict, oe.OutputError.batched_trials = simulate, True
            pairs = list(zip(results[True], results[False]))
            row["same_estimates"] = all(a.params.equals(b.params) for a, b in pairs)
            row["same_standard_errors"] = all(a.bse.equals(b.bse) for a, b in pairs)
            rows.append(row)
            print(json.dumps(row), flush=True)
    doc = {
        **provenance("oe_line_search"),
        "rows": rows,
    }
    args.json.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
