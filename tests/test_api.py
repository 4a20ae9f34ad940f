"""The Python API (gearaero): from a script, standard input and a notebook's kernel; plots on the
caller's axes and backend."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT), "JSBSIM_DEBUG": "0"}

BACKEND = """
import matplotlib
matplotlib.use("svg")  # the caller's choice
import sys
import campaign.cli, campaign.replays.report, campaign.reports.report, diagnose.plots, identify.plots, identify.pipeline
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
print("matplotlib.pyplot" in sys.modules)
"""


def test_importing_the_package_never_chooses_a_matplotlib_backend(tmp_path):
    """No module selects a backend (a notebook's inline plots would break) nor loads pyplot at import."""
    out = subprocess.run([sys.executable, "-c", BACKEND], capture_output=True, text=True, env=ENV, timeout=120,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    source = [p for pkg in ("campaign", "identify", "diagnose", "infra", "maneuvers", "gearaero")
              for p in (ROOT / pkg).rglob("*.py")]
    assert not [str(p) for p in source if "matplotlib.use(" in p.read_text()]
