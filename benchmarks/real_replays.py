"""Replays of real flight records on a model identified from another record of the same aeroplane, trimmed in
steady flight and in the flight each record starts in (run by hand, about 10 s).

    python benchmarks/real_replays.py [--method {ee,oe,fe}] [--json FILE]

DLR's records (``tests/data/``: the two ATTAS elevator records, and the HFB-320 record cut into its 3-2-1-1
and its pulse) are imported with their maps (``docs/examples/``), each identified on its own (equation error,
or ``--method``'s estimator) and built into a JSBSim aircraft (``campaign model``). Each record is then flown,
as imported, on the model of the other record of its aeroplane (:func:`campaign.diagnosis.run.recorded`: the recorded surfaces and the
measured thrust, in still air, from the start estimated from the record), twice: trimmed in steady flight
(the start's rates set to 0), and trimmed in the flight the record starts in (its pitch attitude's and
airspeed's rates over the quiet head, as the diagnosis's replays are). Each row gives the worst pitch and
altitude error over the whole record (the altitude where the record measures it), against Part 60's 1.5 deg
and 100 ft, and the trim offsets flown.

``--json`` writes the rows (default ``benchmarks/results/real_replays.json``, ``real_replays_oe.json`` with
``--method oe``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from campaign.cli import main as campaign  # noqa: E402
from campaign.diagnosis.run import recorded  # noqa: E402
from campaign.simulation.aircraft import AircraftSource, load_effects  # noqa: E402
from campaign.simulation.replay_log import fly_log  # noqa: E402
from real_terms import _records  # noqa: E402
from provenance import provenance  # noqa: E402  (this folder is the script's first path)

#: Part 60's tolerances over the record [deg, ft].
TOLERANCE = {"theta_deg": 1.5, "alt_ft": 100.0}


def _errors(log, flown) -> dict[str, float | None]:
    """The worst error of the replay ``flown`` against ``log`` per channel of :data:`TOLERANCE` (None for a
    channel the import map gave as a constant)."""
    constants = set(log.meta.get("imported", {}).get("constants", ()))
    t = log.data["t_s"].to_numpy() - float(log.data["t_s"].iloc[0])
    return {
        ch: None
        if ch in constants
        else float(np.max(np.abs(np.interp(t, flown["t_s"], flown[ch]) - log.data[ch].to_numpy())))
        for ch in TOLERANCE
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, help="the result file")
    ap.add_argument("--method", choices=("ee", "oe", "fe"), default="ee", help="the identification's estimator")
    args = ap.parse_args()
    results = ROOT / "benchmarks" / "results"
    args.json = args.json or results / (
        "real_replays.json" if args.method == "ee" else f"real_replays_{args.method}.json"
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        records = _records(work)
        models = {}
        for name, (folder, _, _) in records.items():
            campaign(["identify", str(folder), "--plots", "none", "--method", args.method])
            models[name] = work / "m" / folder.name
            campaign(["model", str(folder / "identification"), "--out", str(models[name])])
        for name, (_, logs, other) in records.items():
            (log,) = logs
            source = AircraftSource(str(models[other]), load_effects(None))
            start, inputs = recorded(log)
            row = {
                "record": name,
                "model_of": other,
                "start": {"accel_fps2": start.accel_fps2, "theta_rate_dps": start.theta_rate_dps},
            }
            for kind, s in (("steady", replace(start, accel_fps2=0.0, theta_rate_dps=0.0)), ("as_started", start)):
                flown = fly_log(source, s, inputs)
                row[kind] = {"max_error": _errors(log, flown), "offsets": flown.attrs["offsets"]}
            rows.append(row)
            print(name, "on", other, {k: row[k]["max_error"] for k in ("steady", "as_started")}, flush=True)

    def passing(kind: str) -> int:
        return sum(all(v is None or v <= TOLERANCE[ch] for ch, v in r[kind]["max_error"].items()) for r in rows)

    doc = {
        **provenance("real_replays"),
        "method": args.method,
        "tolerance": TOLERANCE,
        "within_tolerance": {"steady": passing("steady"), "as_started": passing("as_started"), "of": len(rows)},
        "rows": rows,
    }
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(
        f"within Part 60 over the record: trimmed steady {doc['within_tolerance']['steady']} of {len(rows)}, "
        f"trimmed as started {doc['within_tolerance']['as_started']} of {len(rows)}"
    )


if __name__ == "__main__":
    main()
