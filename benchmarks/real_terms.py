"""Terms taken out of models identified on real flight records: is the first cause the term, and does the
record held out confirm it? (run by hand, about 2 min on 2 cores).

    python benchmarks/real_terms.py [--json FILE]

Each of DLR's records (``tests/data/``: the two ATTAS elevator records, and the HFB-320 record cut into its
3-2-1-1 and its pulse) is imported with its map (``docs/examples/``), identified on its own by equation error
and built into a JSBSim aircraft (``campaign model``). Each model is diagnosed on its own record with the
other record of the same aeroplane held out: as identified, and with one identified parameter changed
(:data:`CHANGES`). A change in :data:`NAMED` must be named first (its coefficient and variable) and confirmed
on the held-out record; the others are smaller (a 20 % pitch stiffness, a quadratic term, a constant offset)
and recorded as the diagnosis answers them.

``--json`` writes the rows (default ``benchmarks/results/real_terms.json``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from campaign.cli import main as campaign  # noqa: E402
from campaign.diagnosis.run import load_data  # noqa: E402
from diagnose.diagnosis import diagnose  # noqa: E402
from diagnose.evaluate import ModelEvaluator  # noqa: E402
from provenance import provenance  # noqa: E402  (this folder is the script's first path)

DATA, EXAMPLES = ROOT / "tests" / "data", ROOT / "docs" / "examples"
#: Changes that must be named first: (coefficient, regressor, factor) -> (coefficient, first variable).
NAMED = {
    ("Cm", "qhat_rad", 0.5): ("Cm", "qhat_rad"),
    ("CL", "dalpha_rad", 0.8): ("CL", "alpha_deg"),
    ("Cm", "delevator_rad", 0.0): ("Cm", "elevator_deg"),
    ("CL", "delevator_rad", 0.0): ("CL", "elevator_deg"),
    ("CL", "qhat_rad", 0.0): ("CL", "qhat_rad"),
    ("CD", "dalpha_rad", 0.0): ("CD", "alpha_deg"),
}
#: Every change tried: those of :data:`NAMED`, then smaller ones.
CHANGES = (
    *NAMED,
    ("Cm", "dalpha_rad", 0.8),
    ("CD", "dalpha2_rad2", 0.0),
    ("Cm", "dalpha2_rad2", 0.0),
    ("CL", "const", 1.03),
    ("CD", "const", 1.1),
)


def _records(work: Path) -> dict[str, tuple[Path, list, str]]:
    """Each record imported into a folder of its own: ``{name: (folder, logs, the other record's name)}``."""
    out = {}
    attas = (EXAMPLES / "attas-map.toml").read_text()
    for k in (1, 2):
        folder = work / f"attas-elv{k}"
        (work / "attas-map.toml").write_text(attas)
        campaign(
            ["import", str(DATA / f"fAttasElv{k}.mat"), "--map", str(work / "attas-map.toml"), "--out", str(folder)]
        )
        out[f"ATTAS fAttasElv{k}"] = (folder, load_data(folder), f"ATTAS fAttasElv{3 - k}")
    (work / "hfb-map.toml").write_text((EXAMPLES / "hfb320-map.toml").read_text() + "\n[records]\nsplit_s = [22.0]\n")
    both = work / "hfb"
    campaign(["import", str(DATA / "hfb320_1_10.asc"), "--map", str(work / "hfb-map.toml"), "--out", str(both)])
    for stem, name, other in (("hfb320_1_10_1", "3-2-1-1", "pulse"), ("hfb320_1_10_2", "pulse", "3-2-1-1")):
        folder = work / f"hfb-{name}"
        folder.mkdir()
        shutil.copy(both / f"{stem}.parquet", folder)
        out[f"HFB-320 {name}"] = (folder, load_data(folder), f"HFB-320 {other}")
    return out


def _model(ident: Path, out: Path, change: tuple | None) -> Path | None:
    """``campaign model`` of the identification, one parameter of its point changed first (None if the
    identification has no such parameter)."""
    if change is not None:
        doc = json.loads((ident / "identification.json").read_text())
        point = next(iter(doc["points"].values()))
        c, reg, k = change
        if not point[c]["params"].get(reg):
            return None
        copy = out.parent / "identification"
        shutil.copytree(ident, copy)
        point[c]["params"][reg] *= k
        point["log"] = str((ident / point["log"]).resolve())
        (copy / "identification.json").write_text(json.dumps(doc))
        ident = copy
    campaign(["model", str(ident), "--out", str(out)])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "real_terms.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        records = _records(work)
        for name, (folder, logs, other) in records.items():
            campaign(["identify", str(folder), "--plots", "none"])
            for j, change in enumerate((None, *CHANGES)):
                model = _model(folder / "identification", work / "models" / f"{folder.name}-{j}" / "model", change)
                if model is None:
                    rows.append({"record": name, "change": list(change), "result": "not in the model"})
                    continue
                diag = diagnose(logs, ModelEvaluator(model), held=records[other][1])
                aero = diag.aero_causes
                first = aero[0] if aero else None
                row = {
                    "record": name,
                    "held_out": other,
                    "change": list(change) if change else None,
                    "first_aero": [first.coefficient, *first.variables] if first else None,
                    "held_out_gain": first.verdict.get("held_out_logs_gain") if first else None,
                    "sensor_causes": [f"{c.channel} {c.error}" for c in diag.causes if c.kind == "sensor"],
                }
                if change in NAMED:
                    row["right"] = bool(first) and (first.coefficient, first.variables[0]) == NAMED[change]
                if not aero:
                    row["said"] = diag.summary().split("\n")[0] if not diag.causes else "sensor causes only"
                    largest = [ln.strip() for ln in diag.summary().splitlines() if "largest candidate" in ln]
                    row["largest_candidate"] = largest[0] if largest else None
                rows.append(row)
                print(name, change, row.get("first_aero"), row.get("held_out_gain"), row.get("right", ""), flush=True)
    must = [r for r in rows if "right" in r]
    doc = {
        **provenance("real_terms"),
        "records": list(records),
        "named_cases": len(must),
        "named_right": sum(r["right"] for r in must),
        "named_gains": [min(r["held_out_gain"] for r in must if r["right"]), max(r["held_out_gain"] for r in must)],
        "as_identified_aero_causes": sum(bool(r["first_aero"]) for r in rows if r.get("change") is None),
        "rows": rows,
    }
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"{doc['named_right']} of {doc['named_cases']} terms taken out named first and confirmed")


if __name__ == "__main__":
    main()
