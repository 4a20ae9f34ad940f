"""The package as a user installs it: a wheel built from the sources (not editable) in a fresh virtual
environment outside the checkout runs the main job, with the aircraft, matrices, cases and instrument
profiles it ships."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from campaign.simulation.matrix import load_matrix
from campaign.validation.support import matrix_toml

ROOT = Path(__file__).resolve().parents[1]
UV = shutil.which("uv", path=str(Path(sys.executable).parent)) or shutil.which("uv")
#: What the wheel is built from: the packaging files and the packages, nothing else of the checkout.
SOURCES = (
    "pyproject.toml",
    "README.md",
    "LICENSE",
    "CHANGELOG.md",
    "gearaero",
    "campaign",
    "identify",
    "diagnose",
    "infra",
    "maneuvers",
    "aircraft",
)
PAIR = matrix_toml(
    [("up", 5, 0.3, 2000), ("down", 5, 0.3, 2000)],
    "pair",
    '[defaults]\nmaneuvers_gear_up = ["doublet"]\nmaneuvers_gear_down = ["doublet", "gear_extension"]\n'
    "[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.gear_extension]\npost_s = 5.0\n"
    "[stall.clmax_by_flap]\n5 = 1.90\n",
)


@pytest.mark.skipif(UV is None, reason="uv is not installed (.ci/run installs it)")
def test_the_wheel_in_a_fresh_environment_outside_the_checkout_runs_the_main_job(tmp_path):
    src = tmp_path / "src"
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            src.mkdir(exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    install = subprocess.run(
        [UV, "pip", "install", "--quiet", "-p", str(py), str(src)], capture_output=True, text=True, env=env, timeout=600
    )
    assert install.returncode == 0, install.stderr[-3000:]
    shutil.rmtree(src)  # nothing may read the sources any more
    work = tmp_path / "work"
    work.mkdir()
    (work / "pair.toml").write_text(PAIR)
    env["JSBSIM_DEBUG"] = "0"

    def run(*argv: str) -> str:
        out = subprocess.run(list(argv), capture_output=True, text=True, env=env, cwd=work, timeout=600)
        assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
        return out.stdout

    where = run(
        str(py),
        "-c",
        "import gearaero, campaign, aircraft; print(gearaero.__version__); "
        "print(gearaero.__file__); print(aircraft.SHIPPED_737)",
    ).split()
    assert where[0] == version
    assert all(Path(w).is_relative_to(venv) for w in where[1:]), where
    shipped = run(
        str(py),
        "-c",
        "from campaign.replays.replay import load_cases\n"
        "from campaign.simulation.matrix import load_matrix\n"
        "from campaign.simulation.instruments import shipped\n"
        "print(len(load_cases()), len(load_matrix().points), shipped())",
    )
    assert shipped.split(maxsplit=2)[:2] == ["5", str(len(load_matrix().points))]
    assert "flight-test" in shipped
    run(
        str(venv / "bin" / "campaign"),
        "run",
        "--matrix",
        "pair.toml",
        "--out",
        "out",
        "--noise",
        "flight-test",
        "--jobs",
        "2",
        "--no-replay",
        "--quiet",
    )
    report = (work / "out" / "report.html").read_text()
    assert f"gear-aero-id {version}" in report
    man = json.loads((work / "out" / "manifest.json").read_text())
    assert man["tool"] == {"name": "gear-aero-id", "version": version}
    ident = json.loads((work / "out" / "identification" / "identification.json").read_text())
    assert ident["tool"]["version"] == version and ident["linear"]
    text = run(str(py), "-c", "import gearaero; help(gearaero.diagnose)")
    assert "Parameters" in text and "DiagnosisResult" in text
