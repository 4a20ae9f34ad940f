"""What the data compatibility's estimate costs, with and without the Jacobian its converged fits reuse (run by
hand, about 3 min on 2 cores).

    python benchmarks/compat_fit_cost.py [--json FILE]

Our 737 flies the diagnosis matrix (:data:`campaign.validation.hidden.DIAG_MATRIX`, 12 logs reconstructed)
through the flight-test instrument profile with nine instrument errors injected, in still air and in 1.5 ft/s
turbulence (the compatibility tests' data, seed 41). Each data set's estimate (:func:`identify.compat.estimate`,
one job: its whole jackknife's twelve replicates in this process) is made three times each way, in turn, in
this sitting: with :data:`identify.compat.reconstruction.REUSE_LAST_JACOBIAN` (a converged fit's blocks hold
the Jacobian of the point before its last step) and without it (that Jacobian computed again). Each row gives
the least CPU-seconds of this process (its BLAS threads included), the residual evaluations of every
Gauss-Newton fit (whole residuals and single air-data columns apart), and how far the standard errors moved
(the estimates must be the same, bit for bit).

``--json`` writes the rows (default ``benchmarks/results/compat_fit_cost.json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
import identify.compat.fit as fit  # noqa: E402
import identify.compat.reconstruction as rc  # noqa: E402
from campaign.diagnosis.run import load_data  # noqa: E402
from campaign.simulation.aircraft import DEFAULT_AIRCRAFT  # noqa: E402
from campaign.validation.hidden import DIAG_MATRIX  # noqa: E402
from campaign.validation.support import run_matrix  # noqa: E402
from provenance import provenance  # noqa: E402  (this folder is the script's first path)

#: Each estimate is made this many times, the two kinds in turn; a row gives the least CPU time of each.
ROUNDS = 3

#: The injected errors, in the instrument profile's terms (those of ``tests/test_compat.py``).
PROFILE = """extends = "flight-test"
[turbulence]
sigma_fps = {sigma}
[channels.alpha_deg]
bias = 0.5
scale = 1.05
delay_s = 0.05
[channels.theta_deg]
scale = 1.02
delay_s = 0.04
[channels.q_dps]
bias = 0.05
[channels.p_dps]
bias = -0.03
[channels.ax_fps2]
bias = 0.05
[channels.az_fps2]
bias = 0.15
"""


def _counted(counts: dict):
    """:func:`identify.compat.reconstruction.gauss_newton` counting the residual evaluations it asks for."""
    solve = rc.gauss_newton

    def gauss_newton(residual, *args, column=None, **kwargs):
        def whole(x):
            counts["residuals"] += 1
            return residual(x)

        def one(x, i):
            counts["columns"] += 1
            return column(x, i)

        return solve(whole, *args, column=None if column is None else one, **kwargs)

    return gauss_newton


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "compat_fit_cost.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for sigma in (0.0, 1.5):
            where = Path(work) / f"sigma-{sigma}"
            where.mkdir()
            (where / "profile.toml").write_text(PROFILE.format(sigma=sigma))
            logs = load_data(
                run_matrix(where, DIAG_MATRIX, str(DEFAULT_AIRCRAFT), noise=str(where / "profile.toml"), seed=41)
            )
            row, results = {"turbulence_sigma_fps": sigma, "logs": len(logs)}, {}
            for _ in range(ROUNDS):
                for reuse in (False, True):
                    counts = {"residuals": 0, "columns": 0}
                    rc.REUSE_LAST_JACOBIAN, fit.gauss_newton = reuse, _counted(counts)
                    t = time.process_time()
                    results[reuse] = fit.estimate(logs, jobs=1)
                    cpu = time.process_time() - t
                    key = "reused" if reuse else "computed_again"
                    best = row.get(key, {}).get("cpu_s", float("inf"))
                    row[key] = {"cpu_s": round(min(cpu, best), 2), **counts}
            rc.REUSE_LAST_JACOBIAN, fit.gauss_newton = True, rc.gauss_newton
            a, b = results[True].parameters, results[False].parameters
            row["same_estimates"] = [p.estimate for p in a] == [p.estimate for p in b]
            row["se_moved_max"] = max(abs(p.se / q.se - 1.0) for p, q in zip(a, b) if q.se > 0)
            row["applied"] = [p.name for p in results[True].applied]
            rows.append(row)
            print(json.dumps(row), flush=True)
    doc = {
        **provenance("compat_fit_cost"),
        "rows": rows,
    }
    args.json.write_text(json.dumps(doc, indent=1) + "\n")


if __name__ == "__main__":
    main()
