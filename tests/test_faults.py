"""Faults: a local worker that dies fails only its point; ``kill -9`` of a whole run at six moments,
then a resume, gives the uninterrupted folder; malformed input is one line, exit code 2, and changes
nothing on disk."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
from campaign.cli import main
from campaign.orchestration.runner import fly_logs, run_campaign
from campaign.orchestration.store import LOCK, read_log, readable_log
from campaign.validation.support import matrix_toml, one_line_error


def _config(matrix):
    from campaign.simulation.aircraft import AircraftSource, load_effects
    from campaign.simulation.engine import FlightConfig
    from campaign.simulation.instruments import load_profile

    return FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects("none")),
        0,
        load_profile("none"),
        matrix.maneuver_params,
        matrix.clmax_by_flap,
    )


def test_a_point_that_kills_its_local_worker_fails_alone(tmp_path):
    from campaign.simulation.matrix import load_matrix

    m = tmp_path / "m.toml"
    m.write_text(matrix_toml([(g, 0, [0.3, 0.5], [2000, 6000]) for g in ("up", "down")]))
    matrix = load_matrix(str(m))
    config = _config(matrix)
    doomed = matrix.points[2].id

    def killer(point, cfg):  # pickled by value: the worker aborts on one point, as a segfault would
        if point.id == doomed:
            os.abort()
        return fly_logs(point, cfg)

    out = tmp_path / "c"
    summary = run_campaign(matrix, config, out, jobs=2, progress=False, flyer=killer)
    assert [pid for pid, _ in summary.failed] == [doomed], summary.failed
    assert "worker died" in summary.failed[0][1] and "SIGABRT" in summary.failed[0][1], summary.failed
    man = json.loads((out / "manifest.json").read_text())
    ok = [r for r in man["points"] if r["status"] == "ok"]
    assert len(ok) == 7 and man["complete"]
    assert sorted(f for r in ok for f in r["files"]) == sorted(p.name for p in out.glob("*.parquet"))
    assert not list(out.glob(".*.tmp"))
    # the resume flies the failed point again, on a sound worker this time, and the logs equal a clean run's
    summary = run_campaign(matrix, config, out, jobs=2, progress=False)
    assert not summary.failed and summary.flown == 1
    clean = tmp_path / "clean"
    run_campaign(matrix, config, clean, jobs=2, progress=False)
    assert {p.name: p.read_bytes() for p in out.glob("*.parquet")} == {
        p.name: p.read_bytes() for p in clean.glob("*.parquet")
    }
    assert (
        json.loads((out / "manifest.json").read_text())["points"]
        == json.loads((clean / "manifest.json").read_text())["points"]
    )


KILL_MATRIX = """name = "kill"
[maneuvers.doublet]
tail_s = 2.0
[maneuvers.gear_extension]
post_s = 5.0
""" + "".join(
    f'[[points]]\ngear = "{g}"\nflap_deg = 5\nmach = {m}\nalt_ft = 2000\n' for m in (0.3, 0.35) for g in ("up", "down")
)

#: One replay case of the shipped five: the replays' moments come as they do with all of them, six flights
#: instead of thirty.
KILL_CASE = '[[case]]\nname = "takeoff-145kt"\nalt_ft = 2000\nias_kt = 145\nflap_deg = 5\ngear = "retract"\n'


def _newer(folder: Path, pattern: str, t0: float, n: int = 1) -> bool:
    """At least ``n`` files matching ``pattern`` written since ``t0`` (a staging folder the run
    renames between the glob and the stat no longer counts)."""
    count = 0
    for p in folder.glob(pattern):
        try:
            count += p.stat().st_mtime >= t0
        except FileNotFoundError:
            pass
    return count >= n


def _points(out: Path) -> int:
    try:
        return len(json.loads((out / "manifest.json").read_text())["points"])
    except (FileNotFoundError, json.JSONDecodeError, KeyError):
        return 0


#: Moments to kill ``campaign run`` at, in order: each attempt resumes what the last one left and is
#: killed at the next moment (a moment the attempt passes too quickly to catch is skipped).
MOMENTS = [
    ("flying: a first log written", lambda o, t0: _newer(o, "*.parquet", t0)),
    ("flying: a point in the manifest", lambda o, t0: _points(o) >= 1 and _newer(o, "manifest.json", t0)),
    ("identify: model copies written", lambda o, t0: _newer(o, ".identification.partial/aircraft_linear", t0)),
    ("identify: swapped in", lambda o, t0: _newer(o, "identification/identification.json", t0)),
    ("replay: a first replay log", lambda o, t0: _newer(o, "replays/*.parquet", t0)),
    ("replay: a first plot", lambda o, t0: _newer(o, "replays/plots/*.png", t0)),
]


def _tree(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and p.name != LOCK
    }


@pytest.mark.slow
def test_kill_9_at_six_moments_then_resume_gives_the_uninterrupted_folder(tmp_path, short_tmp):
    m, cases = tmp_path / "kill.toml", tmp_path / "cases.toml"
    m.write_text(KILL_MATRIX)
    cases.write_text(KILL_CASE)
    argv = [
        sys.executable,
        "-m",
        "campaign.cli",
        "run",
        "--matrix",
        str(m),
        "--cases",
        str(cases),
        "--jobs",
        "2",
        "--quiet",
        "--out",
    ]
    ref, out = tmp_path / "ref", tmp_path / "killed"
    env = {**os.environ, "TMPDIR": str(short_tmp)}
    subprocess.run(argv + [str(ref)], check=True, capture_output=True, env=env)
    assert sorted(p.name for p in short_tmp.iterdir()) == []  # the run and its workers leave no aircraft copies behind
    killed_at = []
    for what, reached in MOMENTS:
        t0 = time.time()
        proc = subprocess.Popen(
            argv + [str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, process_group=0, env=env
        )  # killed: copies stay
        deadline = t0 + 120
        while proc.poll() is None and time.time() < deadline and not reached(out, t0):
            time.sleep(0.002)
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)  # the run and its workers
            killed_at.append(what)
        proc.wait()
        # what a kill leaves is never a corrupt log: every log on disk reads, every manifest entry has its logs
        assert all(readable_log(p) for p in out.rglob("*.parquet"))
    assert len(killed_at) >= 4, killed_at
    assert {"flying", "identify", "replay"} == {w.split(":")[0] for w in killed_at}
    assert list(short_tmp.glob("gearid-*"))  # the killed runs' aircraft copies
    res = subprocess.run(argv + [str(out)], capture_output=True, text=True, env=env)
    assert res.returncode == 0, res.stderr
    assert sorted(p.name for p in short_tmp.glob("gearid-*")) == []  # ... removed by the next run
    assert not [p for p in out.rglob("*") if p.name.startswith(".") and p.name != LOCK]  # no strays
    got, want = _tree(out), _tree(ref)
    assert sorted(got) == sorted(want)
    assert json.loads((out / "replays" / "cases.json").read_text())[0]["name"] == "takeoff-145kt"
    assert len(list((out / "replays").glob("*.parquet"))) == 6  # the one case given, three models, two loops
    # every result is the uninterrupted run's to the byte; the report differs by its date and folder name
    assert [k for k in want if got[k] != want[k]] == ["report.html"]


# ---------------------------------------------------------------------------------------------------------------
# Bad-input sweep: each input is refused in one line with exit code 2, and the existing campaign folder (logs,
# manifest, identification, lock) is byte for byte and timestamp for timestamp what it was.

SWEEP_MATRIX = KILL_MATRIX.split("[[points]]")[0] + "".join(
    f'[[points]]\ngear = "{g}"\nflap_deg = 5\nmach = 0.3\nalt_ft = 2000\n' for g in ("up", "down")
)


@pytest.fixture(scope="module")
def existing(tmp_path_factory):
    """A flown and identified campaign folder, and its matrix."""
    d = tmp_path_factory.mktemp("sweep")
    m = d / "m.toml"
    m.write_text(SWEEP_MATRIX)
    assert main(["run", "--matrix", str(m), "--out", str(d / "c"), "--no-replay", "--quiet"]) == 0
    return d / "c", m


def _snapshot(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): (p.read_bytes(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _aircraft(tmp: Path, edit=None, extra: dict | None = None) -> Path:
    """A copy of our 737 folder, its XML edited by ``edit(text)``, ``extra`` files added."""
    dest = tmp / "ac" / "737"
    shutil.copytree(DEFAULT_AIRCRAFT, dest, ignore=shutil.ignore_patterns("effects"))
    if edit:
        (dest / "737.xml").write_text(edit((dest / "737.xml").read_text()))
    for rel, text in (extra or {}).items():
        (dest / rel).write_text(text)
    return dest


def _write(tmp: Path, name: str, text) -> str:
    p = tmp / name
    p.write_bytes(text) if isinstance(text, bytes) else p.write_text(text)
    return str(p)


def _csv_folder(tmp: Path, c: Path, edit_csv=None, edit_meta=None, sidecar=True) -> str:
    """The campaign's first log as a CSV with a JSON sidecar, edited."""
    log, meta = read_log(next(iter(sorted(c.glob("*doublet.parquet")))))
    d = tmp / "csv"
    d.mkdir(parents=True)
    text = log.to_csv(index=False)
    (d / "a.csv").write_text(edit_csv(text) if edit_csv else text)
    if sidecar:
        side = json.dumps(edit_meta(meta) if edit_meta else meta)
        (d / "a.json").write_text(side)
    return str(d)


