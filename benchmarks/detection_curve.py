"""The detection curve: hit rate against size / noise floor, false positives, invented causes.

    python benchmarks/detection_curve.py [--effects N] [--nulls N] [--seed-base S] [--out DIR]
                                         [--aircraft "stock 737"] [--sigma-fps 3] [--sensor alpha_scale]
    python benchmarks/detection_curve.py --merge DIR [DIR ...] --out DIR

Random effects from the shape grammar (tests/shapes.py: every candidate variable and pairs of
them, on the range each aircraft flies it over (:func:`flown_ranges`), late onset,
early saturation, bump, dip, step, ramp above a threshold, dead band, random monotone and
non-monotone tables, gear x flap, gear x alpha, gear x Mach, alpha x Mach, a random
sign, a size log-uniform from 0.3x to 30x the coefficient's noise floor) are hidden in the data of
our 737 and of the stock 737 and A320 of the jsbsim package, flown over each one's matrix (:data:`OUR_737`,
:data:`STOCK_737`, :data:`A320`: five or six conditions, two Mach numbers at one alpha, a Mach number at
two flap angles) through the flight-test profile (1.5 ft/s turbulence) or the same with 3 ft/s, a
random sensor error in a fifth of the cases; each is diagnosed against the bare model. Nulls: the same
without an effect.

A hit: the first aerodynamic discrepancy named, a cause or one the data cannot confirm (in the
summary's order, :func:`diagnose.verdict.rank`: those ten times their floor by the share of the
residual they take, then the others by their size beyond instrument errors over the floor), is the effect's
coefficient, holds the effect's variables, and leads with one of them. Invented: another such
discrepancy named beside it, on another coefficient or none of its variables. A hit as flown: a hit,
or the first cause is the effect's coefficient, leads with one of its variables and holds no other
of them, and the effect leaves less than the floor beyond a function of that variable alone over the
data flown (:func:`left_beyond`; alpha x Mach where one Mach number alone reaches the alpha it acts
at: the data cannot show the Mach part). Reported beside the hits, which do not count it. Shape
error: the extension's largest error in the effect's coefficient over every sample flown (the
extended model less the model, against the effect: the model with it less the model, JSBSim
evaluating each at the measured states), over the effect's largest; 0 is the effect, 1 what the bare
model leaves; the table gives its median and 90th percentile over the hits. The size is the effect's
range over the data flown (the model and the model with the effect evaluated at the measured
states), against the coefficient's floor (tests/shapes.py). A false positive: a null with an aero
cause named, or a sensor cause when no sensor error was hidden. The seeds start at ``--seed-base``
(2,000,000 by default; a validation takes a range no one has developed against, and its table goes
into ``benchmarks/results/detection_curve_*.csv``; the tests use 900-905).

Writes ``detection_curve.csv``, ``detection_curve.md`` (the table), ``detection_curve.png`` and
``cases/<seed>.json`` (every candidate cause and its verdict) into ``--out``; ``--merge`` writes
the first three for the cases of several such folders (ranges flown by processes side by side).
Run by hand, outside CI: about 16 s a case on 2 cores (two processes side by side: 360 cases in
48 minutes).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
from itertools import pairwise
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.validation.hidden import (
    SENSOR_FAMILIES,
    differences,
    discrepancies,
    make_sensor,
    shape_error,
)
from campaign.validation.shapes import FLOOR, PAIRS, VARIABLES, Effect, draw
from campaign.validation.support import matrix_toml, pairs, run_matrix

BINS = (0.3, 1.0, 3.0, 10.0, 30.0)


def same_alpha_alt_ft(alt_ft: float, mach: float, to_mach: float) -> float:
    """The altitude [ft] at which ``to_mach`` flies at the dynamic pressure ``mach`` has at ``alt_ft``
    (:func:`campaign.design.plan.same_lift_alt_ft`, the plan's candidate), rounded to 500 ft."""
    from campaign.design.plan import same_lift_alt_ft

    return float(round(same_lift_alt_ft(alt_ft, mach, to_mach) / 500.0) * 500.0)


#: Each aircraft's matrix: two altitudes and three Mach numbers, a flap setting (not the stock 737's: it has
#: no flap angle), and Mach 0.4 at the alpha of the lowest Mach 0.3 condition (a third altitude). Without
#: that point two Mach numbers met at one alpha only at the edges of the 2-3-1-1s (Mach 0.3 and 0.5, by about
#: a degree) or at another flap angle (our 737's Mach 0.2 at flap 30), and an effect in alpha x Mach read as
#: a finer shape in alpha alone. The A320 does not trim at Mach 0.3 and 10,000 ft; with three conditions any
#: one held out would take a Mach number, an altitude or the flap setting from the fit. The A320 also flies
#: Mach 0.5 at the alpha of Mach 0.4 at 10,000 ft (21,000 ft): its Mach 0.5 trims at 1.9 deg and its Mach 0.4
#: at 4.7, and an effect changing in that gap would fit a level per Mach number as well. Our 737 also flies
#: flap 30 at Mach 0.3 and 10,000 ft (165 kt calibrated, under the 737-800's 175 kt flap-30 placard): with
#: Mach 0.2 flown at flap 30 only and flap 0 at Mach 0.3 to 0.5, the flap angle would be a function of Mach
#: over the data (:mod:`diagnose.flap_mach`), and an effect in Mach below 0.3 the flap's.
OUR_737 = matrix_toml(
    pairs(
        (0, 0.3, [2000, 10000]),
        (0, 0.5, 10000),
        (30, 0.2, 2000),
        (30, 0.3, 10000),
        (0, 0.4, same_alpha_alt_ft(2000, 0.3, 0.4)),
    ),
    "diagnosis",
)
STOCK_737 = matrix_toml(
    pairs((0, 0.3, [2000, 10000]), (0, 0.5, 10000), (0, 0.4, 5000), (0, 0.4, same_alpha_alt_ft(2000, 0.3, 0.4))),
    "clean",
)
A320 = matrix_toml(
    pairs(
        (0, 0.3, 5000),
        (0, 0.4, 10000),
        (0, 0.5, 10000),
        (15, 0.3, 5000),
        (0, 0.4, same_alpha_alt_ft(5000, 0.3, 0.4)),
        (0, 0.5, same_alpha_alt_ft(10000, 0.4, 0.5)),
    ),
    "a320",
)


AIRCRAFT = ("our 737", "stock 737", "A320")


def aircraft(rng: np.random.Generator, only: str | None = None) -> tuple[str, str, str]:
    """(name, folder, matrix TOML) of one of the three aircraft (drawn; ``only`` forces it, the
    draw still made so that the rest of the case is the same)."""
    import jsbsim

    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    stock = Path(jsbsim.get_default_root_dir()) / "aircraft"
    every = [
        ("our 737", str(DEFAULT_AIRCRAFT), OUR_737),
        ("stock 737", str(stock / "737"), STOCK_737),
        ("A320", str(stock / "A320"), A320),
    ]
    drawn = every[int(rng.integers(3))]
    return every[AIRCRAFT.index(only)] if only else drawn


@functools.cache
def flown_ranges(folder: str, matrix: str) -> dict[str, tuple[float, float]]:
    """The range [own units] each of the grammar's variables is flown over on an aircraft's matrix: the
    1st to 99th percentile of its logged channel, the bare aircraft flown through the flight-test profile
    in 1.5 ft/s (seed 0). The shapes are drawn on it (:func:`campaign.validation.shapes.draw`): the stock A320 trims
    its elevator between -25 and -2 deg and flies Mach 0.3 to 0.5, where our 737 flies -3 to 3 deg and
    Mach 0.2 to 0.5. A variable the matrix holds still (the stock 737's flap) has an empty range."""
    from campaign.diagnosis.run import load_data

    with tempfile.TemporaryDirectory(prefix="ranges-") as tmp:
        prof = Path(tmp) / "instruments.toml"
        prof.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 1.5\n')
        data = run_matrix(Path(tmp), matrix, folder, None, noise=str(prof), seed=0)
        frames = [log.data for log in load_data(data)]
    return {
        v: tuple(float(np.percentile(np.concatenate([f[v].to_numpy() for f in frames]), q)) for q in (1, 99))
        for v in VARIABLES
    }


def realized(data: Path, folder: str, fx: Path, effect: Effect, work: Path, extension: str | None) -> dict:
    """The effect over the logs flown (the model with the effect less the model, JSBSim evaluating both
    at the measured states, every log flown, held-out ones included): its range ``size``; the range of
    its middle 98 % ``middle`` (an effect the data reach in a few samples only is large by the first,
    small by the second); the extension's ``shape_error`` there (:func:`campaign.validation.hidden.shape_error`; nan
    without an extension); and ``left``: for each of its variables, the middle 98 % range of what the
    effect leaves beyond a function of that variable alone (:func:`left_beyond`)."""
    from campaign.diagnosis.run import load_data
    from identify.export import merge_into_aircraft

    truth = merge_into_aircraft(Path(folder), fx, work / "truth", replace_gear=False)
    models = [truth] + ([extension] if extension else [])
    frame, (true, *fitted) = differences(load_data(data), Path(folder), models, effect.coefficient)
    return {
        "size": float(np.ptp(true)),
        "middle": _middle(true),
        "shape_error": shape_error(fitted[0], true) if fitted else np.nan,
        "left": {v: left_beyond(true, frame[v].to_numpy()) for v in effect.variables},
    }


def _middle(x: np.ndarray) -> float:
    return float(np.subtract(*np.percentile(x, [99, 1])))


#: Neighbours in one variable's order over which :func:`left_beyond` averages the effect.
NEIGHBOURS = 15


def left_beyond(true: np.ndarray, x: np.ndarray) -> float:
    """The middle 98 % range of what an effect leaves beyond a function of ``x`` alone [-]: the effect
    less its mean over the :data:`NEIGHBOURS` samples nearest in ``x`` (those of one value, in a random
    order). An effect of two variables whose second is the same wherever it acts (alpha x Mach where
    only one Mach number reaches the alpha it acts at) leaves nothing: over the data flown it is an
    effect of the first alone."""
    shuffled = np.random.default_rng(0).permutation(len(x))  # samples of one value (gear down) from every log
    order = shuffled[np.argsort(x[shuffled], kind="stable")]
    near = np.convolve(np.pad(true[order], NEIGHBOURS // 2, mode="edge"), np.ones(NEIGHBOURS) / NEIGHBOURS, "valid")
    return _middle(true[order] - near)


def profile(
    rng: np.random.Generator, work: Path, sensor: bool, sigma_fps: float | None = None, family: str | None = None
) -> tuple[str, str]:
    """An instrument profile (a file) and its description: 1.5 or 3 ft/s (or ``sigma_fps``), a sensor
    error or none (``family``: an error of that family)."""
    sigma = float(rng.choice([1.5, 3.0]))
    sigma = sigma if sigma_fps is None else float(sigma_fps)
    text, what = f'extends = "flight-test"\n[turbulence]\nsigma_fps = {sigma}\n', f"{sigma:g} ft/s"
    if sensor:
        drawn = str(rng.choice(SENSOR_FAMILIES))
        fault = make_sensor(family or drawn, rng)
        text = fault.profile.replace('extends = "flight-test"\n', text)
        what += f", {fault.description}"
    path = work / "instruments.toml"
    path.write_text(text)
    return str(path), what


def case(
    seed: int,
    null: bool = False,
    only: str | None = None,
    sigma_fps: float | None = None,
    keep: Path | None = None,
    sensor_family: str | None = None,
) -> dict:
    """Draw, fly, diagnose and score one case (``only``, ``sigma_fps``, ``sensor_family``: force the
    aircraft, the turbulence or a sensor error of that family; ``keep``: a folder to write the case's
    candidates and their verdicts to, as ``<seed>.json``, for calibrating the verdict on them). The case's
    logs and report are flown in a temporary folder, removed when it is scored."""
    with tempfile.TemporaryDirectory(prefix="curve-") as tmp:
        return _case(Path(tmp), seed, null, only, sigma_fps, keep, sensor_family)


def _case(
    work: Path,
    seed: int,
    null: bool,
    only: str | None,
    sigma_fps: float | None,
    keep: Path | None,
    sensor_family: str | None,
) -> dict:
    from campaign.diagnosis.run import run_diagnosis

    rng = np.random.default_rng(seed)
    name, folder, matrix = aircraft(rng, only)
    effect = None
    if not null:
        ranges = flown_ranges(folder, matrix)
        allowed = [v for v in VARIABLES if ranges[v][1] > ranges[v][0]]
        pick = PAIRS[int(rng.integers(len(PAIRS)))] if rng.uniform() < 0.3 else (str(rng.choice(allowed)),)
        if not set(pick) <= set(allowed):
            pick = (pick[0],)
        effect = draw(rng, variables=pick, ranges=ranges)
    sensor = rng.uniform() < 0.2 or sensor_family is not None
    prof, what = profile(rng, work, sensor, sigma_fps, sensor_family)
    fx = None
    if effect is not None:
        fx = work / "hidden.xml"
        fx.write_text(effect.xml)
    data = run_matrix(work, matrix, folder, str(fx) if fx else None, noise=prof, seed=seed)
    doc = run_diagnosis(data, Path(folder), work / "report", plots=False, jobs=2)
    aero = discrepancies(doc)
    if keep is not None:
        keep.mkdir(parents=True, exist_ok=True)
        slim = {
            k: [{f: v for f, v in c.items() if f != "curve"} for c in doc.get(k, [])]
            for k in ("causes", "unconfirmed", "rejected")
        }
        (keep / f"{seed}.json").write_text(
            json.dumps(
                {
                    "seed": seed,
                    "aircraft": name,
                    "conditions": what,
                    "sensor": sensor,
                    "effect": None
                    if effect is None
                    else {
                        "coefficient": effect.coefficient,
                        "variables": list(effect.variables),
                        "description": effect.description,
                    },
                    "held_out_check": doc.get("held_out_check"),
                    **slim,
                },
                default=str,
            )
        )
    row = {
        "seed": seed,
        "aircraft": name,
        "conditions": what,
        "discrepancy": doc["discrepancy"],
        "named": f"{aero[0]['coefficient']} vs {', '.join(aero[0]['variables'])}" if aero else "",
    }
    # an unconfirmed discrepancy is reported as one ("a discrepancy all the same"): not rejected
    missed_big = [
        c
        for c in doc["rejected"]
        if c["kind"] == "aero"
        and c["evidence"].get("F", 0) >= 1e3
        and c["verdict"].get("holdout_gain", 0) >= 1.5
        and not c["verdict"].get("unconfirmed")
    ]
    row["rejected_strong"] = "; ".join(
        f"{c['coefficient']} vs {', '.join(c['variables'])}: {c['verdict']['reason']}" for c in missed_big
    )
    if effect is None:
        false = bool(aero) or (not sensor and any(c["kind"] == "sensor" for c in doc["causes"]))
        return {**row, "effect": "", "size_over_floor": np.nan, "hit": False, "invented": "", "false_positive": false}
    first = aero[0] if aero else {}
    hit = (
        first.get("coefficient") == effect.coefficient
        and set(effect.variables) <= set(first["variables"])
        and first["variables"][0] in effect.variables
    )
    invented = [
        f"{c['coefficient']} vs {', '.join(c['variables'])}"
        for c in aero[1:]
        if c["coefficient"] != effect.coefficient or not set(effect.variables) & set(c["variables"])
    ]
    got = realized(data, folder, fx, effect, work, doc.get("extension"))
    floor = FLOOR[effect.coefficient]
    # as flown: the variables named, of the effect's, leave less than the floor of it unexplained
    named = [v for v in first.get("variables", []) if v in effect.variables]
    as_flown = hit or (
        first.get("coefficient") == effect.coefficient
        and first["variables"][0] in effect.variables
        and len(named) == 1
        and got["left"][named[0]] < floor
    )
    return {
        **row,
        "effect": effect.description,
        "size_over_floor": got["size"] / floor,
        "middle_98_over_floor": got["middle"] / floor,
        "hit": hit,
        "hit_as_flown": as_flown,
        "left_over_floor": "; ".join(f"{v} {x / floor:.2f}" for v, x in got["left"].items()),
        "shape_error": got["shape_error"],
        "invented": "; ".join(invented),
        "false_positive": False,
        "nominal_over_floor": effect.size_over_floor,
    }


def _said(text) -> bool:
    """A text column holds something (a CSV read back holds NaN where it was empty)."""
    return isinstance(text, str) and bool(text)


def table(rows: list[dict]) -> str:
    effects = [r for r in rows if _said(r["effect"])]
    nulls = [r for r in rows if not _said(r["effect"])]
    lines = [
        (
            "| size / floor | effects | hits | hit rate | hits as flown | shape error of the hits (median, 90th "
            "percentile) | invented causes | strong candidates rejected |"
        ),
        "|---|---|---|---|---|---|---|---|",
    ]
    for lo, hi in pairwise(BINS):
        b = [r for r in effects if lo <= r["size_over_floor"] < hi or (hi == BINS[-1] and r["size_over_floor"] >= hi)]
        hits = sum(r["hit"] for r in b)
        rate = f"{100 * hits / len(b):.0f} %" if b else "-"
        flown = sum(bool(r.get("hit_as_flown", r["hit"])) for r in b)
        flown = f"{flown} ({100 * flown / len(b):.0f} %)" if b else "-"
        shapes = [r["shape_error"] for r in b if r["hit"] and np.isfinite(r.get("shape_error", np.nan))]
        shape = f"{np.median(shapes):.2f}, {np.percentile(shapes, 90):.2f}" if shapes else "-"
        label = f"{lo:g} and more" if hi == BINS[-1] else f"{lo:g}-{hi:g}"
        lines.append(
            f"| {label} | {len(b)} | {hits} | {rate} | {flown} | {shape} | {sum(_said(r['invented']) for r in b)} | "
            f"{sum(_said(r['rejected_strong']) for r in b)} |"
        )
    fp = sum(r["false_positive"] for r in nulls)
    below = [r for r in effects if r["size_over_floor"] < BINS[0]]
    wrong = sum(_said(r["named"]) and not r["hit"] for r in below)
    lines.append(
        f"\nBelow {BINS[0]:g} times the floor over the data flown: {len(below)} effects, "
        f"{sum(r['hit'] for r in below)} named, {wrong} with another aerodynamic cause named (as good as "
        f"nulls: a cause named there is a false discovery). Nulls: {len(nulls)}, false positives: {fp}."
    )
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    effects = [r for r in rows if _said(r["effect"])]
    centres, rates, counts = [], [], []
    for lo, hi in pairwise(BINS):
        b = [r for r in effects if lo <= r["size_over_floor"] < hi or (hi == BINS[-1] and r["size_over_floor"] >= hi)]
        if b:
            centres.append(np.sqrt(lo * hi))
            rates.append(100 * np.mean([r["hit"] for r in b]))
            counts.append(len(b))
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.semilogx(centres, rates, "o-")
    for x, y, n in zip(centres, rates, counts):
        ax.annotate(f"n={n}", (x, y), textcoords="offset points", xytext=(0, -14), ha="center", fontsize=8)
    ax.set_xlabel("effect size / noise floor")
    ax.set_ylabel("first cause right [%]")
    ax.set_ylim(0, 105)
    ax.grid(alpha=0.3)
    ax.set_title(f"Detection curve ({len(effects)} random effects)")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def main() -> int:
    import pandas as pd

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", type=int, default=300)
    ap.add_argument("--nulls", type=int, default=60)
    ap.add_argument("--seed-base", type=int, default=2_000_000)
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "detection-curve")
    ap.add_argument("--aircraft", choices=AIRCRAFT, help="fly every case on this aircraft")
    ap.add_argument("--sigma-fps", type=float, help="every case in this turbulence [ft/s]")
    ap.add_argument("--sensor", choices=SENSOR_FAMILIES, help="a sensor error of this family in every case")
    ap.add_argument(
        "--merge",
        type=Path,
        nargs="+",
        metavar="DIR",
        help="fly nothing: the table and plot of the cases in these --out folders together",
    )
    a = ap.parse_args()
    if a.merge:
        if any(d.resolve() == a.out.resolve() for d in a.merge):
            ap.error(f"--out {a.out}: one of the folders merged; its cases would be overwritten (choose another)")
        for d in a.merge:
            if not (d / "detection_curve.csv").is_file():
                ap.error(f"--merge {d}: no detection_curve.csv there (a folder a run wrote with --out)")
    a.out.mkdir(parents=True, exist_ok=True)
    if a.merge:
        return report(pd.concat([pd.read_csv(d / "detection_curve.csv") for d in a.merge]).to_dict("records"), a.out)
    rows = []
    for i in range(a.effects + a.nulls):
        r = case(
            a.seed_base + i,
            null=i >= a.effects,
            only=a.aircraft,
            sigma_fps=a.sigma_fps,
            keep=a.out / "cases",
            sensor_family=a.sensor,
        )
        rows.append(r)
        print(
            f"{r['seed']} {r['aircraft']:9s} {r['conditions']:40s} {r['effect'][:70]:70s} "
            f"size/floor {r['size_over_floor']:5.1f} -> {r['named'] or '-'} hit={r['hit']} "
            f"shape error {r.get('shape_error', np.nan):.2f} "
            f"{'invented: ' + r['invented'] if r['invented'] else ''}"
            f"{' REJECTED STRONG: ' + r['rejected_strong'] if r['rejected_strong'] else ''}",
            flush=True,
        )
        pd.DataFrame(rows).to_csv(a.out / "detection_curve.csv", index=False)
    return report(rows, a.out)


def report(rows: list[dict], out: Path) -> int:
    """Write the table, the plot and (merged) the cases' CSV into ``out``, and print the table."""
    import pandas as pd

    pd.DataFrame(rows).to_csv(out / "detection_curve.csv", index=False)
    text = table(rows)
    (out / "detection_curve.md").write_text(text + "\n")
    plot(rows, out / "detection_curve.png")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
