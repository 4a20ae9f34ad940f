"""Hit rate, false-positive rate and shape errors of the diagnosis over random hidden effects.

    python benchmarks/diagnosis_hit_rate.py [N_SEEDS] [N_NULL]

Each case draws a random overlay from one family (tests/hidden.py), flies the
diagnosis matrix with flight-test noise, diagnoses against the bare model and
scores: first cause right (coefficient and variable), shape error (fitted vs true
discrepancy, share of the true peak) and the held-out gain. Null cases fly no
overlay. Outside CI: about 6 s per case on 2 cores.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.hidden import FAMILIES, make, score  # noqa: E402


def main(n_seeds: int = 8, n_null: int = 12) -> None:
    t0 = time.perf_counter()
    rows = []
    for s in range(n_seeds):
        rng = np.random.default_rng(50_000 + s)
        for fam in FAMILIES:
            h = make(fam, rng)
            r = score(tempfile.mkdtemp(prefix="hit-"), h, seed=60_000 + s)
            hit = bool(r["discrepancy"] and r.get("coefficient_ok") and r.get("variable_ok"))
            rows.append((fam, h.description, hit, r.get("shape_error", np.nan), r.get("gain", np.nan)))
            first = r["doc"]["causes"][0] if r["doc"]["causes"] else {}
            print(f"{fam:20s} {h.description:58s} hit={hit!s:5} shape={rows[-1][3]:.3f} gain={rows[-1][4]:.1f} "
                  f"-> {first.get('coefficient')} {first.get('variables')}", flush=True)
    fps = 0
    for s in range(n_null):
        r = score(tempfile.mkdtemp(prefix="null-"), None, seed=70_000 + s)
        fps += bool(r["discrepancy"])
        print(f"null seed {70_000 + s}: discrepancy={r['discrepancy']}", flush=True)
    hits = np.array([r[2] for r in rows])
    shape = np.array([r[3] for r in rows])
    gain = np.array([r[4] for r in rows])
    print(f"\n{len(rows)} hidden-effect cases, {n_null} null cases, {time.perf_counter() - t0:.0f} s")
    print(f"hit rate (first cause: right coefficient and variable): {hits.mean() * 100:.1f} % ({hits.sum()}/{len(hits)})")
    print(f"false-positive rate (null cases reporting a discrepancy): {fps}/{n_null}")
    ok = hits & np.isfinite(shape)
    print(f"shape error over hits, % of peak: median {np.median(shape[ok]) * 100:.1f}, "
          f"90th pct {np.percentile(shape[ok], 90) * 100:.1f}, max {shape[ok].max() * 100:.1f}; "
          f"within 10 %: {(shape[ok] < 0.10).mean() * 100:.0f} %")
    print(f"held-out gain over hits: min {np.nanmin(gain[ok]):.1f}, median {np.nanmedian(gain[ok]):.1f}; "
          f">= 3x: {(gain[ok] >= 3).mean() * 100:.0f} %")
    for fam in FAMILIES:
        sel = np.array([r[0] == fam for r in rows])
        print(f"  {fam:20s} hits {hits[sel].sum()}/{sel.sum()}  shape max {np.nanmax(shape[sel]) * 100:.1f} %  "
              f"gain min {np.nanmin(gain[sel]):.1f}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
