"""Compare the last two speed results and name what got slower.

    python benchmarks/compare.py [OLD.json NEW.json] [--threshold 20]

Without files, the two newest of ``benchmarks/results/speed/`` (by the date they were measured). Each
figure both files hold is compared on its wall time, its CPU-seconds (the command's and every process
it started: less moved by other work on a shared machine than the wall time) and its peak memory (the
main process and its workers, summed), and each stage of the diagnosis on its wall and CPU time. A
figure more than ``--threshold`` percent slower (or larger) on either is named, with how busy the
machine was with other work in each run: a regression in wall time alone, with the CPU-seconds
unchanged and the machine busier, is the machine's. Exits 1 if anything got slower, 0 otherwise.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "speed"
#: What is compared of a figure: field -> (what it is, its unit).
METRICS = {
    "wall_s": ("wall time", "s"),
    "cpu_s": ("CPU", "s"),
    "sum_mb": ("peak memory, main + workers", "MB"),
    "ratio": ("ratio", ""),
}
#: Below these a change is noise whatever its share: half a second, 20 MB.
FLOOR = {"wall_s": 0.5, "cpu_s": 0.5, "sum_mb": 20.0, "ratio": 0.0}


def newest(n: int = 2, folder: Path = RESULTS) -> list[Path]:
    """The ``n`` result files measured last (their ``date``), oldest first."""
    files = sorted(folder.glob("*.json"), key=lambda p: (json.loads(p.read_text()).get("date", ""), p.name))
    return files[-n:]


def changes(old: dict, new: dict, threshold: float) -> list[dict]:
    """Every figure and stage both results hold, compared metric by metric: name, metric, old, new, the
    change [%] and whether it is a regression (``threshold`` % or more, beyond :data:`FLOOR`)."""
    out = []
    rows = [(k, old["figures"][k], new["figures"][k]) for k in old.get("figures", {}) if k in new.get("figures", {})]
    rows += [
        (f"diagnosis stage: {k}", old["stages"]["stages"][k], new["stages"]["stages"][k])
        for k in (old.get("stages") or {}).get("stages", {})
        if k in (new.get("stages") or {}).get("stages", {})
    ]
    for name, a, b in rows:
        for m, (what, unit) in METRICS.items():
            if m not in a or m not in b or not a[m]:
                continue
            pct = 100.0 * (b[m] / a[m] - 1.0)
            worse = -pct if m == "ratio" else pct  # the flying loop's ratio to raw stepping: lower is slower
            out.append(
                {
                    "figure": name,
                    "metric": what,
                    "unit": unit,
                    "old": a[m],
                    "new": b[m],
                    "change_pct": pct,
                    "slower": worse > threshold and abs(b[m] - a[m]) > FLOOR[m],
                    "busy": (a.get("others_busy"), b.get("others_busy")),
                }
            )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path, help="OLD.json NEW.json (default: the two newest results)")
    ap.add_argument("--threshold", type=float, default=20.0, help="percent slower that counts [%%]")
    a = ap.parse_args(argv)
    files = a.files or newest()
    if len(files) != 2:
        print(f"compare: needs two result files, found {len(files)} in {RESULTS}", file=sys.stderr)
        return 2
    old, new = (json.loads(Path(f).read_text()) for f in files)
    for f, d in zip(files, (old, new)):
        print(
            f"{'old' if d is old else 'new'}: {f.name}, commit {d.get('code_commit', '?')[:12]}, measured "
            f"{d.get('date', '?')} on {d.get('machine', {}).get('cpu', '?')}"
        )
    rows = changes(old, new, a.threshold)
    slower = [r for r in rows if r["slower"]]
    for r in rows:
        mark = "SLOWER" if r["slower"] else ""
        busy = "" if r["busy"][0] is None else f"  (others busy {r['busy'][0]:.0%} -> {r['busy'][1]:.0%})"
        print(
            f"{mark:6} {r['figure']}, {r['metric']}: {r['old']:g} -> {r['new']:g} {r['unit']} "
            f"({r['change_pct']:+.0f} %){busy}"
        )
    if slower:
        print(
            f"\n{len(slower)} slower by more than {a.threshold:g} %: "
            + "; ".join(f"{r['figure']} ({r['metric']} {r['change_pct']:+.0f} %)" for r in slower)
        )
        return 1
    print(f"\nnothing slower by more than {a.threshold:g} % ({len(rows)} figures compared)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
