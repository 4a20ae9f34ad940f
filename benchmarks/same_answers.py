"""The answers of a commit, hashed: logs, identification, tables, XML and the diagnosis.

    python benchmarks/same_answers.py --save FILE [--work DIR]
    python benchmarks/same_answers.py --compare FILE [--work DIR]

Flies the paper's matrix twice (the flight-test profile and noise-free, 2 jobs), identifies,
replays, and diagnoses each folder against our bare 737 (one job: with two, a JSBSim
evaluation's last digits depend on what the worker evaluated before), then hashes (SHA-256) every file a
user reads as data: the Parquet logs, ``identification/*.json``, ``*.csv`` tables, every
``*.xml`` written, ``replays/metrics.*``, ``diagnosis.json``, ``diagnosis.txt`` and
``extension.xml``. Plots and the manifest (which carries package versions and dates) are
left out. ``--save`` writes the hashes, ``--compare`` says which files differ from a saved set
and exits 1 if any does. Run it at two commits to show a refactoring changed no answer
(about 2 minutes). The work folder is emptied first and must be the same for both runs: the
diagnosis names its paths.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = [sys.executable, "-c", "import sys; from campaign.cli import main; sys.exit(main())"]
PROFILES = ("flight-test", "none")
KEPT = (".parquet", ".json", ".csv", ".xml", ".txt")
SKIPPED = ("manifest.json",)


def _campaign(*args: str) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    subprocess.run([*CAMPAIGN, *args, "--quiet"], check=True, cwd=ROOT, env=env)


def hashes(folder: Path) -> dict[str, str]:
    """SHA-256 of every data file under ``folder`` [hex], by path relative to it."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and p.suffix in KEPT and p.name not in SKIPPED and "plots" not in p.parts:
            out[str(p.relative_to(folder))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def answers(work: Path) -> dict[str, str]:
    """Fly, identify, replay and diagnose in ``work``; the hashes of what they wrote."""
    for profile in PROFILES:
        run = work / f"run-{profile}"
        _campaign("run", "--noise", profile, "--out", str(run), "--jobs", "2")
        _campaign(
            "diagnose",
            "--data",
            str(run),
            "--model",
            str(ROOT / "aircraft" / "737"),
            "--out",
            str(work / f"diagnosis-{profile}"),
            "--no-plots",
            "--jobs",
            "1",
        )
    return hashes(work)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--save", type=Path)
    mode.add_argument("--compare", type=Path)
    ap.add_argument(
        "--work", type=Path, default=Path(tempfile.gettempdir()) / "same-answers", help="where to fly (emptied first)"
    )
    a = ap.parse_args()
    work = a.work
    shutil.rmtree(work, ignore_errors=True)
    got = answers(work)
    if a.save:
        a.save.write_text(json.dumps(got, indent=1, sort_keys=True))
        print(f"{len(got)} files hashed into {a.save} (work in {work})")
        return 0
    want = json.loads(a.compare.read_text())
    differ = sorted(k for k in set(want) | set(got) if want.get(k) != got.get(k))
    for k in differ:
        print(f"differs: {k} ({'missing' if k not in got else 'new' if k not in want else 'content'})")
    print(f"{len(got)} files, {len(differ)} differ from {a.compare} (work in {work})")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
