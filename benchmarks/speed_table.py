"""The tool's speed on this machine, as the commands a user types: one result file per run.

    python benchmarks/speed_table.py [--scale N] [--seeds K] [--skip-scale | --only-scale]
                                     [--diagnosis-only] [--repeat R] [--code DIR --commit SHA]
                                     [--out FILE | --no-write]

Every stage runs as the command a user types (``campaign ...``) in a fresh process, on the paper's
matrix with the flight-test instrument profile, with 1 and 2 jobs; then the diagnosis with 2 jobs
(``R`` times each, without plots, with the key plots, and on a campaign three times the paper's
points), stage by stage (``diagnose_stages.py``); the flying loop against raw stepping
(``stepping.py``); and a campaign N times the paper's points (each point repeated at N altitudes
150 ft apart), flown and identified with 2 jobs, once per noise seed.

For each command: wall time; CPU-seconds of the command and every process it started (``utime +
stime`` in ``/proc/<pid>/stat``, sampled every 50 ms: a process's last 50 ms may be missed); each
process's high-water mark (``VmHWM``, its last reading: a forked worker starts from its fork server's),
reported for the main process, the largest worker and summed over the main process and its workers
(the fork server and the resource tracker, which compute nothing, apart); the largest worker's unique memory (USS, ``Private_Clean +
Private_Dirty`` of ``smaps_rollup``, every 0.5 s: RSS counts the shared libraries' pages, about 80
MB of numpy, scipy, pandas and JSBSim code, in every process) and the processes' proportional memory
(PSS) summed, what the command took from the machine; and how busy the machine was with
other work meanwhile (the CPU-seconds of ``/proc/stat`` not ours, over the wall time and the cores).

The figures go into ``benchmarks/results/speed/<date>-<commit>.json`` (the machine, the commit and
its date, every figure, the command); ``benchmarks/compare.py`` compares the last two and names what
got slower, and ``benchmarks/tables.py`` writes the documentation's speed page from the newest.
``--code DIR --commit SHA`` measures another checkout of the tool (a ``git archive`` of an older
commit: the same commands, run there), for a before and after in one sitting. Run by hand, outside
CI (about 20 minutes on 2 cores with the defaults).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "speed"
CAMPAIGN = [sys.executable, "-c", "import sys; from campaign.cli import main; sys.exit(main())"]
#: The checkout the commands run from (``--code``): this one unless told.
CODE = [ROOT]


#: The unique memory is sampled every this many 50 ms ticks: a read of ``smaps_rollup`` costs about
#: 2 ms a process (and takes its memory-map lock), so reading it every tick took a fifth of a core
#: from the command being timed. ``VmHWM`` is the kernel's own high-water mark: cheap, every tick.
USS_EVERY = 10
TICK = os.sysconf("SC_CLK_TCK")


def _hwm_kb(pid: int) -> int:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def _uss_pss_kb(pid: int) -> tuple[int, int]:
    """Unique (``Private_Clean + Private_Dirty``) and proportional (``Pss``: each shared page divided among
    the processes that map it) memory of ``pid`` [kB]."""
    try:
        lines = Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()
    except OSError:
        return 0, 0
    return (
        sum(int(ln.split()[1]) for ln in lines if ln.startswith(("Private_Clean:", "Private_Dirty:"))),
        sum(int(ln.split()[1]) for ln in lines if ln.startswith("Pss:")),
    )


def _cpu_s(pid: int) -> float | None:
    """CPU-seconds (user + system) process ``pid`` has used, or None if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICK


def _role(pid: int, main: int) -> str:
    """``main``, ``fork server``, ``resource tracker`` or ``worker`` (what computes beside the main process)."""
    if pid == main:
        return "main"
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        parent = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, ValueError):
        return "worker"
    if b"resource_tracker" in cmd:
        return "resource tracker"
    if b"forkserver import main" in cmd and parent == main:
        return "fork server"
    return "worker"


def _machine_busy_s() -> float:
    """CPU-seconds every process of the machine has used since boot (``/proc/stat``, idle and iowait
    left out)."""
    v = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    return (sum(v[:8]) - v[3] - v[4]) / TICK


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


