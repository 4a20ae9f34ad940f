"""Information per flight second: the orthogonal multisine against the 2-3-1-1 (run by hand).

    python benchmarks/multisine_information.py [--seeds N] [--band F_LO_HZ F_HI_HZ] [--out DIR]

Both manoeuvres last the same (28 s: 2 s trimmed, 18 s of inputs, 8 s of free response) and have
the same peaks (3 deg elevator, 1 deg stabilizer, scaled by the stall margin alike). Each is flown
gear up on our 737 (bare, no effects) at three conditions, through the flight-test profile
(1.5 ft/s turbulence, 50 Hz, noise) over ``--seeds`` seeds, and identified by the equation error.
Per derivative and condition:

- predicted: the Cramér-Rao bound of the least squares, ``s^2 (X'X)^-1`` with the fit's own
  residual variance (``bse_white``), the mean over seeds;
- reported: the coloured-residual standard error the fit reports (``bse``), the mean over seeds;
- realized: the scatter of the estimates over seeds, robust (1.4826 times the median absolute
  deviation: one seed in thirty can throw an estimate 20 standard errors off, and a plain
  standard deviation would be that seed's); ``outliers`` counts estimates more than 5 robust
  deviations from the median.

Writes ``multisine_information.csv``, ``.md`` (the table) and ``.png`` into ``--out``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.validation.support import matrix_toml, pairs  # noqa: E402

CONDITIONS = pairs((0, 0.3, 5000), (5, 0.3, 2000), (30, 0.2, 2000))
MANEUVERS = {
    "2-3-1-1": ("doublet", "[maneuvers.doublet]\ntail_s = 8.0\n"),
    "multisine": ("multisine", "[maneuvers.multisine]\nduration_s = 18.0\nlead_s = 2.0\ntail_s = 8.0\n"),
}
BAND_HZ = (0.1, 0.5)
DERIVATIVES = {
    "Cmq": ("Cm", "qhat_rad"),
    "Cmalpha": ("Cm", "dalpha_rad"),
    "Cmde": ("Cm", "delevator_rad"),
    "CLalpha": ("CL", "dalpha_rad"),
}


def fly(work: Path, kind: str, seed: int, band_hz: tuple[float, float] = BAND_HZ) -> pd.DataFrame:
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, AircraftSource, load_effects
    from campaign.simulation.engine import FlightConfig
    from campaign.simulation.matrix import load_matrix
    from campaign.orchestration.runner import run_campaign
    from identify.logs import read_campaign
    from identify.pipeline import identify_logs

    name, table = MANEUVERS[kind]
    if kind == "multisine":
        table += f"f_lo_hz = {band_hz[0]}\nf_hi_hz = {band_hz[1]}\n"
    folder = work / f"{name}-{seed}"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "m.toml").write_text(
        matrix_toml(
            [c for c in CONDITIONS if c[0] == "up"],
            name,
            f'[defaults]\nmaneuvers_gear_up = ["{name}"]\nmaneuvers_gear_down = ["{name}"]\n{table}',
        )
    )
    m = load_matrix(folder / "m.toml")
    cfg = FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(None)),
        seed,
        "flight-test",
        m.maneuver_params,
        m.clmax_by_flap,
    )
    run_campaign(m, cfg, folder / "out", jobs=2, progress=False)
    logs = read_campaign(folder / "out")
    seconds = {lg.point: float(lg.data.t_s.iloc[-1] - lg.data.t_s.iloc[0]) for lg in logs}
    rows = []
    for f in identify_logs(logs).fits:
        for d, (c, r) in DERIVATIVES.items():
            res = f.fits[c]
            rows.append(
                {
                    "maneuver": kind,
                    "seed": seed,
                    "point": f.point,
                    "derivative": d,
                    "estimate": float(res.params[r]),
                    "bse": float(res.bse[r]),
                    "bse_white": float(res.bse_white[r]),
                    "seconds": seconds[f.point],
                }
            )
    return pd.DataFrame(rows)


def table(df: pd.DataFrame) -> pd.DataFrame:
    g = df.groupby(["derivative", "point", "maneuver"])

    def robust(x: pd.Series) -> float:
        return 1.4826 * float((x - x.median()).abs().median())

    def outliers(x: pd.Series) -> int:
        return int(((x - x.median()).abs() > 5 * robust(x)).sum())

    out = pd.DataFrame(
        {
            "predicted": g.bse_white.mean(),
            "reported": g.bse.mean(),
            "realized": g.estimate.agg(robust),
            "outliers": g.estimate.agg(outliers),
            "seconds": g.seconds.mean(),
        }
    ).reset_index()
    wide = out.pivot_table(
        index=["derivative", "point"],
        columns="maneuver",
        values=["predicted", "reported", "realized", "outliers", "seconds"],
    )
    res = pd.DataFrame(index=wide.index)
    for what in ("predicted", "reported", "realized"):
        # information per flight second, multisine over 2-3-1-1: (se^2 T) of the 2-3-1-1 over the multisine's
        res[f"{what} 2-3-1-1"] = wide[(what, "2-3-1-1")]
        res[f"{what} multisine"] = wide[(what, "multisine")]
        res[f"{what} info ratio"] = (wide[(what, "2-3-1-1")] ** 2 * wide[("seconds", "2-3-1-1")]) / (
            wide[(what, "multisine")] ** 2 * wide[("seconds", "multisine")]
        )
    res["outliers 2-3-1-1"] = wide[("outliers", "2-3-1-1")].astype(int)
    res["outliers multisine"] = wide[("outliers", "multisine")].astype(int)
    return res.reset_index()


def markdown(res: pd.DataFrame) -> str:
    def cell(v) -> str:
        return f"{v:.3g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(res.columns) + " |", "|" + "---|" * len(res.columns)]
    return "\n".join(lines + ["| " + " | ".join(cell(v) for v in row) + " |" for row in res.itertuples(index=False)])


def plot(res: pd.DataFrame, ax=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(9, 4.5))

    def short(point: str) -> str:
        h, m, f = point.split("_")[:3]
        return f"{int(h[1:])}/{m[1:]}/{int(f[1:])}"

    labels = [f"{d}\n{short(p)}" for d, p in zip(res.derivative, res.point)]
    x = np.arange(len(res))
    for i, what in enumerate(("predicted", "reported", "realized")):
        ax.bar(x + (i - 1) * 0.27, res[f"{what} info ratio"], 0.27, label=what)
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_yscale("log")
    ax.set_xticks(x, labels, fontsize=7, rotation=60)
    ax.set_ylabel("information per flight second,\nmultisine / 2-3-1-1")
    ax.set_title("same length (28 s) and peaks; 1.5 ft/s turbulence; realized over seeds (robust)", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    ax.figure.tight_layout()
    return ax.figure


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--from-csv", type=Path, help="tabulate a previous run's multisine_information.csv")
    ap.add_argument(
        "--band", type=float, nargs=2, default=BAND_HZ, metavar=("F_LO_HZ", "F_HI_HZ"), help="the multisine's band [Hz]"
    )
    a = ap.parse_args()
    out = a.out or Path(tempfile.mkdtemp(prefix="multisine-"))
    out.mkdir(parents=True, exist_ok=True)
    if a.from_csv:
        df = pd.read_csv(a.from_csv)
    else:
        df = pd.concat(
            [fly(out / "work", kind, s, tuple(a.band)) for kind in MANEUVERS for s in range(a.seeds)], ignore_index=True
        )
        df.to_csv(out / "multisine_information.csv", index=False)
    res = table(df)
    text = markdown(res)
    (out / "multisine_information.md").write_text(text + "\n")
    plot(res).savefig(out / "multisine_information.png", dpi=100)
    print(text)
    print(f"written to {out}")


if __name__ == "__main__":
    main()
