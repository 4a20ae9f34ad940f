"""The estimators on the real records through the command line, as a user runs them (about 2 minutes).

    python benchmarks/estimators_cli.py [WORKDIR]

Imports the HFB-320 record and the two ATTAS elevator records with the channel maps in
``docs/examples/``, runs ``campaign identify`` with each method (and, for ATTAS, the short-period
structure of ``docs/examples/short-period.toml``), and writes ``benchmarks/results/estimators_cli.json``:
per run the command, whether every point converged, the seconds it took, and the derivatives against
their reference: the published filter-error estimates (HFB-320), an output-error run of the data
set's own model structure by the estimator directly (HFB-320), the published output-error
short-period estimates (ATTAS).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from test_estimators import ATTAS_PUBLISHED, HFB_PUBLISHED_FE, HFB_START, OutputError, hfb  # noqa: E402

HFB = {
    ("CL", "dalpha_rad"): ("CLalpha", "CL_alpha"),
    ("Cm", "dalpha_rad"): ("Cmalpha", "Cm_alpha"),
    ("Cm", "qhat_rad"): ("Cmqhat", "Cm_q"),
    ("Cm", "delevator_rad"): ("Cmde_rad", "Cm_de"),
}
TC11 = {
    "Z_alpha_per_s": "Zalpha",
    "Z_q": "Zq",
    "Z_de_per_s": "Zde",
    "M_alpha_per_s2": "Malpha",
    "M_q_per_s": "Mq",
    "M_de_per_s2": "Mde",
}
IMPORTS = {
    "hfb": [("tests/data/hfb320_1_10.asc", "docs/examples/hfb320-map.toml")],
    "attas": [
        ("tests/data/fAttasElv1.mat", "docs/examples/attas-elv1-map.toml"),
        ("tests/data/fAttasElv2.mat", "docs/examples/attas-elv2-map.toml"),
    ],
}


def campaign(work: Path, *args: str) -> tuple[int, float]:
    env = dict(os.environ, PYTHONPATH=str(ROOT), JSBSIM_DEBUG="0")
    t0 = time.perf_counter()
    code = subprocess.run(
        [sys.executable, "-m", "campaign.cli", *args], cwd=work, env=env, capture_output=True, text=True
    ).returncode
    return code, time.perf_counter() - t0


def main(work: Path) -> None:
    work.mkdir(parents=True, exist_ok=True)
    for folder, files in IMPORTS.items():
        for data, mp in files:
            code, _ = campaign(work, "import", str(ROOT / data), "--map", str(ROOT / mp), "--out", folder)
            assert code == 0, (data, code)
    model, rec = hfb()
    independent = OutputError(model, [rec], HFB_START).fit()
    rows = []
    runs = [("HFB-320", "hfb", m, ()) for m in ("ee", "oe", "fe")]
    runs += [("ATTAS", "attas", m, ()) for m in ("ee", "oe", "fe")]
    runs += [("ATTAS", "attas", "oe", ("--structure", "docs/examples/short-period.toml"))]
    for record, folder, method, extra in runs:
        out = f"{folder}-{method}{'-sp' if extra else ''}"
        args = [
            "identify",
            folder,
            "--method",
            method,
            "--plots",
            "none",
            "--out",
            out,
            *(a if a.startswith("--") else str(ROOT / a) for a in extra),
        ]
        code, seconds = campaign(work, *args)
        doc = json.loads((work / out / "identification.json").read_text())
        point = next(iter(doc["points"].values()))
        row = {
            "record": record,
            "method": method,
            "structure": "short period" if extra else "default",
            "command": "campaign " + " ".join(a.replace(str(ROOT) + "/", "") for a in args),
            "exit_code": code,
            "seconds": round(seconds, 1),
            "points": len(doc["points"]),
            "not_converged": len(doc.get("not_converged", [])),
            "point_method": point["method"],
        }
        if record == "HFB-320":
            row["derivatives"] = {
                label: {
                    "ours": point[c]["params"].get(t),
                    "published_fe": HFB_PUBLISHED_FE[name],
                    "independent_oe": float(independent.params[name]),
                }
                for (c, t), (name, label) in HFB.items()
            }
        elif extra:
            td = point["timedomain"]
            row["derivatives"] = {
                k: {"ours": td["derivatives"][k], "published_oe": ATTAS_PUBLISHED[v]} for k, v in TC11.items()
            }
        else:
            row["derivatives"] = {label: {"ours": point[c]["params"].get(t)} for (c, t), (_, label) in HFB.items()}
            if "timedomain" in point and "derivatives" in point["timedomain"]:
                row["dimensional"] = point["timedomain"]["derivatives"]
        if "timedomain" in point:
            row["left_out"] = point["timedomain"]["structure"]["left_out"]
        rows.append(row)
        print(json.dumps(row))
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    doc = {
        "benchmark": "estimators on real records through the command line",
        "command": "python benchmarks/estimators_cli.py",
        "code_commit": commit,
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "setup": "each record imported with its channel map in docs/examples/, then `campaign identify`; "
        "seconds on a shared 2-core machine (noisy)",
        "rows": rows,
    }
    (ROOT / "benchmarks" / "results" / "estimators_cli.json").write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="estcli-")))
