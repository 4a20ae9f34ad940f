"""Identification accuracy over the full default matrix (run by hand, ~1 min on 2 cores).

    python benchmarks/identification_accuracy.py [WORKDIR]
    python benchmarks/identification_accuracy.py --methods [WORKDIR]

``--methods`` flies the bare model noise-free and with the flight-test profile (1.5 ft/s
turbulence), identifies each with equation error, output error and filter error, and prints
the bias and RMS error of each derivative against the XML over the matrix.

Flies three campaigns (bare model, reference aircraft, reference with
flight-test noise), identifies them and prints: derivative recovery against the
XML, linear gear increments against the model, nonlinear increments against the
reference (model + overlay, read from JSBSim here -- never by identify/), the
noise check (share of parameters within 3 SE) and the paper's-point residuals.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects
from campaign.simulation.engine import FlightConfig, new_fdm
from campaign.simulation.matrix import load_matrix
from campaign.orchestration.runner import run_campaign
from identify.logs import read_campaign
from identify.pipeline import identify_logs

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from campaign.validation.hidden import reference_gear_truth  # noqa: E402
from campaign.validation.support import z_scores  # noqa: E402

ARM = (638.95 - 635.84) / 155.81
CLA = ([0, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8], [5.247, 5.358, 5.5, 5.726, 6.058, 6.558, 7.349, 8.746])


def campaign(work: Path, name: str, effects, noise="none", seed=0):
    m = load_matrix()
    cfg = FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(effects)), seed, noise, m.maneuver_params, m.clmax_by_flap
    )
    out = work / name
    run_campaign(m, cfg, out, jobs=2, progress=False)
    return identify_logs(read_campaign(out))


def xml_truth(mach: float) -> dict:
    """The bare model's derivatives at a Mach number (per rad; Cm about the CG)."""
    cla = np.interp(mach, *CLA)
    return {
        ("CL", "dalpha_rad"): cla,
        ("CL", "delevator_rad"): 0.40,
        ("CL", "dstabilizer_rad"): 0.95,
        ("CL", "qhat_rad"): 4.5,
        ("Cm", "dalpha_rad"): -1.3 - cla * ARM,
        ("Cm", "delevator_rad"): -1.4 - 0.4 * ARM,
        ("Cm", "dstabilizer_rad"): -3.4 - 0.95 * ARM,
        ("Cm", "qhat_rad"): -25 - 4.5 * ARM,
        ("CD", "dalpha2_rad2"): 0.045 * cla**2,
    }


COLUMNS = {
    ("CL", "dalpha_rad"): "CLalpha",
    ("CL", "delevator_rad"): "CLde",
    ("Cm", "dalpha_rad"): "Cmalpha",
    ("Cm", "qhat_rad"): "Cmq",
    ("Cm", "delevator_rad"): "Cmde",
}
NAMES = {"ee": "equation error", "oe": "output error", "fe": "filter error"}
DATA = {"noise-free": "noise-free", "flight-test": "flight-test profile (1.5 ft/s turbulence)"}