@dataclass
class Run:
    """One command timed (:func:`timed`).

    Attributes
    ----------
    wall_s, cpu_s : float
        Wall time and the CPU-seconds of the command and every process it started [s].
    main_mb, worker_mb, unique_mb : float
        Peak RSS of the main process and of the largest worker, the largest worker's peak unique memory [MB].
    sum_mb : float
        Peak RSS of the main process and every worker, summed (each its own peak) [MB].
    all_mb : float
        The same with the fork server and the resource tracker [MB].
    pss_mb : float
        Each process's peak proportional memory (PSS, every 0.5 s: a page shared by k processes counts
        1/k in each), summed over all of them: the memory the command took from the machine, about [MB].
    others_busy : float
        The share of the machine's cores that other work used meanwhile (0 to 1).
    load : list of float
        The 1-minute load average before and after.
    processes : list of dict
        Each process: its role, peak RSS [MB] and CPU [s].
    """

    wall_s: float
    cpu_s: float
    main_mb: float
    worker_mb: float
    unique_mb: float
    sum_mb: float
    all_mb: float
    pss_mb: float
    others_busy: float
    load: list[float]
    processes: list[dict] = field(default_factory=list)
    out: str = field(default="", repr=False)

    def figures(self) -> dict:
        return {k: (round(v, 2) if isinstance(v, float) else v) for k, v in asdict(self).items() if k != "out"}


def _load() -> float:
    return float(Path("/proc/loadavg").read_text().split()[0])


def _env(code: Path, path: str | None = None) -> dict:
    """The commands' environment: the checkout ``code`` first on the path, Python's compiled bytecode
    written and read as an installed package's is (an environment that forbids it,
    ``PYTHONDONTWRITEBYTECODE``, compiles every module of the tool again in each process: 2-3 s of CPU a
    command)."""
    return dict(os.environ, PYTHONPATH=path or str(code), JSBSIM_DEBUG="0", PYTHONDONTWRITEBYTECODE="")


def compiled(code: Path) -> None:
    """The tool's modules compiled once (their ``__pycache__``), before anything is timed."""
    subprocess.run(
        [
            sys.executable,
            "-c",
            "import campaign.cli.main, campaign.diagnosis.run, diagnose.plots, "
            "campaign.orchestration.runner, identify.pipeline, identify.plots, campaign.replays.replay, "
            "campaign.replays.report",
        ],
        cwd=code,
        env=_env(code),
        check=True,
    )


def timed(args: list[str], cwd: Path | None = None) -> Run:
    """Run ``campaign ARGS`` in a fresh process from the checkout :data:`CODE` and time it (:class:`Run`)."""
    code = CODE[0]
    env = _env(code)
    load0, busy0 = _load(), _machine_busy_s()
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        CAMPAIGN + args, cwd=cwd or code, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    peaks: dict[int, int] = {}
    uss: dict[int, int] = {}
    pss: dict[int, int] = {}
    cpu: dict[int, float] = {}
    roles: dict[int, str] = {}

    def sample() -> None:
        tick = 0
        while proc.poll() is None:
            for p in [proc.pid] + _descendants(proc.pid):
                # the last reading, not the largest: a child read between its fork and its exec shows its
                # parent's memory (vfork shares it), and its own high-water mark starts again at the exec
                peaks[p] = _hwm_kb(p) or peaks.get(p, 0)
                c = _cpu_s(p)
                if c is not None:
                    cpu[p] = max(cpu.get(p, 0.0), c)
                if p not in roles:
                    roles[p] = _role(p, proc.pid)
                if tick % USS_EVERY == 0:
                    u, q = _uss_pss_kb(p)
                    uss[p], pss[p] = max(uss.get(p, 0), u), max(pss.get(p, 0), q)
            tick += 1
            time.sleep(0.05)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    out, err = proc.communicate()
    wall = time.perf_counter() - t0
    th.join()
    _wait_gone(set(peaks) - {proc.pid})
    busy = _machine_busy_s() - busy0
    if proc.returncode != 0:
        raise SystemExit(f"campaign {' '.join(args)} failed ({proc.returncode}):\n{err[-2000:]}")
    workers = [p for p, r in roles.items() if r == "worker" and peaks.get(p, 0) > 0]
    mb = {p: v / 1024 for p, v in peaks.items()}
    ours = sum(cpu.values())
    return Run(
        wall,
        ours,
        mb.pop(proc.pid, 0.0),
        max((mb[p] for p in workers), default=0.0),
        max((uss.get(p, 0) / 1024 for p in workers), default=0.0),
        peaks.get(proc.pid, 0) / 1024 + sum(mb[p] for p in workers),
        sum(v / 1024 for v in peaks.values()),
        sum(pss.values()) / 1024,
        max(busy - ours, 0.0) / (wall * (os.cpu_count() or 1)),
        [load0, _load()],
        [
            {"role": roles.get(p, "main"), "peak_mb": round(peaks[p] / 1024), "cpu_s": round(cpu.get(p, 0.0), 2)}
            for p in sorted(peaks)
        ],
        out,
    )