ENTITY_XML = (
    '<?xml version="1.0"?>\n<!DOCTYPE effects [<!ENTITY secret SYSTEM "file:///etc/passwd">]>\n'
    '<effects><axis name="DRAG"><function name="aero/x"><value>&secret;</value></function></axis></effects>\n'
)
LAUGHS_XML = (
    '<?xml version="1.0"?>\n<!DOCTYPE effects [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;">]>\n'
    '<effects><axis name="DRAG"><function name="aero/x"><value>&b;</value></function></axis></effects>\n'
)
GOOD_FX = '<effects><axis name="DRAG"><function name="aero/extra"><value>0.001</value></function></axis></effects>\n'


def _cases(t: Path, c: Path, m: Path) -> dict:
    """id -> a function giving (argv, needles); it writes its files into ``t``."""
    mt = m.read_text() if m.is_file() else ""
    run = ["run", "--matrix", str(m), "--out", str(c), "--quiet"]

    def matrix(name, text):
        return ["run", "--matrix", _write(t, name, text), "--out", str(c), "--quiet"]

    def cases(name, text, *extra):
        return ["replay", str(c), "--cases", _write(t, name, text), *extra]

    case = '[[case]]\nname = "landing-x"\nalt_ft = 2000\nias_kt = 135\nflap_deg = 5\ngear = "extend"\n'
    ident_csv = ["identify", "--out", str(c / "identification")]
    return {
        # matrix TOML
        "matrix: TOML syntax": lambda: (matrix("a.toml", "[[points]\n"), ["a.toml", "TOML"]),
        "matrix: unknown key": lambda: (
            matrix("b.toml", mt.replace('name = "kill"', 'name = "kill"\ncolour = 1')),
            ["b.toml", "colour"],
        ),
        "matrix: Mach 0": lambda: (matrix("c.toml", mt.replace("mach = 0.3", "mach = 0", 1)), ["c.toml", "mach"]),
        "matrix: a flap the aircraft lacks": lambda: (
            matrix("d.toml", mt.replace("flap_deg = 5", "flap_deg = 45", 1)),
            ["d.toml", "flap_deg"],
        ),
        "matrix: gear sideways": lambda: (
            matrix("e.toml", mt.replace('gear = "up"', 'gear = "sideways"')),
            ["e.toml", "gear"],
        ),
        "matrix: altitude as text": lambda: (
            matrix("f.toml", mt.replace("alt_ft = 2000", 'alt_ft = "high"', 1)),
            ["f.toml", "alt_ft"],
        ),
        "matrix: no points": lambda: (matrix("g.toml", 'name = "empty"\n'), ["g.toml", "points"]),
        "matrix: not UTF-8": lambda: (matrix("h.toml", b'name = "\xff\xfe"\n'), ["h.toml"]),
        "matrix: missing file": lambda: (["run", "--matrix", str(t / "nope.toml"), "--out", str(c)], ["nope.toml"]),
        "matrix: amplitude beyond the elevator": lambda: (
            matrix("i.toml", mt.replace("tail_s = 2.0", "tail_s = 2.0\namplitude_deg = 40")),
            ["i.toml", "amplitude_deg"],
        ),
        # effects XML
        "effects: not well-formed": lambda: (
            run + ["--effects", _write(t, "a.xml", "<effects><axis name='DRAG'></effects>")],
            ["a.xml", "not well-formed"],
        ),
        "effects: wrong root": lambda: (run + ["--effects", _write(t, "b.xml", "<aircraft/>")], ["b.xml", "<effects>"]),
        "effects: external entity": lambda: (run + ["--effects", _write(t, "c.xml", ENTITY_XML)], ["c.xml", "entity"]),
        "effects: expanding entities": lambda: (
            run + ["--effects", _write(t, "d.xml", LAUGHS_XML)],
            ["d.xml", "entity"],
        ),
        "effects: unknown axis": lambda: (
            run + ["--effects", _write(t, "e.xml", GOOD_FX.replace("DRAG", "UP"))],
            ["e.xml", "UP"],
        ),
        "effects: missing file": lambda: (run + ["--effects", str(t / "nope.xml")], ["nope.xml", "not found"]),
        "effects: prose that names XInclude": lambda: (
            run + ["--effects", _write(t, "f.xml", "Notes: XInclude and <!DOCTYPE are words here.\n")],
            ["f.xml", "not well-formed"],
        ),
        "effects: XInclude": lambda: (
            run
            + [
                "--effects",
                _write(
                    t,
                    "g.xml",
                    '<effects xmlns:xi="http://www.w3.org/2001/XInclude"><xi:include href="/etc/passwd"/></effects>',
                ),
            ],
            ["g.xml", "XInclude"],
        ),
        # aircraft folders
        "aircraft: missing folder": lambda: (run + ["--aircraft", str(t / "nowhere")], ["nowhere", "not found"]),
        "aircraft: no aircraft XML": lambda: (
            run + ["--aircraft", str((t / "empty" / "737").mkdir(parents=True) or t / "empty" / "737")],
            ["737.xml", "not found"],
        ),
        "aircraft: not well-formed": lambda: (
            run + ["--aircraft", str(_aircraft(t / "a", lambda s: s[:-200]))],
            ["737.xml", "not well-formed"],
        ),
        "aircraft: entity reaching out": lambda: (
            run
            + [
                "--aircraft",
                str(
                    _aircraft(
                        t / "b",
                        lambda s: s.replace(
                            "<fdm_config",
                            '<!DOCTYPE fdm_config [<!ENTITY x SYSTEM "../../../../etc/passwd">]>\n<fdm_config',
                            1,
                        ),
                    )
                ),
            ],
            ["737.xml", "entity"],
        ),
        "aircraft: system include climbing out": lambda: (
            run
            + [
                "--aircraft",
                str(
                    _aircraft(
                        t / "c",
                        lambda s: s.replace(
                            "<aerodynamics", '<system file="../../../../../etc/hosts"/>\n<aerodynamics', 1
                        ),
                    )
                ),
            ],
            ["737.xml", "../../../../../etc/hosts", "outside the aircraft folder"],
        ),
        "aircraft: engine file absolute": lambda: (
            run
            + ["--aircraft", str(_aircraft(t / "d", lambda s: s.replace('file="CFM56-7B27"', 'file="/etc/passwd"')))],
            ["737.xml", "/etc/passwd", "outside"],
        ),
        "aircraft: entity in an engine file": lambda: (
            run + ["--aircraft", str(_aircraft(t / "e", extra={"Engines/direct.xml": LAUGHS_XML}))],
            ["direct.xml", "entity"],
        ),
        # instrument profiles
        "instruments: unknown key": lambda: (
            run + ["--instruments", _write(t, "a.i.toml", "rate_hz = 50\ncolour = 2\n")],
            ["a.i.toml", "colour"],
        ),
        "instruments: unknown base": lambda: (
            run + ["--instruments", _write(t, "b.i.toml", 'extends = "wind-tunnel"\n')],
            ["b.i.toml", "extends"],
        ),
        "instruments: negative noise": lambda: (
            run + ["--instruments", _write(t, "c.i.toml", "[channels.alpha_deg]\nnoise = -1\n")],
            ["c.i.toml", "noise"],
        ),
        # replay case files
        "cases: TOML syntax": lambda: (cases("a.c.toml", "[[case]\n"), ["a.c.toml", "TOML"]),
        "cases: unknown key": lambda: (cases("b.c.toml", case + "colour = 1\n"), ["b.c.toml", "colour"]),
        "cases: gear sideways": lambda: (
            cases("c.c.toml", case.replace('"extend"', '"sideways"')),
            ["c.c.toml", "gear"],
        ),
        "cases: no airspeed": lambda: (
            cases("d.c.toml", case.replace("ias_kt = 135", "ias_kt = 0")),
            ["d.c.toml", "ias_kt"],
        ),
        "cases: too short for Part 60": lambda: (cases("e.c.toml", case + "pre_s = 1\n"), ["e.c.toml", "pre_s"]),
        "cases: none": lambda: (cases("f.c.toml", "# nothing\n"), ["f.c.toml", "case"]),
        "cases: a flap the aircraft lacks": lambda: (
            cases("g.c.toml", case.replace("flap_deg = 5", "flap_deg = 45")),
            ["g.c.toml", "flap_deg"],
        ),
        "cases: no case matches": lambda: (["replay", str(c), "--case", "zzz"], ["--case", "zzz"]),
        "cases: given to run": lambda: (
            run + ["--cases", _write(t, "h.c.toml", case + "colour = 1\n")],
            ["h.c.toml", "colour"],
        ),
        # measured CSVs and sidecars
        "csv: a column missing": lambda: (
            ident_csv + [_csv_folder(t / "a", c, lambda s: s.replace("alpha_deg", "aoa", 1))],
            ["a.csv", "alpha_deg"],
        ),
        "csv: text in a number": lambda: (
            ident_csv + [_csv_folder(t / "b", c, lambda s: s.replace("\n", "\nabc", 3)[:])],
            ["a.csv", "row"],
        ),
        "csv: binary garbage": lambda: (
            ident_csv + [_write_dir(t / "c", {"a.csv": bytes(range(256)) * 8, "a.json": "{}"})],
            ["a.csv"],
        ),
        "csv: sidecar missing": lambda: (ident_csv + [_csv_folder(t / "d", c, sidecar=False)], ["a.json", "missing"]),
        "csv: sidecar not JSON": lambda: (
            ident_csv + [_write_dir(t / "e", {"a.csv": "t_s\n0\n", "a.json": "{oops"})],
            ["a.json", "JSON"],
        ),
        "csv: sidecar field missing": lambda: (
            ident_csv + [_csv_folder(t / "f", c, edit_meta=lambda d: {k: v for k, v in d.items() if k != "geometry"})],
            ["a.csv", "geometry"],
        ),
        "campaign: manifest not JSON": lambda: (
            ["identify", _write_dir(t / "g", {"manifest.json": "{oops"}), "--out", str(c / "identification")],
            ["manifest.json", "JSON"],
        ),
        # import maps
        "import: map unknown key": lambda: (
            [
                "import",
                _csv_folder(t / "h", c) + "/a.csv",
                "--map",
                _write(t, "a.map.toml", "colour = 1\n"),
                "--out",
                str(c),
            ],
            ["a.map.toml", "colour"],
        ),
        "import: map without a time column": lambda: (
            ["import", _csv_folder(t / "i", c) + "/a.csv", "--map", _write(t, "b.map.toml", ""), "--out", str(c)],
            ["b.map.toml", "time.column"],
        ),
        # CLI arguments
        "cli: --jobs 0": lambda: (run + ["--jobs", "0"], ["--jobs"]),
        "cli: --jobs text": lambda: (run + ["--jobs", "two"], ["--jobs"]),
        "cli: --seed text": lambda: (run + ["--seed", "x"], ["--seed"]),
        "cli: --noise unknown": lambda: (run + ["--noise", "loud"], ["--noise"]),
        "cli: unknown point": lambda: (
            ["fly", "h99999_m0.30_f00_gup", "--matrix", str(m), "--out", str(c)],
            ["h99999_m0.30_f00_gup"],
        ),
        "cli: --cluster malformed": lambda: (run + ["--cluster", "nonsense"], ["--cluster", "tcp://HOST:PORT"]),
        "cli: --out is a file": lambda: (
            ["run", "--matrix", str(m), "--out", str(c / "manifest.json")],
            ["manifest.json"],
        ),
        "cli: other settings into the folder": lambda: (run + ["--seed", "5"], ["manifest.json", "seed"]),
        "cli: diagnose into the campaign": lambda: (
            ["diagnose", "--data", str(c), "--model", str(DEFAULT_AIRCRAFT), "--out", str(c)],
            [str(c)],
        ),
        "cli: identify --model not an aircraft": lambda: (["identify", str(c), "--model", str(t)], ["not found"]),
        "cli: unknown command": lambda: (["fly-away"], ["fly-away"]),
    }


