"""Hit rate, false positives, invented causes, shape and sensor-estimate errors, detection floors.

    python benchmarks/diagnosis_hit_rate.py [N_SEEDS] [N_NULL] [N_STOCK_NULL] [N_SENSOR] [N_FLOOR_SEEDS]

Every flight goes through the shipped flight-test instrument profile (Dryden
turbulence at 1.5 ft/s, 50 Hz after anti-alias filtering, no qdot channel,
nose-boom vanes 62 ft ahead of the CG, sensor noise), with seeds no development was done against.

1. Hidden aero effects: each case draws a random overlay from one family
   (tests/hidden.py), flies the diagnosis matrix on our 737, diagnoses against the
   bare model and scores the first aero cause (right coefficient and variable), the
   shape error (fitted vs true discrepancy, share of the true peak), the held-out
   gain, and any cause named beside it that the effect does not explain.
2. Nulls on our 737.
3. Nulls on stock aircraft: the stock 737 and the A320 of the jsbsim package
   against their own logs.
4. The stock 737's own terms removed or scaled in the model copy.
5. Sensor faults (alpha bias, scale and delay, an accelerometer bias, a thrust
   scale error), injected through an instrument profile: named first as a sensor
   fault of the right channel and kind, nothing aerodynamic invented, the
   estimate's error against 2 standard errors or 10 %.
6. A sensor fault and an aero effect together: both named.
7. Detection floors: each family's size swept down; the floor is the smallest size
   found at every seed tried, and at every larger size.

Run by hand, outside CI: well over an hour on 2 cores with the defaults. N_SEEDS=0
skips stage 1, N_FLOOR_SEEDS=0 stage 7.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.validation.hidden import (  # noqa: E402
    CLEAN,
    FAMILIES,
    OWN_TERMS,
    SENSOR_FAMILIES,
    make,
    make_sensor,
    score,
    score_sensor,
)
from campaign.validation.support import matrix_toml, pairs, run_matrix, scaled_copy  # noqa: E402

#: Sizes swept for the detection floors: aero families as a multiple of their drawn size,
#: sensor faults in their own units (accelerometer: x then z).
AERO_SCALES = (0.05, 0.1, 0.2, 0.35, 0.5, 1.0)
SENSOR_SIZES = {
    "alpha_bias": (0.03, 0.06, 0.1, 0.15, 0.25, 0.4),
    "alpha_scale": (0.005, 0.01, 0.02, 0.03, 0.05),
    "alpha_delay": (0.005, 0.01, 0.02, 0.04, 0.06),
    "accel_bias:ax_fps2": (0.005, 0.01, 0.02, 0.04, 0.06),
    "accel_bias:az_fps2": (0.01, 0.02, 0.04, 0.08, 0.15),
    "thrust_scale": (0.005, 0.01, 0.02, 0.03, 0.05),
}


def _secondary(causes: list[dict], coefficient: str, variables) -> list[str]:
    """Causes named beside the first aero one that the hidden effect does not explain."""
    aero = [c for c in causes if c["kind"] == "aero"]
    out = [
        f"{c['coefficient']} vs {', '.join(c['variables'])}"
        for c in aero[1:]
        if c["coefficient"] != coefficient or not set(variables) & set(c["variables"])
    ]
    return out + [f"sensor {c['channel']} {c['error']}" for c in causes if c["kind"] == "sensor"]


def _tmp(prefix: str) -> Path:
    return Path(tempfile.mkdtemp(prefix=prefix))


def hidden_effects(n_seeds: int) -> list[dict]:
    rows = []
    for s in range(n_seeds):
        rng = np.random.default_rng(50_000 + s)
        for fam in FAMILIES:
            h = make(fam, rng)
            r = score(_tmp("hit-"), h, seed=60_000 + s)
            aero = [c for c in r["doc"]["causes"] if c["kind"] == "aero"]
            hit = bool(r["discrepancy"] and r.get("coefficient_ok") and r.get("variable_ok"))
            first = aero[0] if aero else {}
            row = {
                "family": fam,
                "description": h.description,
                "hit": hit,
                "shape": r.get("shape_error", np.nan),
                "gain": r.get("gain", np.nan),
                "secondary": _secondary(r["doc"]["causes"], h.coefficient, h.variables),
                "size_over_floor": first.get("verdict", {}).get("size_over_floor", np.nan),
            }
            rows.append(row)
            print(
                f"{fam:20s} {h.description:58s} hit={hit!s:5} shape={row['shape']:.3f} gain={row['gain']:.1f} "
                f"size/floor={row['size_over_floor']:.0f} -> {first.get('coefficient')} {first.get('variables')}"
                f"{'  secondary: ' + '; '.join(row['secondary']) if row['secondary'] else ''}",
                flush=True,
            )
    return rows


def nulls_ours(n: int) -> list[bool]:
    out = []
    for s in range(n):
        r = score(_tmp("null-"), None, seed=70_000 + s)
        big = r["doc"].get("largest_rejected") or {}
        named = [c.get("channel") or c["coefficient"] for c in r["doc"]["causes"]]
        print(
            f"null, our 737, seed {70_000 + s}: discrepancy={r['discrepancy']} {named}  closest: "
            f"{big.get('candidate')}: {big.get('reason')}",
            flush=True,
        )
        out.append(bool(r["discrepancy"]))
    return out


def nulls_stock(n: int) -> list[bool]:
    import jsbsim

    from campaign.diagnosis.run import run_diagnosis

    stock = Path(jsbsim.get_default_root_dir()) / "aircraft"
    matrices = {"737": CLEAN, "A320": matrix_toml(pairs((0, 0.3, 5000), (0, 0.5, 10000), (15, 0.3, 5000)), "a320")}
    out = []
    for name, text in matrices.items():
        for s in range(n // len(matrices) + (n % len(matrices) if name == "737" else 0)):
            work = _tmp("stock-null-")
            data = run_matrix(work, text, str(stock / name), noise="flight-test", seed=80_000 + s)
            doc = run_diagnosis(data, stock / name, work / "report", plots=False)
            big = doc.get("largest_rejected") or {}
            named = [c.get("channel") or c["coefficient"] for c in doc["causes"]]
            print(
                f"null, stock {name}, seed {80_000 + s}: discrepancy={doc['discrepancy']} {named}  closest: "
                f"{big.get('candidate')}: {big.get('reason')}",
                flush=True,
            )
            out.append(bool(doc["discrepancy"]))
    return out


def stock_terms() -> list[dict]:
    import jsbsim

    from campaign.diagnosis.run import run_diagnosis

    stock = Path(jsbsim.get_default_root_dir()) / "aircraft" / "737"
    data = run_matrix(_tmp("stock-terms-"), CLEAN, str(stock), noise="flight-test", seed=31)
    rows = []
    for function, scale, coefficient, variable in OWN_TERMS:
        work = _tmp("stock-term-")
        doc = run_diagnosis(data, scaled_copy(stock, work / "model", function, scale), work / "report", plots=False)
        aero = [c for c in doc["causes"] if c["kind"] == "aero"]
        first = aero[0] if aero else {}
        hit = bool(first) and first["coefficient"] == coefficient and first["variables"][0] == variable
        sec = _secondary(doc["causes"], coefficient, (variable,))
        alts = [
            f"{a['channel']} {a['error']} {a['needs']:+.3g} ({a['needs_se']:.1f} SE)"
            for a in first.get("evidence", {}).get("sensor_alternatives", [])
        ]
        rows.append({"hit": hit, "secondary": sec})
        print(
            f"stock 737 {function.split('/')[-1]} x{scale:g}: hit={hit!s:5} -> {first.get('coefficient')} "
            f"{first.get('variables')} size/floor={first.get('verdict', {}).get('size_over_floor', 0):.0f} "
            f"gain={doc['gain'].get('residual_gain', float('nan')):.1f}"
            f"{'  secondary: ' + '; '.join(sec) if sec else ''}{'  or a sensor: ' + '; '.join(alts) if alts else ''}",
            flush=True,
        )
    return rows


def sensor_faults(n: int) -> list[dict]:
    rows = []
    for s in range(n):
        rng = np.random.default_rng(90_000 + s)
        for fam in SENSOR_FAMILIES:
            f = make_sensor(fam, rng)
            r = score_sensor(_tmp("sensor-"), f, seed=91_000 + s)
            row = {
                "family": fam,
                "hit": bool(r["sensor_first"] and not r["aero_named"]),
                "within": r.get("within"),
                "rel_error": abs(r["estimate_error"] / f.value) if "estimate_error" in r else np.nan,
                "z_error": abs(r["estimate_error"] / r["se"]) if "estimate_error" in r else np.nan,
                "invented": r["aero_named"] + r["other_sensors"],
            }
            rows.append(row)
            print(
                f"{fam:14s} {f.description:32s} hit={row['hit']!s:5} estimate={r.get('estimate', np.nan):+.4g} "
                f"+- {r.get('se', np.nan):.2g} (error {row['rel_error'] * 100:.1f} %, {row['z_error']:.1f} SE)"
                f"{'  invented: ' + '; '.join(row['invented']) if row['invented'] else ''}",
                flush=True,
            )
    return rows


def sensor_and_aero(n: int) -> list[dict]:
    rows = []
    for s in range(n):
        rng = np.random.default_rng(95_000 + s)
        f = make_sensor(SENSOR_FAMILIES[s % len(SENSOR_FAMILIES)], rng)
        h = make(FAMILIES[s % len(FAMILIES)], rng)
        r = score_sensor(_tmp("both-"), f, seed=96_000 + s, hidden=h)
        row = {
            "sensor": bool(r["sensor_ok"]),
            "aero": bool(r.get("coefficient_ok") and r.get("variable_ok")),
            "shape": r.get("shape_error", np.nan),
        }
        rows.append(row)
        print(
            f"both: {f.description} + {h.description}: sensor={row['sensor']} aero={row['aero']} "
            f"shape={row['shape']:.3f} named={[c.get('channel') or c['coefficient'] for c in r['doc']['causes']]}",
            flush=True,
        )
    return rows


def _floor(sizes, found: dict) -> float:
    """Smallest size found at every seed, with every larger size found too (nan: none).

    The sweep runs from the largest size down and stops at the first miss, so sizes
    below it are absent from ``found``.
    """
    floor = np.nan
    for v in sorted(sizes, reverse=True):
        if v not in found or not all(found[v]):
            break
        floor = v
    return floor


def detection_floors(n_seeds: int = 2) -> dict:
    out = {}
    if n_seeds == 0:
        return out
    for fam in FAMILIES:
        found = {}
        for k in sorted(AERO_SCALES, reverse=True):
            found[k] = []
            for s in range(n_seeds):
                h = make(fam, np.random.default_rng(97_000 + s), scale=k)
                r = score(_tmp("floor-"), h, seed=97_500 + s)
                found[k].append(bool(r["discrepancy"] and r.get("coefficient_ok") and r.get("variable_ok")))
                if not found[k][-1]:
                    break
            if not all(found[k]):
                break
        out[fam] = (_floor(AERO_SCALES, found), found, "x drawn size")
        print(f"floor {fam:20s} {out[fam][0]} x drawn size  {found}", flush=True)
    for key, sizes in SENSOR_SIZES.items():
        fam, _, ch = key.partition(":")
        found = {}
        for v in sorted(sizes, reverse=True):
            found[v] = []
            for s in range(n_seeds):
                f = make_sensor(fam, np.random.default_rng(98_000 + s), v, ch or None)
                r = score_sensor(_tmp("floor-"), f, seed=98_500 + s)
                found[v].append(bool(r["sensor_ok"] and not r["aero_named"]))
                if not found[v][-1]:
                    break
            if not all(found[v]):
                break
        out[key] = (_floor(sizes, found), found, "")
        print(f"floor {key:20s} {out[key][0]}  {found}", flush=True)
    return out


def main(n_seeds: int = 8, n_null: int = 20, n_stock_null: int = 10, n_sensor: int = 6, n_floor_seeds: int = 2) -> None:
    t0 = time.perf_counter()
    rows = hidden_effects(n_seeds)
    fp_ours = nulls_ours(n_null)
    fp_stock = nulls_stock(n_stock_null)
    own = stock_terms()
    sens = sensor_faults(n_sensor)
    both = sensor_and_aero(n_sensor)
    floors = detection_floors(n_floor_seeds)
    hits = np.array([r["hit"] for r in rows], dtype=bool)
    shape = np.array([r["shape"] for r in rows], dtype=float)
    gain = np.array([r["gain"] for r in rows], dtype=float)
    ok = hits & np.isfinite(shape)
    print(
        f"\n{len(rows)} hidden-effect cases, {len(fp_ours) + len(fp_stock)} null cases, {len(own)} stock-737 "
        f"terms, {len(sens)} sensor faults, {len(both)} sensor + aero, {time.perf_counter() - t0:.0f} s"
    )
    print(
        f"hit rate (first aero cause: right coefficient and variable): {hits.mean() * 100:.1f} % "
        f"({hits.sum()}/{len(hits)})"
    )
    print(
        f"false positives: {sum(fp_ours)}/{len(fp_ours)} nulls on our 737, {sum(fp_stock)}/{len(fp_stock)} on stock "
        f"aircraft (737, A320)"
    )
    print(
        f"invented causes: {sum(len(r['secondary']) for r in rows)} over {len(rows)} hidden effects, "
        f"{sum(len(r['secondary']) for r in own)} over {len(own)} stock-737 terms, "
        f"{sum(len(r['invented']) for r in sens)} over {len(sens)} sensor faults"
    )
    print(f"stock 737's own terms changed: {sum(r['hit'] for r in own)}/{len(own)} named first")
    if ok.any():
        print(
            f"shape error over hits, % of peak: median {np.median(shape[ok]) * 100:.1f}, "
            f"90th pct {np.percentile(shape[ok], 90) * 100:.1f}, max {shape[ok].max() * 100:.1f}; "
            f"within 10 %: {(shape[ok] < 0.10).mean() * 100:.0f} %"
        )
        print(
            f"held-out gain over hits: min {np.nanmin(gain[ok]):.1f}, median {np.nanmedian(gain[ok]):.1f}; "
            f">= 2x: {(gain[ok] >= 2).mean() * 100:.0f} %, >= 3x: {(gain[ok] >= 3).mean() * 100:.0f} %"
        )
    for fam in FAMILIES if rows else ():
        sel = np.array([r["family"] == fam for r in rows])
        print(
            f"  {fam:20s} hits {hits[sel].sum()}/{sel.sum()}  shape max {np.nanmax(shape[sel]) * 100:.1f} %  "
            f"gain min {np.nanmin(gain[sel]):.1f}  size/floor min "
            f"{np.nanmin([r['size_over_floor'] for r, s in zip(rows, sel) if s]):.0f}"
        )
    for fam in SENSOR_FAMILIES:
        sel = [r for r in sens if r["family"] == fam]
        rel = np.array([r["rel_error"] for r in sel])
        print(
            f"  {fam:14s} named first {sum(r['hit'] for r in sel)}/{len(sel)}; estimate within 2 SE or 10 %: "
            f"{sum(bool(r['within']) for r in sel)}/{len(sel)}; error median {np.nanmedian(rel) * 100:.1f} %, "
            f"max {np.nanmax(rel) * 100:.1f} %"
        )
    print(
        f"sensor + aero: sensor named {sum(r['sensor'] for r in both)}/{len(both)}, aero named "
        f"{sum(r['aero'] for r in both)}/{len(both)}"
    )
    print("detection floors (smallest size found at every seed, and above):")
    for k, (v, found, unit) in floors.items():
        print(f"  {k:22s} {v} {unit}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:6]))