def methods(work: Path) -> None:
    """Each method on the paper's matrix, noise-free and with the flight-test profile; prints the table and
    writes ``benchmarks/results/identification_accuracy.json``."""
    import json
    import subprocess
    from datetime import datetime, timezone

    m = load_matrix()
    rows, within = [], {}
    print(f"{'data':<12}{'method':<8}{'derivative':<22}{'bias %':>9}{'RMS %':>9}{'max %':>9}{'|z|<3 %':>9}  s/point")
    for label, noise, seed in (("noise-free", "none", 0), ("flight-test", "flight-test", 1)):
        out = work / f"methods-{label}"
        cfg = FlightConfig(
            AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(None)), seed, noise, m.maneuver_params, m.clmax_by_flap
        )
        if not (out / "manifest.json").exists():
            run_campaign(m, cfg, out, jobs=2, progress=False)
        logs = read_campaign(out)
        for method in ("ee", "oe", "fe"):
            t0 = time.perf_counter()
            ident = identify_logs(logs, jobs=2, method=method, series=())
            per_point = (time.perf_counter() - t0) / len(ident.fits)
            errs: dict = {}
            for f in ident.fits:
                if f.failure:  # its numbers are the equation error's: not this method's
                    continue
                for (c, r), t in xml_truth(f.condition[1]).items():
                    v = f.param(c, r)
                    if v is not None and r != "dalpha2_rad2":
                        se = float(f.fits[c].bse[r])
                        errs.setdefault((c, r), []).append(((v - t) / abs(t) * 100, abs(v - t) / se))
            n = len(ident.fits)
            row = {"data": DATA[label], "method": NAMES[method]}
            z_all = []
            for (c, r), v in errs.items():
                e, z = np.array(v).T
                print(
                    f"{label:<12}{method:<8}{c + ' ' + r:<22}{np.mean(e):>9.2f}{np.sqrt(np.mean(e**2)):>9.2f}"
                    f"{np.max(np.abs(e)):>9.2f}{np.mean(z < 3) * 100:>9.0f}  {per_point:.2f}"
                )
                if (c, r) in COLUMNS:
                    key = COLUMNS[(c, r)]
                    row[key] = float(f"{np.sqrt(np.mean(e**2)):.2g}")
                    row[key + "_bias"] = float(f"{np.mean(e):.2g}")
                    if len(e) < n:
                        row[key + "_points"] = len(e)
                    z_all.append(np.mean(z < 3) * 100)
            row["s_per_point"] = round(per_point, 2)
            if method != "ee":
                row["converged"] = f"{ident.converged} of {n}"
                print(
                    f"{label:<12}{method:<8}converged at {ident.converged} of {n} points; not: "
                    + "; ".join(f"{d['point']} ({d['reason']})" for d in ident.not_converged)
                )
            if label == "flight-test" and z_all:
                within[NAMES[method]] = f"{min(z_all):.0f}-{max(z_all):.0f} %"
            rows.append(row)
    commit = subprocess.run(
        ["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1]
    ).stdout.strip()
    doc = {
        "benchmark": "identification_accuracy",
        "command": "python benchmarks/identification_accuracy.py --methods",
        "code_commit": commit,
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "setup": f"bare 737, the default (paper) matrix, {n} 2-3-1-1s; RMS error of each derivative against the "
        "XML [%] over the points where the method estimated it (its fit converged and kept the term), "
        "and seconds per point on 2 cores",
        "caveat": "the machine was shared with other work while it ran: the seconds per point are noisy",
        "rows": rows,
        "within_3_coloured_se": within,
    }
    path = Path(__file__).resolve().parent / "results" / "identification_accuracy.json"
    path.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"written: {path}")


def main(work: Path) -> None:
    bare = campaign(work, "bare", None)
    errs: dict = {}
    for f in bare.fits:
        truth = xml_truth(f.condition[1])
        for (c, r), t in truth.items():
            v = f.param(c, r)
            errs.setdefault((c, r), []).append(np.nan if v is None else abs(v - t) / abs(t) * 100)
    print(f"bare model, {len(bare.fits)} 2-3-1-1 fits, error vs XML:")
    for (c, r), v in errs.items():
        print(f"  {c} {r:<16} max {np.nanmax(v):6.2f} %  median {np.nanmedian(v):6.3f} %")
    lin = {c: [] for c in ("CL", "CD", "Cm")}
    for m in bare.linear.values():
        a = np.radians(m.alpha_trim_deg)
        t = {"CL": -0.013, "CD": 0.031, "Cm": 0.030 - (-0.013 * np.cos(a) + 0.031 * np.sin(a)) * ARM}
        for c in lin:
            lin[c].append(abs(m.increment(c) - t[c]) / abs(t[c]) * 100)
    print(
        f"linear gear increments, {len(bare.linear)} conditions, worst error %:",
        {c: round(max(v), 3) for c, v in lin.items()},
    )

    ref = campaign(work, "reference", DEFAULT_EFFECTS)
    fdm = new_fdm(AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(DEFAULT_EFFECTS)))
    worst = {c: 0.0 for c in ("CL", "CD", "Cm")}
    for inc in ref.increments.values():
        truth = [reference_gear_truth(fdm, inc.alpha_trim_deg, g, inc.condition[1], ARM) for g in inc.grid]
        for c in worst:
            t = np.array([x[c] for x in truth])
            worst[c] = max(worst[c], float(np.max(np.abs(inc.smooth[c] - t)) / np.max(np.abs(t)) * 100))
    print(
        f"nonlinear increments, {len(ref.increments)} gear-down points, worst error % of peak:",
        {c: round(v, 2) for c, v in worst.items()},
    )

    noisy = campaign(work, "noisy", DEFAULT_EFFECTS, "flight-test", 1)
    z = z_scores(ref.fits, noisy.fits)
    print(
        f"flight-test noise: {np.mean(z <= 3) * 100:.1f} % of {len(z)} parameters within 3 SE "
        f"(RMS z {np.sqrt(np.mean(z**2)):.2f})"
    )
    for label, ident in (("noise-free", ref), ("flight-test noise", noisy)):
        for f in ident.fits:
            if f.point.startswith("h02000_m0.30_f00"):
                print(
                    f"{label:>18} {f.point}: "
                    + "  ".join(
                        f"{c} max {f.fits[c].resid_max:.2g} rel {f.fits[c].rel_error_pct:.2f}%"
                        for c in ("CL", "CD", "Cm")
                    )
                )


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--methods"]
    folder = Path(args[0]) if args else Path(tempfile.mkdtemp(prefix="idacc-"))
    (methods if "--methods" in sys.argv else main)(folder)
