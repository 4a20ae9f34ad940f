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
    ``recorded_at_commit`` (the checkout's HEAD), ``uncommitted_changes`` (the tracked files differ from it:
    the code measured is not that commit's) and ``date`` (UTC, to the second)."""

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], capture_output=True, text=True, cwd=ROOT).stdout.strip()

    return {
        "benchmark": name,
        "command": f"python benchmarks/{name}.py " + " ".join(sys.argv[1:]),
        "recorded_at_commit": git("rev-parse", "HEAD"),
        "uncommitted_changes": bool(git("status", "--porcelain", "--untracked-files=no")),
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
