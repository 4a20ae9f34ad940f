"""A campaign N times the paper's points flown on a Dask LocalCluster, then identified: times and
the identification's main-process peak memory.

    python benchmarks/scale_identify.py [--scale N] [--work DIR] [--cluster-workers K]

Each paper point is repeated at N altitudes 150 ft apart (``speed_table.scaled_matrix``), flown
through the flight-test profile with ``campaign run --cluster`` on a LocalCluster of K one-thread
workers on 127.0.0.1, then ``campaign identify --jobs 2`` runs in a fresh process whose
high-water mark (``VmHWM``) is sampled with its workers' (``speed_table``). Run by hand, outside
CI: about 15 minutes for N = 100 (9,700 points, 6 GB of logs) on 2 cores.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import dask
from distributed import LocalCluster

sys.path.insert(0, str(Path(__file__).resolve().parent))
from speed_table import CAMPAIGN, ROOT, scaled_matrix, timed  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=int, default=100)
    ap.add_argument("--work", type=Path)
    ap.add_argument("--cluster-workers", type=int, default=2)
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="scale-identify-"))
    work.mkdir(parents=True, exist_ok=True)
    n = scaled_matrix(a.scale, work / "scaled.toml")
    camp = work / "campaign"
    with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
        with LocalCluster(
            n_workers=a.cluster_workers, threads_per_worker=1, host="127.0.0.1", dashboard_address=None, silence_logs=50
        ) as cluster:
            t0 = time.perf_counter()
            subprocess.run(
                [
                    *CAMPAIGN,
                    "run",
                    "--matrix",
                    str(work / "scaled.toml"),
                    "--noise",
                    "flight-test",
                    "--out",
                    str(camp),
                    "--cluster",
                    cluster.scheduler_address,
                    "--no-identify",
                    "--quiet",
                ],
                check=True,
                cwd=ROOT,
            )
            fly_s = time.perf_counter() - t0
    r = timed(["identify", str(camp), "--jobs", "2"])
    print(
        f"x{a.scale}: {n} points flown on a LocalCluster of {a.cluster_workers} workers in {fly_s:.0f} s "
        f"({1000 * fly_s / n:.0f} ms a point); identify --jobs 2: {r.wall_s:.0f} s, main process peak "
        f"{r.main_mb:.0f} MB, largest worker peak {r.worker_mb:.0f} MB (work in {work})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
