"""Bad input, interrupts and hostile files: each bad input is one line naming the file and the field,
exit code 2, nothing on disk changed; Ctrl-C is one line and exit code 130 without a worker's
traceback, and the same command then resumes; a sweep of generated bad inputs."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jsbsim
import pytest

from aircraft import SHIPPED_737
from campaign.cli import main
from campaign.orchestration.store import LOCK
from campaign.validation.bad_inputs import attempt, clean, context, make_cases, tree_hash
from campaign.validation.support import one_line_error

ROOT = Path(__file__).resolve().parents[1]
HFB = ROOT / "tests" / "data" / "hfb320_1_10.asc"
HFB_MAP = ROOT / "docs" / "examples" / "hfb320-map.toml"
STOCK_737 = Path(jsbsim.get_default_root_dir()) / "aircraft" / "737"
MATRIX = (
    'name = "t"\n[maneuvers.doublet]\ntail_s = 1.0\n[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.3\nalt_ft = 2000\n'
)


def _files(folder: Path) -> dict:
    """Every file below ``folder``: bytes and modification time."""
    return {
        str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _refused(capsys, tmp_path: Path, argv: list[str], *needles: str) -> str:
    """One line and exit code 2, and no file added, changed or removed under ``tmp_path``."""
    before = _files(tmp_path)
    err = one_line_error(capsys, argv, *needles)
    assert _files(tmp_path) == before
    return err


# ----------------------------------------------------------------------------------------------- import


def _hfb_with(tmp_path: Path, name: str, edit) -> Path:
    rows = [ln.split() for ln in HFB.read_text().splitlines() if ln.strip()]
    for r in rows:
        edit(r)
    p = tmp_path / name
    p.write_text("\n".join(" ".join(r) for r in rows) + "\n")
    return p


def test_an_import_of_degrees_declared_radians_leaves_nothing_and_the_mended_one_succeeds(tmp_path, capsys):
    deg = _hfb_with(tmp_path, "deg.asc", lambda r: r.__setitem__(5, f"{float(r[5]) * 57.29578:.5f}"))
    out = tmp_path / "imported"
    _refused(
        capsys,
        tmp_path,
        ["import", str(deg), "--map", str(HFB_MAP), "--out", str(out)],
        "deg.asc",
        "channels.alpha_deg",
        "hfb320-map.toml",
        "row 1",
    )
    assert not out.exists()
    mended = tmp_path / "deg-map.toml"
    mended.write_text(HFB_MAP.read_text().replace('alpha_deg = "alpha rad"', 'alpha_deg = "alpha deg"'))
    assert main(["import", str(deg), "--map", str(mended), "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["deg.parquet", "import.json", "import.txt"]


@pytest.mark.parametrize(
    "record, map_name, says",
    [
        ("fAttas_qst01.asc", "attas-map.toml", '"mat", its suffix .asc says "whitespace"'),
        ("fAttasElv1.mat", "attas-stall-map.toml", '"whitespace", its suffix .mat says "mat"'),
    ],
)
def test_a_record_read_in_the_format_its_map_gives_against_its_suffix_names_both(
    tmp_path, capsys, record, map_name, says
):
    """A map written for the ATTAS's .mat records given a text record (or the other way round): one line naming
    the file, the map's ``source.format`` and what the suffix says; nothing written."""
    out = tmp_path / "imported"
    examples = ROOT / "docs" / "examples"
    argv = ["import", str(ROOT / "tests" / "data" / record), "--map", str(examples / map_name), "--out", str(out)]
    one_line_error(capsys, argv, record, f"source.format in {examples / map_name} reads it as {says}")
    assert not out.exists()


def test_an_import_whose_out_is_a_file_is_refused(tmp_path, capsys):
    (tmp_path / "afile").write_text("mine\n")
    _refused(
        capsys,
        tmp_path,
        ["import", str(HFB), "--map", str(HFB_MAP), "--out", str(tmp_path / "afile")],
        "afile",
        "is a file",
    )


def test_an_import_of_a_ten_megabyte_line_is_refused_at_once(tmp_path, capsys):
    long = tmp_path / "long.asc"
    long.write_text(HFB.read_text() + " ".join(["1"] * 5_000_000) + "\n")
    t0 = time.perf_counter()
    err = _refused(
        capsys,
        tmp_path,
        ["import", str(long), "--map", str(HFB_MAP), "--out", str(tmp_path / "o")],
        "long.asc",
        "row 602",
        "longer than",
    )
    assert time.perf_counter() - t0 < 30 and len(err) < 300, err


