"""What every benchmark's result file begins with: the benchmark, the command that measured it, the commit of
the code it measured and the date."""

from __future__ import annotations

import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def provenance(name: str) -> dict:
    """``benchmark``, ``command`` (``python benchmarks/<name>.py`` and this run's arguments),
    ``recorded_at_commit`` (the checkout's HEAD) and ``date`` (UTC, to the second)."""
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    return {
        "benchmark": name,
        "command": f"python benchmarks/{name}.py " + " ".join(sys.argv[1:]),
        "recorded_at_commit": commit,
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