def stepping() -> tuple[float, str]:
    code = CODE[0]
    script = code / "benchmarks" / "stepping.py"
    out = subprocess.run(
        [sys.executable, str(script if script.exists() else ROOT / "benchmarks" / "stepping.py")],
        cwd=code,
        text=True,
        capture_output=True,
        check=True,
        env=_env(code),
    ).stdout
    ratio = next(float(line.split()[-1]) for line in out.splitlines() if line.startswith("ratio"))
    return ratio, out


def diagnose_stages(data: Path, jobs: int = 2) -> dict:
    """``diagnose_stages.py DATA`` (of this checkout, on the code of :data:`CODE`): each stage's wall and CPU
    seconds."""
    code = CODE[0]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "stages.json"
        subprocess.run(
            [
                sys.executable,
                str(ROOT / "benchmarks" / "diagnose_stages.py"),
                str(data),
                "--jobs",
                str(jobs),
                "--model",
                str(code / "aircraft" / "737"),
                "--json",
                str(path),
            ],
            cwd=code,
            env=_env(code, f"{code}{os.pathsep}{ROOT / 'benchmarks'}"),
            check=True,
            capture_output=True,
            text=True,
        )
        return json.loads(path.read_text())


def scaled_matrix(factor: int, path: Path) -> int:
    """The paper matrix with every point repeated at ``factor`` altitudes 150 ft apart (1500 / ``factor`` ft
    beyond 10, so that no two points meet); returns its point count."""
    from campaign.simulation.matrix import DEFAULT_MATRIX, load_matrix

    text = DEFAULT_MATRIX.read_text()
    head = text[: text.index("[[points]]")]
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
    return len(load_matrix(path).points)


def machine() -> dict:
    """What the figures were measured on."""
    model = next(
        (
            ln.split(":", 1)[1].strip()
            for ln in Path("/proc/cpuinfo").read_text().splitlines()
            if ln.startswith("model name")
        ),
        platform.processor(),
    )
    mem = next(int(ln.split()[1]) for ln in Path("/proc/meminfo").read_text().splitlines() if ln.startswith("MemTotal"))
    import jsbsim
    import numpy

    return {
        "host": platform.node(),
        "cpu": model,
        "cores": os.cpu_count(),
        "memory_gb": round(mem / 2**20, 1),
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "jsbsim": jsbsim.__version__,
    }