def test_a_map_with_a_negative_wing_area_is_refused(tmp_path, capsys):
    bad = tmp_path / "neg.toml"
    bad.write_text(HFB_MAP.read_text().replace('S = "30.097 m^2"', 'S = "-1341 ft^2"'))
    _refused(
        capsys,
        tmp_path,
        ["import", str(HFB), "--map", str(bad), "--out", str(tmp_path / "o")],
        "neg.toml",
        "aircraft.S",
        "-1341",
    )


# ----------------------------------------------------------------------------------------------- overlays


def test_an_overlay_reading_a_property_nothing_defines_is_one_line_not_an_abort(tmp_path):
    """JSBSim ran such a model, then threw from its destructor and the process aborted (exit 134)."""
    (tmp_path / "m.toml").write_text(MATRIX)
    fx = tmp_path / "fx.xml"
    fx.write_text(
        '<effects><axis name="DRAG"><function name="aero/extra"><product><property>no/such/property'
        "</property><value>0.01</value></product></function></axis></effects>"
    )
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "campaign.cli",
            "run",
            "--matrix",
            "m.toml",
            "--effects",
            str(fx),
            "--out",
            "o",
            "--quiet",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "terminate" not in done.stderr, done.stderr
    assert "fx.xml" in done.stderr and "aero/extra" in done.stderr and "no/such/property" in done.stderr
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "function, needle",
    [
        ('<function name="aero/extra"><value>nan</value></function>', "<value>nan</value>"),
        ('<function name="aero/extra"><value>1e400</value></function>', "<value>1e400</value>"),
        ('<function name="aero/extra"><value>high</value></function>', "<value>high</value>"),
        ('<function name="fcs/elevator-pos-rad"><value>0.01</value></function>', "fcs/elevator-pos-rad"),
    ],
)
def test_an_overlay_value_or_name_is_refused_naming_the_overlay_and_its_function(tmp_path, capsys, function, needle):
    (tmp_path / "m.toml").write_text(MATRIX)
    fx = tmp_path / "fx.xml"
    fx.write_text(f'<effects><axis name="DRAG">{function}</axis></effects>')
    err = _refused(
        capsys,
        tmp_path,
        ["run", "--matrix", str(tmp_path / "m.toml"), "--effects", str(fx), "--out", str(tmp_path / "o"), "--quiet"],
        "fx.xml",
        "<function name=",
        needle,
    )
    assert "JSBSim could not load aircraft" not in err


def test_a_symbolic_link_out_of_the_aircraft_folder_is_refused(tmp_path, capsys):
    import shutil

    ac = tmp_path / "ac" / "737"
    shutil.copytree(SHIPPED_737, ac, ignore=shutil.ignore_patterns("effects"))
    (ac / "Engines" / "CFM56-7B27.xml").unlink()
    (ac / "Engines" / "CFM56-7B27.xml").symlink_to("/etc/passwd")
    (tmp_path / "m.toml").write_text(MATRIX)
    _refused(
        capsys,
        tmp_path,
        [
            "run",
            "--matrix",
            str(tmp_path / "m.toml"),
            "--aircraft",
            str(ac),
            "--effects",
            "none",
            "--out",
            str(tmp_path / "o"),
        ],
        "Engines/CFM56-7B27.xml",
        "/etc/passwd",
        "outside the aircraft folder",
    )


# ----------------------------------------------------------------------------------------------- matrices, profiles


@pytest.mark.parametrize(
    "edit, needles",
    [
        (lambda t: t.replace("mach = 0.3", "mach = nan"), ("points[0].mach", "finite")),
        (lambda t: t.replace("mach = 0.3", "mach = []"), ("points[0].mach", "empty list")),
        (
            lambda t: "[defaults]\nmaneuvers_gear_up = []\n" + t.replace('name = "t"\n', ""),
            ("defaults.maneuvers_gear_up", "empty list"),
        ),
        (lambda t: t + "[maneuvers.level_turn]\nturn_s = 0\n", ("maneuvers.level_turn.turn_s", "> 0")),
    ],
)
def test_a_matrix_value_that_flies_nothing_or_nonsense_is_refused(tmp_path, capsys, edit, needles):
    m = tmp_path / "m.toml"
    m.write_text(edit(MATRIX))
    _refused(capsys, tmp_path, ["run", "--matrix", str(m), "--out", str(tmp_path / "o"), "--quiet"], "m.toml", *needles)


