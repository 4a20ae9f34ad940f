"""The paper's matrix flown locally (``--jobs 2``) and on a Dask LocalCluster (2 workers on
127.0.0.1): wall times, and whether the logs are bit-identical.

    python benchmarks/cluster_vs_local.py [MATRIX]

Run by hand, outside CI.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import dask
from distributed import LocalCluster

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.cli import main  # noqa: E402


def timed(argv: list[str]) -> float:
    t0 = time.perf_counter()
    assert main(argv) == 0
    return time.perf_counter() - t0


def run(matrix: str | None = None) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="cluster-bench-"))
    common = ["--no-identify", "--quiet", "--noise", "flight-test"] + (["--matrix", matrix] if matrix else [])
    local = timed(["run", "--out", str(tmp / "local"), "--jobs", "2"] + common)
    with dask.config.set({"distributed.scheduler.worker-saturation": 1.0}):
        t0 = time.perf_counter()
        with LocalCluster(
            n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None, silence_logs=50
        ) as cluster:
            start = time.perf_counter() - t0
            remote = timed(["run", "--out", str(tmp / "dask"), "--cluster", cluster.scheduler_address] + common)
    a = {p.name: p.read_bytes() for p in (tmp / "local").glob("*.parquet")}
    b = {p.name: p.read_bytes() for p in (tmp / "dask").glob("*.parquet")}
    print(
        f"{len(a)} logs; local --jobs 2: {local:.1f} s; LocalCluster (2 workers): {remote:.1f} s "
        f"(+{start:.1f} s to start the cluster); bit-identical: {a == b}"
    )


if __name__ == "__main__":
    run(*sys.argv[1:2])