def commit_of(code: Path) -> tuple[str, str]:
    """The commit and its date of a git checkout (``unknown`` elsewhere)."""
    try:
        out = subprocess.run(
            ["git", "-C", str(code), "log", "-1", "--format=%H %cI"], capture_output=True, text=True, check=True
        ).stdout.split()
        dirty = subprocess.run(
            ["git", "-C", str(code), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        return out[0] + ("+changes" if dirty else ""), out[1]
    except (subprocess.CalledProcessError, FileNotFoundError, IndexError):
        return "unknown", ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scale", type=int, default=10)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--skip-scale", action="store_true")
    ap.add_argument(
        "--only-scale",
        action="store_true",
        help="the scaled campaign only (and the paper matrix's flying with 2 jobs, its reference)",
    )
    ap.add_argument(
        "--diagnosis-only", action="store_true", help="the diagnosis's figures only (and the paper matrix flown for it)"
    )
    ap.add_argument("--repeat", type=int, default=3, help="runs of each diagnosis (the median is kept)")
    ap.add_argument("--code", type=Path, help="another checkout of the tool to measure (default: this one)")
    ap.add_argument("--commit", help="the commit of --code when it is no git checkout (a git archive)")
    ap.add_argument("--out", type=Path, help="the result file (default: benchmarks/results/speed/<date>-<commit>.json)")
    ap.add_argument("--no-write", action="store_true", help="print only")
    a = ap.parse_args()
    CODE[0] = (a.code or ROOT).resolve()
    commit, commit_date = (a.commit, "") if a.commit else commit_of(CODE[0])
    started = datetime.now(timezone.utc)
    compiled(CODE[0])
    work = Path(tempfile.mkdtemp(prefix="speed-"))
    doc = {
        "benchmark": "speed_table",
        "command": "python benchmarks/speed_table.py " + " ".join(sys.argv[1:]),
        "code_commit": commit,
        "code_date": commit_date,
        "date": started.isoformat(timespec="seconds"),
        "machine": machine(),
        "figures": {},
        "stages": {},
    }
    fig = doc["figures"]
    paper = work / "paper-j2"
    rows = []
    if a.only_scale or a.diagnosis_only:
        fig["fly (138 manoeuvres), 2 jobs"] = timed(
            ["run", "--noise", "flight-test", "--no-identify", "--quiet", "--out", str(paper), "--jobs", "2"]
        ).figures()
    if not (a.only_scale or a.diagnosis_only):
        for jobs in (1, 2):
            camp = work / f"paper-j{jobs}"
            j = ["--jobs", str(jobs)]
            for name, args in (
                (
                    "fly (138 manoeuvres)",
                    ["run", "--noise", "flight-test", "--no-identify", "--quiet", "--out", str(camp)],
                ),
                ("identify", ["identify", str(camp)]),
                ("replay", ["replay", str(camp)]),
                ("plots (redrawn)", ["plots", str(camp)]),
                (
                    "run: fly through plots",
                    ["run", "--noise", "flight-test", "--quiet", "--out", str(work / f"whole-j{jobs}")],
                ),
                (
                    "diagnose (full matrix)",
                    [
                        "diagnose",
                        "--data",
                        str(camp),
                        "--model",
                        str(CODE[0] / "aircraft" / "737"),
                        "--out",
                        str(work / f"diag-j{jobs}"),
                        "--quiet",
                    ],
                ),
            ):
                fig[f"{name}, {jobs} job{'s' if jobs > 1 else ''}"] = timed(args + j).figures()
        for name in (
            "fly (138 manoeuvres)",
            "identify",
            "replay",
            "plots (redrawn)",
            "run: fly through plots",
            "diagnose (full matrix)",
        ):
            one, two = fig[f"{name}, 1 job"], fig[f"{name}, 2 jobs"]
            rows.append(
                f"| {name} | {one['wall_s']:.1f} | {two['wall_s']:.1f} | "
                f"x{one['wall_s'] / two['wall_s']:.2f} | {two['cpu_s']:.1f} | {two['main_mb']:.0f} | "
                f"{two['worker_mb']:.0f} | {two['unique_mb']:.0f} | {two['sum_mb']:.0f} |"
            )
        print(
            "| stage (paper matrix, flight-test profile) | 1 job [s] | 2 jobs [s] | speed-up | CPU, 2 jobs [s] | "
            "main peak [MB] | largest worker peak [MB] | largest worker USS [MB] | main + workers peak [MB] |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        print("\n".join(rows), flush=True)
        ratio, _ = stepping()
        fig["flying loop / raw fdm.run()"] = {"ratio": ratio}
        print(f"\nflying loop / raw fdm.run(): {ratio:.2f}\n")
    if not a.only_scale:
        diagnosis(a, work, paper, fig, doc)
    if not a.skip_scale and not a.diagnosis_only:
        scaled(a, work, fig)
    shutil.rmtree(work, ignore_errors=True)
    if not a.no_write:
        out = a.out or RESULTS / f"{started.strftime('%Y-%m-%dT%H%M')}-{commit[:7]}.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"\nfigures in {out}")


#: The diagnoses timed: name -> extra arguments and the campaign (1: the paper matrix, 3: three times its points).
DIAGNOSES = {
    "diagnose, no plots": (["--no-plots"], 1),
    "diagnose, key plots": ([], 1),
    "diagnose x3 (291 points), no plots": (["--no-plots"], 3),
}


def diagnosis(a, work: Path, paper: Path, fig: dict, doc: dict) -> None:
    """The diagnosis with 2 jobs, each of :data:`DIAGNOSES` ``a.repeat`` times, and stage by stage."""
    if not paper.exists():
        timed(["run", "--noise", "flight-test", "--no-identify", "--quiet", "--out", str(paper), "--jobs", "2"])
    n = scaled_matrix(3, work / "x3.toml")
    x3 = work / "paper-x3"
    fig[f"fly x3 ({n} points), 2 jobs"] = timed(
        [
            "run",
            "--matrix",
            str(work / "x3.toml"),
            "--noise",
            "flight-test",
            "--no-identify",
            "--quiet",
            "--out",
            str(x3),
            "--jobs",
            "2",
        ]
    ).figures()
    print(
        "| diagnosis, 2 jobs (median of runs) | wall [s] | CPU [s] | main peak [MB] | largest worker peak [MB] | "
        "main + workers peak [MB] | PSS [MB] | others' share of the cores |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, (extra, scale) in DIAGNOSES.items():
        data = paper if scale == 1 else x3
        runs = []
        for k in range(a.repeat):
            runs.append(
                timed(
                    [
                        "diagnose",
                        "--data",
                        str(data),
                        "--model",
                        str(CODE[0] / "aircraft" / "737"),
                        "--out",
                        str(work / f"diag-{scale}-{len(extra)}-{k}"),
                        "--quiet",
                        "--jobs",
                        "2",
                    ]
                    + extra
                )
            )
        fig[name] = {
            **{
                k: sorted(getattr(r, k) for r in runs)[len(runs) // 2]
                for k in (
                    "wall_s",
                    "cpu_s",
                    "main_mb",
                    "worker_mb",
                    "unique_mb",
                    "sum_mb",
                    "all_mb",
                    "pss_mb",
                    "others_busy",
                )
            },
            "runs": [r.figures() for r in runs],
        }
        f = fig[name]
        print(
            f"| {name} | {f['wall_s']:.1f} | {f['cpu_s']:.1f} | {f['main_mb']:.0f} | {f['worker_mb']:.0f} | "
            f"{f['sum_mb']:.0f} | {f['pss_mb']:.0f} | {f['others_busy']:.2f} |",
            flush=True,
        )
    doc["stages"] = diagnose_stages(paper)


def scaled(a, work: Path, fig: dict) -> None:
    """A campaign ``a.scale`` times the paper's points, flown and identified with 2 jobs once per seed."""
    matrix = work / "scaled.toml"
    n = scaled_matrix(a.scale, matrix)
    ref = next((fig[k]["wall_s"] for k in ("fly (138 manoeuvres), 2 jobs",) if k in fig), None)
    print(f"\ncampaign x{a.scale}: {n} points, 2 jobs, flight-test profile")
    print(
        "| seed | fly [s] | identify [s] | fly + identify [s] | fly per point [ms] (paper matrix: "
        f"{ref / 97 * 1000 if ref else float('nan'):.0f}) | main / worker peak [MB] |"
    )
    print("|---|---|---|---|---|---|")
    for seed in range(a.seeds):
        camp = work / f"scaled-{seed}"
        fly = timed(
            [
                "run",
                "--matrix",
                str(matrix),
                "--noise",
                "flight-test",
                "--seed",
                str(seed),
                "--no-identify",
                "--quiet",
                "--jobs",
                "2",
                "--out",
                str(camp),
            ]
        )
        ident = timed(["identify", str(camp), "--jobs", "2", "--plots", "none"])
        fig[f"x{a.scale} ({n} points) seed {seed}: fly, 2 jobs"] = fly.figures()
        fig[f"x{a.scale} ({n} points) seed {seed}: identify, 2 jobs"] = ident.figures()
        print(
            f"| {seed} | {fly.wall_s:.1f} | {ident.wall_s:.1f} | {fly.wall_s + ident.wall_s:.1f} | "
            f"{fly.wall_s / n * 1000:.0f} | {max(fly.main_mb, ident.main_mb):.0f} / "
            f"{max(fly.worker_mb, ident.worker_mb):.0f} |",
            flush=True,
        )
        shutil.rmtree(camp, ignore_errors=True)


if __name__ == "__main__":
    main()
