"""Generated bad inputs against the command line: each must exit with code 2 and one line naming the
file and the field, without a traceback, and leave the disk as it was.

    python benchmarks/bad_input_sweep.py [--n 1200] [--seed 0] [--subprocess 24]

Six kinds in turn (:mod:`campaign.validation.bad_inputs`): test matrices, import maps, measured data
files, instrument profiles, effect overlays and command lines, each a valid input with one thing made
wrong at random. The CLI's ``main()`` runs in this process; ``--subprocess`` of the cases run again
as real processes (an abort or a signal shows only there). Before and after every case the results
folder that the cases read (a campaign imported from the HFB-320 record), the shipped aircraft and the
inputs' own sources are hashed, names, bytes and times. Writes
``benchmarks/results/bad_input_sweep.json``.
"""

from __future__ import annotations

import argparse
import collections
import datetime
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("JSBSIM_DEBUG", "0")

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from aircraft import SHIPPED_737  # noqa: E402
from campaign.cli import main as cli  # noqa: E402
from campaign.validation.bad_inputs import KINDS, attempt, clean, context, make_cases, tree_hash  # noqa: E402

DATA = ROOT / "tests" / "data" / "hfb320_1_10.asc"
MAP = ROOT / "docs" / "examples" / "hfb320-map.toml"
RESULT = ROOT / "benchmarks" / "results" / "bad_input_sweep.json"


def _watched(results: Path) -> dict[str, str]:
    return {
        "results folder": tree_hash(results),
        "shipped aircraft": tree_hash(SHIPPED_737),
        **{
            name: hashlib.sha256(f.read_bytes() + str(f.stat().st_mtime_ns).encode()).hexdigest()
            for name, f in (("measured file", DATA), ("map", MAP))
        },
    }


def in_subprocess(case) -> dict:
    """The case as a real process: its exit code (a signal is negative) and stderr."""
    done = subprocess.run(
        [sys.executable, "-m", "campaign.cli", *case.argv], capture_output=True, text=True, timeout=600
    )
    err = done.stderr
    return {
        "label": case.label,
        "code": done.returncode,
        "one_line": err.count("\n") == 1,
        "traceback": "Traceback" in err or "terminate called" in err,
        "named": all(any(alt in err for alt in n.split("|")) for n in case.needles),
    }


def sweep(n: int, seed: int, n_sub: int, work: Path) -> dict:
    results = work / "results"
    with open(os.devnull, "w") as quiet:
        old = sys.stdout
        sys.stdout = quiet
        try:
            assert cli(["import", str(DATA), "--map", str(MAP), "--out", str(results)]) == 0
        finally:
            sys.stdout = old
    ctx = context(work, DATA, MAP, results, SHIPPED_737)
    cases = make_cases(ctx, work, n, seed)
    before = _watched(results)
    rows, changed = [], collections.Counter()
    t0 = time.perf_counter()
    for i, case in enumerate(cases):
        t = time.perf_counter()
        r = attempt(case)
        r["s"] = time.perf_counter() - t
        now = _watched(results)
        for what in before:
            if now[what] != before[what]:
                changed[what] += 1
                before[what] = now[what]  # count each change once
        r["clean"] = clean(r)
        rows.append(r)
        if (i + 1) % 100 == 0:
            print(
                f"{i + 1} of {n}: {sum(x['clean'] for x in rows)} clean, {time.perf_counter() - t0:.0f} s",
                file=sys.stderr,
            )
    wall = time.perf_counter() - t0
    step = max(1, n // max(n_sub, 1))
    subs = [in_subprocess(c) for c in cases[::step][:n_sub]] if n_sub else []
    by_kind = {
        k: {
            "tried": sum(r["kind"] == k for r in rows),
            "clean": sum(r["clean"] for r in rows if r["kind"] == k),
            "labels": len({r["label"] for r in rows if r["kind"] == k}),
        }
        for k in KINDS
    }
    commit = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    return {
        "benchmark": "bad_input_sweep",
        "command": f"python benchmarks/bad_input_sweep.py --n {n} --seed {seed} --subprocess {n_sub}",
        "code_commit": commit,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "inputs_tried": n,
        "distinct_inputs": len({c.sha256 for c in cases}),
        "clean": sum(r["clean"] for r in rows),
        "exit_code_not_2": sum(r["code"] != 2 for r in rows),
        "not_one_line": sum(not r["one_line"] for r in rows),
        "file_or_field_not_named": sum(not r["named"] for r in rows),
        "tracebacks": sum(r["traceback"] for r in rows),
        "wrote_out": sum(r["wrote_out"] for r in rows),
        "disk_changed": dict(changed) or {what: 0 for what in before},
        "by_kind": by_kind,
        "seconds": round(wall, 1),
        "median_case_s": round(sorted(r["s"] for r in rows)[len(rows) // 2], 3),
        "subprocess": {
            "tried": len(subs),
            "clean": sum(s["code"] == 2 and s["one_line"] and s["named"] and not s["traceback"] for s in subs),
            "exit_codes": dict(collections.Counter(str(s["code"]) for s in subs)),
        },
        "failures": [{k: r[k] for k in ("label", "code", "stderr", "escaped")} for r in rows if not r["clean"]][:20],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1200, help="bad inputs to try (default 1200)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--subprocess", type=int, default=24, help="of them, run again as real processes (default 24)")
    ap.add_argument("--out", type=Path, default=RESULT, help="the JSON written (default benchmarks/results/)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bad-input-sweep-") as tmp:
        cwd = os.getcwd()
        os.chdir(tmp)  # what a case writes by mistake lands here, not in the checkout
        try:
            doc = sweep(args.n, args.seed, args.subprocess, Path(tmp) / "work")
        finally:
            os.chdir(cwd)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps({k: v for k, v in doc.items() if k != "failures"}, indent=1))
    return 0 if doc["clean"] == doc["inputs_tried"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
