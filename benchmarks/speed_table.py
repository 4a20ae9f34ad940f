"""One table of the tool's speed on this machine: stages with 1 and 2 jobs, peak memory, scaling.

    python benchmarks/speed_table.py [--scale N] [--seeds K] [--skip-scale | --only-scale]

Every stage runs as the command a user types (``campaign ...``) in a fresh process, on
the paper's matrix with the flight-test instrument profile. Peak memory is each
process's high-water mark (``VmHWM`` in ``/proc``), sampled every 50 ms over the
command and all its workers: the main process and the largest worker are reported. RSS
counts the shared libraries' pages in every process (about 80 MB of numpy, scipy,
pandas and JSBSim code that the workers share); the largest unique memory (USS:
``Private_Clean + Private_Dirty`` of ``/proc/<pid>/smaps_rollup``, sampled every 0.5 s) is what a
worker adds on its own.

Last part: a campaign N times the paper's points (each paper point repeated at N
altitudes 150 ft apart), flown and identified with 2 jobs, once per noise seed, and
the flying time per point against the paper matrix's.

Run by hand, outside CI (about 15 minutes on 2 cores with the defaults).
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CAMPAIGN = [sys.executable, "-c", "import sys; from campaign.cli import main; sys.exit(main())"]


#: The unique memory is sampled every this many 50 ms ticks: a read of ``smaps_rollup`` costs about
#: 2 ms a process (and takes its memory-map lock), so reading it every tick took a fifth of a core
#: from the command being timed. ``VmHWM`` is the kernel's own high-water mark: cheap, every tick.
USS_EVERY = 10


def _hwm_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _uss_kb(pid: int) -> int:
    try:
        lines = Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()
    except OSError:
        return 0
    return sum(int(ln.split()[1]) for ln in lines if ln.startswith(("Private_Clean:", "Private_Dirty:")))


def _descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        try:
            kids = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            continue
        out += [int(k) for k in kids]
        todo += [int(k) for k in kids]
    return out


def _wait_gone(pids: set[int], limit_s: float = 10.0) -> None:
    """Wait until the processes ``pids`` have ended (a zombie counts as ended).

    A command's worker server outlives its command by up to a second as it exits (its
    interpreter's teardown): the next command timed must not share the cores with it.
    """
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        alive = []
        for p in pids:
            try:
                state = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if state != "Z":
                alive.append(p)
        if not alive:
            return
        time.sleep(0.05)


def timed(args: list[str]) -> tuple[float, float, float, str, float]:
    """Wall time [s], main process and largest worker peak RSS [MB], stdout of one command, and the
    largest worker's peak unique memory (USS) [MB]."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    proc = subprocess.Popen(CAMPAIGN + args, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    peaks: dict[int, int] = {}
    uss: dict[int, int] = {}

    def sample() -> None:
        tick = 0
        while proc.poll() is None:
            for p in [proc.pid] + _descendants(proc.pid):
                peaks[p] = max(peaks.get(p, 0), _hwm_kb(p))
                if tick % USS_EVERY == 0:
                    uss[p] = max(uss.get(p, 0), _uss_kb(p))
            tick += 1
            time.sleep(0.05)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    th.join()
    _wait_gone(set(peaks) - {proc.pid})
    if proc.returncode != 0:
        raise SystemExit(f"campaign {' '.join(args)} failed ({proc.returncode}):\n{err[-2000:]}")
    main = peaks.pop(proc.pid, 0) / 1024
    worker = max((v for p, v in peaks.items() if v > 60_000), default=0) / 1024  # not the resource trackers
    unique = max((v for p, v in uss.items() if p != proc.pid), default=0) / 1024
    return wall, main, worker, out, unique


def stepping() -> tuple[float, str]:
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "stepping.py")], cwd=ROOT, text=True,
                         capture_output=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), check=True).stdout
    ratio = next(float(line.split()[-1]) for line in out.splitlines() if line.startswith("ratio"))
    return ratio, out