def _write_dir(d: Path, files: dict) -> str:
    d.mkdir(parents=True)
    for name, text in files.items():
        _write(d, name, text)
    return str(d)


@pytest.mark.parametrize("what", list(_cases(Path(), Path(), Path())))
def test_bad_input_is_one_line_and_changes_nothing(what, existing, tmp_path, capsys):
    c, m = existing
    before = _snapshot(c)
    argv, needles = _cases(tmp_path, c, m)[what]()
    capsys.readouterr()
    one_line_error(capsys, argv, *needles)
    assert _snapshot(c) == before
    assert not list(tmp_path.glob("**/.campaign.lock")), "a refused command left a lock behind"


@pytest.mark.parametrize(
    "good, bad, field", [("ias_kt = 145", "ias_kt = 0", "ias_kt"), ("flap_deg = 5", "flap_deg = 45", "flap_deg")]
)
def test_run_refuses_a_bad_cases_file_before_it_flies(tmp_path, capsys, good, bad, field):
    m = Path(_write(tmp_path, "m.toml", SWEEP_MATRIX))
    assert good in KILL_CASE
    bad = _write(tmp_path, "bad.c.toml", KILL_CASE.replace(good, bad))
    one_line_error(
        capsys,
        ["run", "--matrix", str(m), "--out", str(tmp_path / "c"), "--cases", bad, "--quiet"],
        "bad.c.toml",
        field,
    )
    assert not list(tmp_path.glob("c/*.parquet")) and not (tmp_path / "c" / "manifest.json").exists()
