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
import gearaero
assert matplotlib.get_backend() == "svg", matplotlib.get_backend()
print("matplotlib.pyplot" in sys.modules)
"""


def test_importing_the_package_never_chooses_a_matplotlib_backend(tmp_path):
    """No module selects a backend (a notebook's inline plots would break) nor loads pyplot at import."""
    out = subprocess.run(
        [sys.executable, "-c", BACKEND], capture_output=True, text=True, env=ENV, timeout=120, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "False"
    source = [
        p
        for pkg in ("campaign", "identify", "diagnose", "infra", "maneuvers", "gearaero")
        for p in (ROOT / pkg).rglob("*.py")
    ]
    assert not [str(p) for p in source if "matplotlib.use(" in p.read_text()]


import json  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

import gearaero as ga  # noqa: E402
from campaign.validation.support import matrix_toml  # noqa: E402

#: Two conditions flown gear up and gear down with a gear extension (2000 ft flap 5 and 10,000 ft flap 0,
#: Mach 0.3): three conditions for the diagnosis to hold one out, short manoeuvres.
SMALL = matrix_toml(
    [("up", 5, 0.3, 2000), ("down", 5, 0.3, 2000), ("up", 0, 0.3, 10000)],
    "api",
    '[defaults]\nmaneuvers_gear_up = ["doublet"]\nmaneuvers_gear_down = ["doublet", "gear_extension"]\n'
    "[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.gear_extension]\npost_s = 5.0\n"
    "[stall.clmax_by_flap]\n0 = 1.45\n5 = 1.90\n",
)


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    folder = tmp_path_factory.mktemp("api")
    (folder / "m.toml").write_text(SMALL)
    camp = ga.fly(folder / "m.toml", folder / "camp", jobs=2, replay=False)
    return camp


def test_fly_is_campaign_run_and_its_result_says_so(flown):
    assert flown.status == 0
    d = flown.to_dict()
    assert json.loads(json.dumps(d)) == d  # JSON-ready
    assert (
        d["points"] == d["points_ok"] == 3
        and d["failed"] == {}
        and d["tool"] == {"name": "gear-aero-id", "version": ga.__version__}
    )
    assert "3 of 3 points ok" in flown.summary() and "report:" in flown.summary()
    assert flown.report is not None and flown.metrics is None  # no replays asked for
    ident = flown.identification
    assert ident.to_dict()["tool"]["version"] == ga.__version__
    assert "Linear gear increments (eq. 4)" in ident.summary()
    lin = ident.linear_gear_model
    assert list(lin.condition) == ["h02000_m0.30_f05"]
    # kept: the same logs, model, options and tool version identify nothing again
    again = ga.identify(flown)
    assert again.kept and again.identification is None and again.to_dict() == ident.to_dict()


def test_a_log_from_a_dataframe_identifies_like_the_file_it_came_from(flown, tmp_path):
    """The documented metadata contract: the frame's channels plus area, chord, pitch inertia and mass
    make a log the identification reads as it reads the campaign's own."""
    logs = ga.read_logs(flown.folder)
    made = []
    for lg in logs:
        g, inertia = lg.meta["geometry"], lg.meta["inertia_slugft2"]
        frame = lg.data.drop(columns=["mach", "qbar_psf", "ias_kt", "mass_slug"])  # derived / given as a number
        made.append(
            ga.log_from_frame(
                frame,
                S_ft2=g["S_ft2"],
                cbar_ft=g["cbar_ft"],
                iyy_slugft2=inertia["iyy"],
                ixx_slugft2=inertia["ixx"],
                izz_slugft2=inertia["izz"],
                ixz_slugft2=inertia["ixz"],
                mass_slug=float(lg.data.mass_slug.iloc[0]),
                thrust_z_arm_ft=g["thrust_z_arm_ft"],
                cg_x_in=g["cg_x_in"],
                cg_z_in=g["cg_z_in"],
                aerorp_x_in=g["aerorp_x_in"],
                aerorp_z_in=g["aerorp_z_in"],
                maneuver=lg.maneuver,
            )
        )
    assert [m.condition for m in made] == [lg.condition for lg in logs]
    # named as a campaign names them; a transition's status point has the gear of its first sample
    assert [(m.gear_down, Path(m.path).name) for m in made if not m.transition] == [
        (lg.gear_down, Path(lg.path).name) for lg in logs if not lg.transition
    ]
    assert [Path(m.path).name for m in made if m.transition] == ["h02000_m0.30_f05_gup__gear_extension.parquet"]
    mach = made[0].data.mach.to_numpy()
    assert np.max(np.abs(mach - logs[0].data.mach.to_numpy())) < 2e-3  # ISA, as JSBSim's atmosphere
    ident = ga.identify(made, tmp_path / "ident", plots="none")
    theirs = flown.identification.linear_gear_model
    ours = ident.linear_gear_model
    for c in ("dCL_gear", "dCD_gear", "dCm_gear"):
        assert abs(ours[c].iloc[0] - theirs[c].iloc[0]) < 0.02 * abs(theirs[c].iloc[0]) + 2e-4, c
    assert ident.identification is not None and ident.identification.fits[0].summary()
    written = ga.write_logs(made[:2], tmp_path / "written")
    assert [p.name for p in written] == [Path(m.path).name for m in made[:2]]
    back = {Path(lg.path).name: lg.meta["status_point"] for lg in ga.read_logs(tmp_path / "written")}
    assert back == {Path(m.path).name: m.meta["status_point"] for m in made[:2]}


@pytest.mark.parametrize(
    "change, says",
    [
        (lambda f, kw: (f.drop(columns=["q_dps"]), kw), "column 'q_dps' missing"),
        (lambda f, kw: (f, {k: v for k, v in kw.items() if k != "mass_slug"}), "mass_slug: give it"),
        (lambda f, kw: (f, {**kw, "S_ft2": -1.0}), "S_ft2: -1 must be positive"),
        (lambda f, kw: (f.assign(alpha_deg=f.alpha_deg.where(f.index != 4, np.nan)), kw), "'alpha_deg', row 5"),
        (lambda f, kw: (f.assign(alpha_deg=f.alpha_deg * 100), kw), "outside -30..60"),
        (lambda f, kw: (f.assign(t_s=f.t_s[::-1].to_numpy()), kw), "'t_s', row 2"),
        (lambda f, kw: (f, {**kw, "sensor_positions_ft": {"q_dps": [1, 0, 0]}}), "sensor_positions_ft.q_dps"),
    ],
)
def test_a_bad_dataframe_is_one_line_naming_the_key(change, says):
    t = np.arange(0.0, 5.0, 0.02)
    frame = pd.DataFrame(
        {
            "t_s": t,
            "alt_ft": 2000.0,
            "tas_kt": 200.0,
            "alpha_deg": 2.0 + 0.1 * np.sin(t),
            "theta_deg": 2.0,
            "p_dps": 0.0,
            "q_dps": 0.1 * np.cos(t),
            "r_dps": 0.0,
            "ax_fps2": 0.5,
            "az_fps2": -32.0,
            "thrust_lbf": 9000.0,
            "elevator_deg": -1.0,
            "stabilizer_deg": 0.5,
            "flap_deg": 5.0,
            "gear_norm": 0.0,
        }
    )
    kw = {"S_ft2": 1341.0, "cbar_ft": 12.98, "iyy_slugft2": 2.48e6, "mass_slug": 4196.0}
    assert ga.log_from_frame(frame, **kw).meta["status_point"]["gear"] == "up"
    bad, kw = change(frame, kw)
    with pytest.raises(ga.UserError, match="log_from_frame") as err:
        ga.log_from_frame(bad, **kw)
    assert says in str(err.value) and "\n" not in str(err.value)


NO_GUARD = """
import sys
import gearaero as ga

camp, out = sys.argv[1:3] if len(sys.argv) > 2 else (CAMP, OUT)
logs = ga.read_logs(camp)
ident = ga.identify(logs, out + "/ident", jobs=2, plots="none")
diag = ga.diagnose(camp, ga.SHIPPED_737, out + "/diag", jobs=2, plots="none")
print("RESULT", len(logs), len(ident.to_dict()["points"]), diag.verdict, diag.to_dict()["tool"]["version"])
"""


def test_a_script_without_a_main_guard_identifies_and_diagnoses_from_stdin(flown, tmp_path):
    """``python - < script.py``: no ``if __name__ == "__main__"``, no file for ``__main__``; the
    workers of the identification and the diagnosis fan out all the same."""
    script = NO_GUARD.replace("CAMP", repr(str(flown.folder))).replace("OUT", repr(str(tmp_path)))
    out = subprocess.run(
        [sys.executable, "-"], input=script, capture_output=True, text=True, env=ENV, timeout=600, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr[-3000:]
    line = [x for x in out.stdout.splitlines() if x.startswith("RESULT")]
    assert line and line[0].split()[1:3] == ["4", "3"], out.stdout
    doc = json.loads((tmp_path / "diag" / "diagnosis.json").read_text())
    assert line[0].endswith(f"{doc['verdict']} {ga.__version__}")
    assert (tmp_path / "diag" / "report.html").exists()


NOTEBOOK_CELLS = [
    "%matplotlib inline\nimport matplotlib\nbackend = matplotlib.get_backend()",
    "import gearaero as ga\nfrom infra.pool import pmap\n\ndef square(x):\n    return x * x\n\n"
    "print('POOL', pmap(square, [(2,), (3,)], 2))",
    "ident = ga.identify(ga.read_logs(CAMP), OUT, jobs=2, plots='none')\nprint('POINTS', len(ident.to_dict()['points']))",
    "fig = ga.plot_increments(list(ident.identification.increments.values()))\n"
    "print('BACKEND', matplotlib.get_backend() == backend, 'inline' in backend)",
]


def test_a_jupyter_kernel_fans_out_and_keeps_its_inline_backend(flown, tmp_path, monkeypatch):
    """A notebook run in a real IPython kernel: the pool runs a function of the notebook's own, the
    identification fans out, and a plot made without ``ax=`` shows inline (the backend untouched)."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    cells = [
        c.replace("CAMP", repr(str(flown.folder))).replace("OUT", repr(str(tmp_path / "ident"))) for c in NOTEBOOK_CELLS
    ]
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(c) for c in cells])
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the kernel's environment
    monkeypatch.setenv("JSBSIM_DEBUG", "0")
    nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    ).execute()
    text = "".join(o.get("text", "") for c in nb.cells for o in c.get("outputs", []))
    assert "POOL [4, 9]" in text and "POINTS 3" in text and "BACKEND True True" in text, text
    images = [o for o in nb.cells[-1].outputs if "image/png" in o.get("data", {})]
    assert images, nb.cells[-1].outputs


def test_help_shows_the_documented_api():
    text = subprocess.run(
        [sys.executable, "-c", "import gearaero; help(gearaero)"],
        capture_output=True,
        text=True,
        env={**ENV, "PAGER": "cat"},
        timeout=120,
    ).stdout
    for name in (
        "read_logs",
        "log_from_frame",
        "fly",
        "identify",
        "model",
        "diagnose",
        "plan",
        "report",
        "__version__",
    ):
        assert name in text, name
    for f in (
        ga.read_logs,
        ga.log_from_frame,
        ga.write_logs,
        ga.fly,
        ga.identify,
        ga.model,
        ga.diagnose,
        ga.plan,
        ga.report,
        ga.plot_replay,
        ga.CampaignResult,
        ga.IdentificationResult,
        ga.ModelResult,
        ga.DiagnosisResult,
        ga.PlanResult,
        ga.ReportResult,
    ):
        doc = f.__doc__ or ""
        assert doc.strip(), f
        if callable(f) and not isinstance(f, type):
            assert "Parameters\n    ----------" in doc and "Returns\n    -------" in doc, f


def test_an_identification_without_a_gear_down_fit_has_an_empty_linear_gear_model(tmp_path):
    """An identification without a gear-down eq. (3) fit (a campaign whose gear-down points fly only the gear
    extension) has an empty ``linear_gear_model.csv``: the property reads it as an empty table, not an
    exception."""
    from gearaero.results import IdentificationResult

    (tmp_path / "linear_gear_model.csv").write_text("")
    (tmp_path / "baseline_parameters.csv").write_text("point,gear\np1,up\n")
    res = IdentificationResult(tmp_path, {}, None, False)
    assert res.linear_gear_model.empty
    assert list(res.parameters.columns) == ["point", "gear"]
