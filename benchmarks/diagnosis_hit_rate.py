"""Hit rate, false positives, invented secondary causes and shape errors of the diagnosis.

    python benchmarks/diagnosis_hit_rate.py [N_SEEDS] [N_NULL] [N_STOCK_NULL]

1. Hidden effects: each case draws a random overlay from one family
   (tests/hidden.py), flies the diagnosis matrix on our 737 with flight-test
   noise, diagnoses against the bare model and scores the first cause (right
   coefficient and variable), the shape error (fitted vs true discrepancy,
   share of the true peak), the held-out gain, and any secondary cause named
   beside it (on another coefficient, or on the same one with none of the
   hidden variables).
2. Nulls on our 737: no overlay, flight-test noise, fresh seeds.
3. Nulls on stock aircraft: the stock 737 and the A320 of the jsbsim package
   against their own logs, flight-test noise at many seeds.
4. The stock 737's own terms removed or scaled in the model copy.

Run by hand, outside CI: about 15 minutes on 2 cores with the defaults.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.hidden import CLEAN, FAMILIES, OWN_TERMS, make, score  # noqa: E402
from tests.support import matrix_toml, pairs, renoise, run_matrix, scaled_copy  # noqa: E402


def _secondary(causes: list[dict], coefficient: str, variables) -> list[str]:
    """Causes named beside the first that the hidden effect does not explain."""
    return [f"{c['coefficient']} vs {', '.join(c['variables'])}" for c in causes[1:]
            if c["coefficient"] != coefficient or not set(variables) & set(c["variables"])]


def hidden_effects(n_seeds: int) -> list[dict]:
    rows = []
    for s in range(n_seeds):
        rng = np.random.default_rng(50_000 + s)
        for fam in FAMILIES:
            h = make(fam, rng)
            r = score(tempfile.mkdtemp(prefix="hit-"), h, seed=60_000 + s)
            causes = r["doc"]["causes"]
            hit = bool(r["discrepancy"] and r.get("coefficient_ok") and r.get("variable_ok"))
            first = causes[0] if causes else {}
            row = {"family": fam, "description": h.description, "hit": hit,
                   "shape": r.get("shape_error", np.nan), "gain": r.get("gain", np.nan),
                   "secondary": _secondary(causes, h.coefficient, h.variables),
                   "size_over_floor": first.get("verdict", {}).get("size_over_floor", np.nan)}
            rows.append(row)
            print(f"{fam:20s} {h.description:58s} hit={hit!s:5} shape={row['shape']:.3f} gain={row['gain']:.1f} "
                  f"size/floor={row['size_over_floor']:.0f} -> {first.get('coefficient')} {first.get('variables')}"
                  f"{'  secondary: ' + '; '.join(row['secondary']) if row['secondary'] else ''}", flush=True)
    return rows


def nulls_ours(n: int) -> list[bool]:
    out = []
    for s in range(n):
        r = score(tempfile.mkdtemp(prefix="null-"), None, seed=70_000 + s)
        big = r["doc"].get("largest_rejected") or {}
        print(f"null, our 737, seed {70_000 + s}: discrepancy={r['discrepancy']}  closest: "
              f"{big.get('candidate')}: {big.get('reason')}", flush=True)
        out.append(bool(r["discrepancy"]))
    return out


def nulls_stock(n: int) -> list[bool]:
    import jsbsim

    from campaign.diagnose import run_diagnosis
    stock = Path(jsbsim.get_default_root_dir()) / "aircraft"
    matrices = {"737": CLEAN, "A320": matrix_toml(pairs((0, 0.3, 5000), (0, 0.5, 10000), (15, 0.3, 5000)), "a320")}
    out = []
    for name, text in matrices.items():
        clean = run_matrix(tempfile.mkdtemp(prefix=f"stock-{name}-"), text, str(stock / name))
        for s in range(n // len(matrices) + (n % len(matrices) if name == "737" else 0)):
            work = Path(tempfile.mkdtemp(prefix="stock-null-"))
            doc = run_diagnosis(renoise(clean, work / "data", 80_000 + s), stock / name, work / "report",
                                plots=False)
            big = doc.get("largest_rejected") or {}
            print(f"null, stock {name}, seed {80_000 + s}: discrepancy={doc['discrepancy']}  closest: "
                  f"{big.get('candidate')}: {big.get('reason')}", flush=True)
            out.append(bool(doc["discrepancy"]))
    return out


def stock_terms() -> list[dict]:
    import jsbsim

    from campaign.diagnose import run_diagnosis
    stock = Path(jsbsim.get_default_root_dir()) / "aircraft" / "737"
    data = renoise(run_matrix(tempfile.mkdtemp(prefix="stock-terms-"), CLEAN, str(stock)),
                   Path(tempfile.mkdtemp(prefix="stock-terms-noisy-")) / "data", 31)
    rows = []
    for function, scale, coefficient, variable in OWN_TERMS:
        work = Path(tempfile.mkdtemp(prefix="stock-term-"))
        doc = run_diagnosis(data, scaled_copy(stock, work / "model", function, scale), work / "report", plots=False)
        causes = doc["causes"]
        first = causes[0] if causes else {}
        hit = bool(first) and first["coefficient"] == coefficient and first["variables"][0] == variable
        sec = _secondary(causes, coefficient, (variable,))
        rows.append({"hit": hit, "secondary": sec})
        print(f"stock 737 {function.split('/')[-1]} x{scale:g}: hit={hit!s:5} -> {first.get('coefficient')} "
              f"{first.get('variables')} size/floor={first.get('verdict', {}).get('size_over_floor', 0):.0f} "
              f"gain={doc['gain'].get('residual_gain', float('nan')):.1f}"
              f"{'  secondary: ' + '; '.join(sec) if sec else ''}", flush=True)
    return rows


def main(n_seeds: int = 8, n_null: int = 15, n_stock_null: int = 15) -> None:
    t0 = time.perf_counter()
    rows = hidden_effects(n_seeds)
    fp_ours = nulls_ours(n_null)
    fp_stock = nulls_stock(n_stock_null)
    own = stock_terms()
    hits = np.array([r["hit"] for r in rows])
    shape = np.array([r["shape"] for r in rows])
    gain = np.array([r["gain"] for r in rows])
    ok = hits & np.isfinite(shape)
    print(f"\n{len(rows)} hidden-effect cases, {len(fp_ours) + len(fp_stock)} null cases, {len(own)} stock-737 "
          f"terms, {time.perf_counter() - t0:.0f} s")
    print(f"hit rate (first cause: right coefficient and variable): {hits.mean() * 100:.1f} % ({hits.sum()}/{len(hits)})")
    print(f"false positives: {sum(fp_ours)}/{len(fp_ours)} nulls on our 737, {sum(fp_stock)}/{len(fp_stock)} on stock "
          f"aircraft (737, A320)")
    print(f"invented secondary causes: {sum(len(r['secondary']) for r in rows)} over {len(rows)} hidden effects, "
          f"{sum(len(r['secondary']) for r in own)} over {len(own)} stock-737 terms")
    print(f"stock 737's own terms changed: {sum(r['hit'] for r in own)}/{len(own)} named first")
    if ok.any():
        print(f"shape error over hits, % of peak: median {np.median(shape[ok]) * 100:.1f}, "
              f"90th pct {np.percentile(shape[ok], 90) * 100:.1f}, max {shape[ok].max() * 100:.1f}; "
              f"within 10 %: {(shape[ok] < 0.10).mean() * 100:.0f} %")
        print(f"held-out gain over hits: min {np.nanmin(gain[ok]):.1f}, median {np.nanmedian(gain[ok]):.1f}; "
              f">= 3x: {(gain[ok] >= 3).mean() * 100:.0f} %")
    for fam in FAMILIES:
        sel = np.array([r["family"] == fam for r in rows])
        print(f"  {fam:20s} hits {hits[sel].sum()}/{sel.sum()}  shape max {np.nanmax(shape[sel]) * 100:.1f} %  "
              f"gain min {np.nanmin(gain[sel]):.1f}  size/floor min "
              f"{np.nanmin([r['size_over_floor'] for r, s in zip(rows, sel) if s]):.0f}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:4]))
