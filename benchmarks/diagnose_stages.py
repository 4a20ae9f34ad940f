"""``campaign diagnose`` timed stage by stage: wall time and CPU-seconds of the main process and
its workers in each stage.

    python benchmarks/diagnose_stages.py DATA_DIR [--model aircraft/737] [--jobs 2] [--json FILE]

``DATA_DIR`` is a campaign folder, for example one flown with
``campaign run --noise flight-test --no-identify --out DATA_DIR``. The diagnosis is the command's
own (:func:`campaign.cli.main`), its report written to a temporary folder and removed; the
stages are those of its progress bar (``campaign.diagnosis.run.STAGES``), "start" is everything
before the first (imports of the command, reading the logs, the model's evaluation copy).
CPU-seconds are read from ``/proc`` for the main process and every live descendant (the
workers and the process that flies replays ahead) as each stage begins; a process that ended
within a stage takes its CPU-seconds with it. ``--json`` also writes the table as data
(``benchmarks/speed_table.py`` keeps it in its result file). Run by hand, outside CI.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time

T0 = time.perf_counter()

import campaign.diagnosis.run as diagnose  # noqa: E402
from speed_table import _descendants  # noqa: E402  (this folder is the script's first path)


def cpu_seconds(pid: int) -> float:
    """CPU-seconds (user + system) of ``pid`` and its live descendants."""
    total = 0.0
    for p in [pid] + _descendants(pid):
        try:
            fields = open(f"/proc/{p}/stat").read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


class StageClock:
    """Stands in for the command's progress bar: notes the time and CPU as each stage begins."""

    marks: list[tuple[str, float, float]] = []

    def __init__(self, *args, **kwargs) -> None:
        self.n = 0

    def set_description(self, name: str) -> None:
        self.marks.append((name, time.perf_counter(), cpu_seconds(os.getpid())))

    def update(self, *args) -> None:
        pass

    def close(self) -> None:
        if not self.marks or self.marks[-1][0] != "end":  # closed once on success, once on an error
            self.marks.append(("end", time.perf_counter(), cpu_seconds(os.getpid())))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data")
    ap.add_argument("--model", default="aircraft/737")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", help="also write the stages' figures into this file")
    a = ap.parse_args()
    diagnose.tqdm = StageClock
    from campaign.cli import main as cli

    out = tempfile.mkdtemp(prefix="diagnose-stages-")
    try:
        rc = cli(
            [
                "diagnose",
                "--data",
                a.data,
                "--model",
                a.model,
                "--out",
                os.path.join(out, "report"),
                "--jobs",
                str(a.jobs),
                "--quiet",
            ]
        )
    finally:
        shutil.rmtree(out, ignore_errors=True)
    end = time.perf_counter()
    print(f"\n| stage ({a.jobs} jobs) | wall [s] | CPU [s] |\n|---|---|---|")
    prev = ("start", T0, 0.0)
    rows = {}
    for mark in StageClock.marks + [("exit", end, cpu_seconds(os.getpid()))]:
        name = "after the stages (the report's files, the workers closed)" if prev[0] == "end" else prev[0]
        print(f"| {name} | {mark[1] - prev[1]:.2f} | {mark[2] - prev[2]:.2f} |")
        rows[name] = {"wall_s": round(mark[1] - prev[1], 2), "cpu_s": round(mark[2] - prev[2], 2)}
        prev = mark
    print(f"| all (the interpreter's own start not included) | {end - T0:.2f} | {prev[2]:.2f} |")
    rows["all"] = {"wall_s": round(end - T0, 2), "cpu_s": round(prev[2], 2)}
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"jobs": a.jobs, "data": a.data, "stages": rows}, f, indent=1)
    raise SystemExit(rc)


if __name__ == "__main__":
    main()