def test_a_weight_the_stock_737_cannot_take_is_refused_before_flying(tmp_path, capsys):
    m = tmp_path / "m.toml"
    m.write_text(MATRIX + "weight_lb = 150000\n")
    _refused(
        capsys,
        tmp_path,
        [
            "run",
            "--matrix",
            str(m),
            "--aircraft",
            str(STOCK_737),
            "--effects",
            "none",
            "--out",
            str(tmp_path / "o"),
            "--quiet",
        ],
        "m.toml",
        "points[0].weight_lb",
        "no point mass",
    )


@pytest.mark.parametrize(
    "profile, field",
    [
        ("rate_hz = 1000\n", "rate_hz"),
        ("[channels.alpha_deg]\ndelay_s = 1e6\n", "channels.alpha_deg.delay_s"),
        ("[channels.alpha_deg]\nscale = 0\n", "channels.alpha_deg.scale"),
    ],
)
def test_an_instrument_profile_beyond_what_a_sensor_can_be_is_refused(tmp_path, capsys, profile, field):
    from campaign.simulation.engine import DT_S
    from campaign.simulation.instruments import SIM_RATE_HZ

    assert SIM_RATE_HZ == 1.0 / DT_S
    (tmp_path / "m.toml").write_text(MATRIX)
    (tmp_path / "p.toml").write_text(profile)
    _refused(
        capsys,
        tmp_path,
        [
            "run",
            "--matrix",
            str(tmp_path / "m.toml"),
            "--instruments",
            str(tmp_path / "p.toml"),
            "--out",
            str(tmp_path / "o"),
            "--quiet",
        ],
        "p.toml",
        field,
    )


# ----------------------------------------------------------------------------------------------- plan, diagnose


@pytest.mark.parametrize(
    "args, needles",
    [
        (["--budget-min", "0"], ("--budget-min",)),
        (["--budget-min", "-5"], ("--budget-min",)),
        (["--budget-min", "nan"], ("--budget-min",)),
        (["--matrix", "MATRIX"], ("bad.toml", "points[0].mach")),
    ],
)
def test_plan_checks_its_arguments_before_the_rivals(tmp_path, capsys, args, needles):
    d = tmp_path / "diag"
    d.mkdir()
    (d / "diagnosis.json").write_text(json.dumps({"rivals": [], "model": str(SHIPPED_737), "data": {"paths": []}}))
    (tmp_path / "bad.toml").write_text(MATRIX.replace("mach = 0.3", "mach = nan"))
    args = [str(tmp_path / "bad.toml") if a == "MATRIX" else a for a in args]
    err = _refused(capsys, tmp_path, ["plan", "--diagnosis", str(d), *args], *needles)
    assert "nothing to separate" not in err


def test_diagnose_will_not_write_inside_its_data(tmp_path, capsys):
    data = tmp_path / "data"
    assert main(["import", str(HFB), "--map", str(HFB_MAP), "--out", str(data)]) == 0
    capsys.readouterr()
    _refused(
        capsys,
        tmp_path,
        ["diagnose", "--data", str(data), "--model", str(SHIPPED_737), "--out", str(data / "diagnosis"), "--quiet"],
        "inside --data",
    )


# ----------------------------------------------------------------------------------------------- Ctrl-C


