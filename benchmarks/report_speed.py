"""Time ``campaign report`` on existing results (run by hand).

    python benchmarks/report_speed.py CAMPAIGN_DIR [DIAGNOSIS_DIR ...]

Prints, per folder, the time to write ``report.html`` once the results exist (the mean of
three writes, the modules already imported) and its size.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from campaign.reports.report import write_report


def main(folders: list[Path]) -> None:
    write_report(folders[0])  # imports and matplotlib's font cache, once
    for folder in folders:
        t0 = time.perf_counter()
        for _ in range(3):
            path = write_report(folder)
        dt = (time.perf_counter() - t0) / 3
        print(f"{folder}: {dt:.2f} s, {path.stat().st_size / 1e6:.2f} MB")


if __name__ == "__main__":
    main([Path(a) for a in sys.argv[1:]])