def scaled_matrix(factor: int, path: Path) -> int:
    """The paper matrix with every point repeated at ``factor`` altitudes 150 ft apart (1500 / ``factor`` ft
    beyond 10, so that no two points meet); returns its point count."""
    src = ROOT / "campaign" / "matrices" / "cai2024.toml"
    text = src.read_text()
    head = text[:text.index("[[points]]")]
    doc = tomllib.loads(text)
    lines = [head.replace(f'name = "{doc["name"]}"', f'name = "{doc["name"]}-x{factor}"')]
    for p in doc["points"]:
        alts = p["alt_ft"] if isinstance(p["alt_ft"], list) else [p["alt_ft"]]
        dense = [a + min(150, 1500 // factor) * k for a in alts for k in range(factor)]
        lines.append("[[points]]")
        for k, v in p.items():
            v = dense if k == "alt_ft" else v
            lines.append(f"{k} = {v!r}".replace("'", '"') if not isinstance(v, bool) else f"{k} = {str(v).lower()}")
    path.write_text("\n".join(lines) + "\n")
    from campaign.simulation.matrix import load_matrix
    return len(load_matrix(path).points)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scale", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--skip-scale", action="store_true")
    ap.add_argument("--only-scale", action="store_true", help="the scaled campaign only (and the paper matrix's "
                                                             "flying with 2 jobs, its reference)")
    a = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="speed-"))
    rows = []
    stages = {}
    if a.only_scale:
        stages["fly (138 manoeuvres)"] = {2: timed(["run", "--noise", "flight-test", "--no-identify", "--quiet",
                                                    "--out", str(work / "paper"), "--jobs", "2"])}
    for jobs in () if a.only_scale else (1, 2):
        camp = work / f"paper-j{jobs}"
        j = ["--jobs", str(jobs)]
        stages.setdefault("fly (138 manoeuvres)", {})[jobs] = timed(
            ["run", "--noise", "flight-test", "--no-identify", "--quiet", "--out", str(camp)] + j)
        stages.setdefault("identify", {})[jobs] = timed(["identify", str(camp)] + j)
        stages.setdefault("replay", {})[jobs] = timed(["replay", str(camp)] + j)
        stages.setdefault("plots (redrawn)", {})[jobs] = timed(["plots", str(camp)] + j)
        whole = work / f"whole-j{jobs}"
        stages.setdefault("run: fly through plots", {})[jobs] = timed(
            ["run", "--noise", "flight-test", "--quiet", "--out", str(whole)] + j)
        stages.setdefault("diagnose (full matrix)", {})[jobs] = timed(
            ["diagnose", "--data", str(camp), "--model", "aircraft/737", "--out", str(work / f"diag-j{jobs}"),
             "--quiet"] + j)
    for name, r in stages.items() if not a.only_scale else ():
        rows.append(f"| {name} | {r[1][0]:.1f} | {r[2][0]:.1f} | x{r[1][0] / r[2][0]:.2f} | {r[2][1]:.0f} | "
                    f"{r[2][2]:.0f} | {r[2][4]:.0f} |")
    if not a.only_scale:
        print(f"flying loop / raw fdm.run(): {stepping()[0]:.2f}\n")
        print("| stage (paper matrix, flight-test profile) | 1 job [s] | 2 jobs [s] | speed-up | main process peak "
              "[MB], 2 jobs | largest worker peak [MB], 2 jobs | largest worker unique (USS) [MB], 2 jobs |")
        print("|---|---|---|---|---|---|---|")
        print("\n".join(rows), flush=True)
    if a.skip_scale:
        shutil.rmtree(work, ignore_errors=True)
        return
    matrix = work / "scaled.toml"
    n = scaled_matrix(a.scale, matrix)
    fly_1x = stages["fly (138 manoeuvres)"][2][0]
    print(f"\ncampaign x{a.scale}: {n} points, 2 jobs, flight-test profile")
    print("| seed | fly [s] | identify [s] | fly + identify [s] | fly per point [ms] (paper matrix: "
          f"{fly_1x / 97 * 1000:.0f}) | main / worker peak [MB] |")
    print("|---|---|---|---|---|---|")
    total = 0.0
    for seed in range(a.seeds):
        camp = work / f"scaled-{seed}"
        fw, fm, fk, *_ = timed(["run", "--matrix", str(matrix), "--noise", "flight-test", "--seed", str(seed),
                               "--no-identify", "--quiet", "--jobs", "2", "--out", str(camp)])
        iw, im, ik, *_ = timed(["identify", str(camp), "--jobs", "2", "--plots", "none"])
        total += fw + iw
        print(f"| {seed} | {fw:.1f} | {iw:.1f} | {fw + iw:.1f} | {fw / n * 1000:.0f} | {max(fm, im):.0f} / "
              f"{max(fk, ik):.0f} |", flush=True)
        shutil.rmtree(camp, ignore_errors=True)
    print(f"\n{a.seeds} seeds x {n} points: {total:.0f} s; flying scales as {n / 97:.1f}x points -> "
          f"see fly per point against the paper matrix's")
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