def _interrupt(argv: list[str], cwd: Path, reached, env: dict) -> subprocess.CompletedProcess:
    """Run the CLI in a process group of its own, send Ctrl-C's SIGINT to the whole group (as a terminal
    does) once ``reached(proc)``, and return what the command did."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "campaign.cli", *argv],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        process_group=0,
        env=env,
    )
    deadline = time.time() + 240
    while proc.poll() is None and time.time() < deadline and not reached(proc):
        time.sleep(0.01)
    assert proc.poll() is None, "the command ended before the moment to interrupt it"
    os.killpg(proc.pid, signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, out, err)


def _in_group(pgid: int) -> int:
    """How many processes the process group ``pgid`` holds (Linux's ``/proc``)."""
    n = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            n += int(stat.read_text().rpartition(")")[2].split()[2]) == pgid
        except (OSError, ValueError, IndexError):
            continue
    return n


CTRL_C_MATRIX = (
    MATRIX.replace('gear = "up"\nflap_deg = 0\nmach = 0.3', 'gear = "up"\nflap_deg = 5\nmach = [0.3, 0.35]')
    + 'maneuvers = ["doublet"]\n[[points]]\ngear = "down"\nflap_deg = 5\nmach = [0.3, 0.35]\nalt_ft = 2000\n'
    'maneuvers = ["doublet", "gear_extension"]\n[maneuvers.gear_extension]\npost_s = 5.0\n'
)


def test_ctrl_c_in_the_identification_and_in_a_diagnosis_is_one_line_and_the_next_run_resumes(tmp_path, short_tmp):
    """Each worker printed ``Process ForkServerProcess-2: ... KeyboardInterrupt`` under the line."""
    import shutil

    env = {**os.environ, "TMPDIR": str(short_tmp)}
    (tmp_path / "m.toml").write_text(CTRL_C_MATRIX)
    run = ["run", "--matrix", "m.toml", "--jobs", "2", "--quiet", "--no-replay", "--out"]
    assert main(run + ["c", "--no-identify"]) == 0
    shutil.copytree(tmp_path / "c", tmp_path / "ref")
    assert main(run + ["ref"]) == 0
    logs = {p.name: p.read_bytes() for p in (tmp_path / "c").glob("*.parquet")}
    done = _interrupt(run + ["c"], tmp_path, lambda _: (tmp_path / "c" / ".identification.partial").exists(), env)
    assert done.returncode == 130, done.stderr
    assert done.stderr == "campaign: interrupted; run the same command again to resume\n", done.stderr
    assert {p.name: p.read_bytes() for p in (tmp_path / "c").glob("*.parquet")} == logs
    assert not [p for p in (tmp_path / "c").iterdir() if p.name.startswith(".") and p.name != LOCK]
    assert (
        subprocess.run(
            [sys.executable, "-m", "campaign.cli", *run, "c"], cwd=tmp_path, env=env, capture_output=True
        ).returncode
        == 0
    )
    got, want = (
        json.loads((tmp_path / f / "identification" / "identification.json").read_text()) for f in ("c", "ref")
    )
    assert json.dumps(got).replace(str(tmp_path / "c"), "F") == json.dumps(want).replace(str(tmp_path / "ref"), "F")
    # a diagnosis interrupted as it runs (its resource tracker and fork server up): no report folder, the
    # data as they were
    data = _files(tmp_path / "c")
    t0 = time.time()
    done = _interrupt(
        ["diagnose", "--data", "c", "--model", str(SHIPPED_737), "--out", "d", "--jobs", "2", "--quiet", "--no-plots"],
        tmp_path,
        lambda p: time.time() - t0 > 2 and _in_group(p.pid) >= 3,
        env,
    )
    assert done.returncode == 130, done.stderr
    assert done.stderr == "campaign: interrupted; run the same command again to resume\n", done.stderr
    assert not (tmp_path / "d").exists() and _files(tmp_path / "c") == data


# ----------------------------------------------------------------------------------------------- the sweep


def test_a_sweep_of_generated_bad_inputs_is_clean(tmp_path):
    """A few dozen of ``benchmarks/bad_input_sweep.py``'s inputs, eight of each kind."""
    results = tmp_path / "results"
    with open(os.devnull, "w") as quiet:
        saved, sys.stdout = sys.stdout, quiet
        try:
            assert main(["import", str(HFB), "--map", str(HFB_MAP), "--out", str(results)]) == 0
        finally:
            sys.stdout = saved
    ctx = context(tmp_path / "work", HFB, HFB_MAP, results, SHIPPED_737)
    before = (tree_hash(results), tree_hash(SHIPPED_737))
    bad = [
        (r["label"], r["stderr"], r["escaped"])
        for r in map(attempt, make_cases(ctx, tmp_path / "work", 48, seed=7))
        if not clean(r)
    ]
    assert not bad, bad
    assert (tree_hash(results), tree_hash(SHIPPED_737)) == before
