"""The CLI: bad input, determinism, resume after a kill, no silent overwrite."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jsbsim
import numpy as np
import pandas as pd

from campaign.cli import main
from campaign.orchestration.store import LOCK, read_log
from campaign.validation.support import matrix_toml, one_line_error

STOCK_737 = os.path.join(jsbsim.get_default_root_dir(), "aircraft", "737")


def test_bad_inputs_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, small_matrix):
    out = tmp_path / "out"
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text("[[points]\n")
    unknown = tmp_path / "unknown.toml"
    unknown.write_text(small_matrix.read_text().replace('name = "small"', 'name = "small"\ncolour = 1'))
    mach0 = tmp_path / "mach0.toml"
    mach0.write_text(small_matrix.read_text().replace("mach = 0.3\nalt_ft = 2000", "mach = 0\nalt_ft = 2000"))
    flap = tmp_path / "flap.toml"
    flap.write_text(small_matrix.read_text().replace("flap_deg = 5", "flap_deg = 45"))
    fx = tmp_path / "fx.xml"
    fx.write_text("<effects><axis name='DRAG'></effects>")
    one_line_error(capsys, ["run", "--matrix", str(unknown), "--out", str(out)], str(unknown), "colour")
    one_line_error(capsys, ["run", "--matrix", str(mach0), "--out", str(out)], str(mach0), "points[1].mach")
    one_line_error(capsys, ["run", "--matrix", str(flap), "--out", str(out)], str(flap), "points[1].flap_deg")
    one_line_error(capsys, ["run", "--matrix", str(bad_toml), "--out", str(out)], str(bad_toml), "TOML")
    one_line_error(capsys, ["run", "--aircraft", str(tmp_path / "nope"), "--out", str(out)], "nope", "aircraft folder")
    one_line_error(capsys, ["run", "--effects", str(fx), "--out", str(out)], str(fx), "not well-formed")
    one_line_error(capsys, ["run", "--jobs", "0", "--out", str(out)], "--jobs")
    one_line_error(capsys, ["fly", "h99999_m0.30_f00_gup", "--out", str(out)], "h99999_m0.30_f00_gup")
    assert not out.exists()


def test_entry_point_is_installed_and_helps():
    for sub in ([], ["run"], ["fly"], ["points"]):
        res = subprocess.run(
            [str(Path(sys.executable).parent / "campaign"), *sub, "--help"], capture_output=True, text=True
        )
        assert res.returncode == 0 and "usage: campaign" in res.stdout


def test_fly_reproduces_the_campaign_bit_for_bit(tmp_path, capsys, small_matrix):
    camp, one = tmp_path / "camp", tmp_path / "one"
    assert (
        main(
            [
                "run",
                "--matrix",
                str(small_matrix),
                "--out",
                str(camp),
                "--jobs",
                "2",
                "--seed",
                "7",
                "--noise",
                "flight-test",
                "--no-identify",
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "fly",
                "h02000_m0.30_f05_gdn",
                "--matrix",
                str(small_matrix),
                "--out",
                str(one),
                "--seed",
                "7",
                "--noise",
                "flight-test",
            ]
        )
        == 0
    )
    files = sorted(p.name for p in one.glob("*.parquet"))
    assert files == ["h02000_m0.30_f05_gdn__doublet.parquet", "h02000_m0.30_f05_gdn__gear_extension.parquet"]
    for f in files:
        assert (one / f).read_bytes() == (camp / f).read_bytes()
    # flying again into the same folder refuses to overwrite
    capsys.readouterr()
    one_line_error(
        capsys, ["fly", "h02000_m0.30_f05_gdn", "--matrix", str(small_matrix), "--out", str(one)], "will not overwrite"
    )


def test_logs_follow_the_schema_and_carry_metadata(tmp_path, small_matrix, capsys):
    out = tmp_path / "c"
    assert main(["run", "--matrix", str(small_matrix), "--out", str(out)]) == 0
    assert (out / "identification" / "identification.json").exists()  # run identifies...
    # ...and would replay, but this matrix flies no condition both gear up and gear down
    assert "replays skipped: no gear models were identified" in capsys.readouterr().out
    manifest = json.loads((out / "manifest.json").read_text())
    assert [p["status"] for p in manifest["points"]] == ["ok"] * 3 and manifest["complete"]
    assert manifest["hashes"]["aircraft"] and manifest["hashes"]["effects"] and manifest["versions"]["jsbsim"]
    import pyarrow.parquet as pq
    from campaign.simulation.catalog import LOG_COLUMNS

    path = out / "h02000_m0.30_f05_gdn__gear_extension.parquet"
    log, meta = read_log(path)
    assert tuple(log.columns) == LOG_COLUMNS
    assert pq.ParquetFile(path).metadata.row_group(0).column(0).compression == "ZSTD"
    assert meta["point"] == "h02000_m0.30_f05_gdn" and meta["maneuver"] == "gear_extension"
    assert set(meta) >= {"seed", "inertia_slugft2", "geometry", "trim", "noise"}
    assert manifest["seeds"]["logs"][path.name] == meta["seed"]
    assert log.t_s.diff().dropna().round(12).eq(round(1 / 120, 12)).all()
    assert "BYTE_STREAM_SPLIT" in pq.ParquetFile(path).metadata.row_group(0).column(0).encodings
    # a log round-trips exactly, whatever its columns hold
    from campaign.orchestration.store import write_log

    mixed = log.head(50).assign(label="a", n=range(50), flag=lambda d: d.t_s > 0.1)
    write_log(tmp_path / "mixed.parquet", mixed, meta)
    back, back_meta = read_log(tmp_path / "mixed.parquet")
    pd.testing.assert_frame_equal(back, mixed, check_exact=True)
    assert back_meta == meta


def test_flight_test_noise_is_seeded(tmp_path, small_matrix):
    a, b, c = (tmp_path / x for x in "abc")
    pid = "h02000_m0.30_f00_gup"
    for out, seed in ((a, 1), (b, 1), (c, 2)):
        assert (
            main(
                [
                    "fly",
                    pid,
                    "--matrix",
                    str(small_matrix),
                    "--out",
                    str(out),
                    "--seed",
                    str(seed),
                    "--noise",
                    "flight-test",
                ]
            )
            == 0
        )
    name = f"{pid}__doublet.parquet"
    assert (a / name).read_bytes() == (b / name).read_bytes()
    la, lc = read_log(a / name)[0], read_log(c / name)[0]
    assert not la.alpha_deg.equals(lc.alpha_deg)
    meta = read_log(a / name)[1]
    assert meta["instruments"]["name"] == "flight-test" and len(meta["instruments"]["sha256"]) == 64
    assert "qdot_dps2" not in la and meta["omitted_channels"] == ["qdot_dps2"]
    assert la.t_s.diff().dropna().round(12).eq(0.02).all()  # 50 Hz


def test_existing_campaign_with_other_settings_is_not_overwritten(tmp_path, capsys, small_matrix):
    out = tmp_path / "c"
    assert main(["run", "--matrix", str(small_matrix), "--out", str(out), "--seed", "1", "--no-replay"]) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    one_line_error(
        capsys, ["run", "--matrix", str(small_matrix), "--out", str(out), "--seed", "2"], "manifest.json", "seed"
    )
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    # the same settings again: nothing to fly, no log changes
    assert main(["run", "--matrix", str(small_matrix), "--out", str(out), "--seed", "1", "--no-identify"]) == 0
    assert {p: p.read_bytes() for p in out.glob("*.parquet")} == {
        k: v for k, v in before.items() if k.suffix == ".parquet"
    }


SLOW_MATRIX = """
name = "slow"
[defaults]
maneuvers_gear_down = ["gear_extension"]
[maneuvers.gear_extension]
post_s = 40.0
[[points]]
gear = "down"
flap_deg = [0]
mach = 0.3
alt_ft = [2000, 3000, 4000, 5000, 6000, 7000, 8000, 9000, 10000]
""".replace("flap_deg = [0]", "flap_deg = 0")


def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path, short_tmp):
    m = tmp_path / "slow.toml"
    m.write_text(SLOW_MATRIX)
    ref, killed = tmp_path / "ref", tmp_path / "killed"
    assert main(["run", "--matrix", str(m), "--out", str(ref), "--no-identify"]) == 0
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "campaign.cli",
            "run",
            "--matrix",
            str(m),
            "--out",
            str(killed),
            "--quiet",
            "--no-identify",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "TMPDIR": str(short_tmp)},
    )  # a killed run leaves its aircraft copy
    deadline = time.time() + 60
    n_done = 0
    while time.time() < deadline and proc.poll() is None:
        try:
            n_done = len(json.loads((killed / "manifest.json").read_text())["points"])
        except (FileNotFoundError, json.JSONDecodeError, KeyError):
            n_done = 0
        if n_done >= 2:
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run finished before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    partial = json.loads((killed / "manifest.json").read_text())
    assert 2 <= len(partial["points"]) < 9 and not partial["complete"]
    assert (killed / LOCK).exists()  # the killed run's lock file is left behind; it must not block the resume
    assert main(["run", "--matrix", str(m), "--out", str(killed), "--no-identify"]) == 0
    final = json.loads((killed / "manifest.json").read_text())
    assert final["complete"] and len(final["points"]) == 9
    ref_files = {p.name: p.read_bytes() for p in ref.glob("*.parquet")}
    got = {
        p.name: p.read_bytes()
        for p in killed.iterdir()
        if p.is_file() and p.name not in ("manifest.json", LOCK, "report.html")
    }
    assert got == ref_files
    assert (killed / "report.html").exists()  # the resumed run's report (its date differs from ref's)
    assert final["points"] == json.loads((ref / "manifest.json").read_text())["points"]


def test_stock_aircraft_fly_at_their_own_flap_angles(tmp_path, capsys):
    """Flap settings mean the aircraft's own fcs/flap-pos-deg: the A320 flies flap 5 at 5 deg; the stock
    737, whose FCS writes only fcs/flap-pos-norm, has no flap angle and refuses anything but 0."""
    m = tmp_path / "m.toml"
    m.write_text(
        matrix_toml(
            [("down", 0, 0.3, 2000), ("up", 5, 0.3, 5000)],
            "flaps",
            "[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.gear_extension]\npost_s = 5.0\n",
        )
    )
    out = tmp_path / "stock"
    assert (
        main(
            [
                "fly",
                "h02000_m0.30_f00_gdn",
                "--matrix",
                str(m),
                "--aircraft",
                STOCK_737,
                "--effects",
                "none",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    log, meta = read_log(out / "h02000_m0.30_f00_gdn__gear_extension.parquet")
    assert meta["absent_channels"] == ["stabilizer_deg"] and (log.stabilizer_deg == 0).all()
    assert log.gear_norm.iloc[-1] == 1.0 and meta["aircraft"] == "737"
    capsys.readouterr()
    one_line_error(
        capsys,
        [
            "fly",
            "h05000_m0.30_f05_gup",
            "--matrix",
            str(m),
            "--aircraft",
            STOCK_737,
            "--effects",
            "none",
            "--out",
            str(out),
        ],
        "points[1].flap_deg",
        "no flap angle",
    )
    a320 = os.path.join(jsbsim.get_default_root_dir(), "aircraft", "A320")
    assert (
        main(
            [
                "fly",
                "h05000_m0.30_f05_gup",
                "--matrix",
                str(m),
                "--aircraft",
                a320,
                "--effects",
                "none",
                "--out",
                str(tmp_path / "a320"),
            ]
        )
        == 0
    )
    log, _ = read_log(tmp_path / "a320" / "h05000_m0.30_f05_gup__doublet.parquet")
    assert np.allclose(log.flap_deg, 5.0, atol=1e-9)


def test_identify_and_diagnose_are_this_projects_packages():
    import diagnose
    import identify

    for pkg in (identify, diagnose):
        assert Path(pkg.__file__).resolve().parent == Path(__file__).resolve().parents[1] / pkg.__name__


def test_corrupt_log_is_an_error_for_identify_and_is_reflown_on_resume(tmp_path, capsys, small_matrix):
    out = tmp_path / "c"
    assert main(["run", "--matrix", str(small_matrix), "--out", str(out), "--no-identify"]) == 0
    victim = out / "h02000_m0.30_f00_gup__doublet.parquet"
    good = victim.read_bytes()
    victim.write_bytes(good[:1000])
    capsys.readouterr()
    assert main(["identify", str(out)]) == 2
    err = capsys.readouterr().err
    assert victim.name in err and "not a readable Parquet log" in err and err.count("\n") == 1
    assert main(["run", "--matrix", str(small_matrix), "--out", str(out), "--no-identify"]) == 0
    assert "1 flown now" in capsys.readouterr().out
    assert victim.read_bytes() == good


def test_outputs_have_ordinary_permissions(tmp_path, small_matrix):
    import os

    old = os.umask(0o022)
    try:
        assert main(["run", "--matrix", str(small_matrix), "--out", str(tmp_path / "c"), "--no-identify"]) == 0
    finally:
        os.umask(old)
    for p in (tmp_path / "c").iterdir():
        assert p.stat().st_mode & 0o777 == 0o644, p


def test_points_into_a_closed_pipe_is_quiet():
    res = subprocess.run(
        f"{sys.executable} -m campaign.cli points | head -1", shell=True, capture_output=True, text=True
    )
    assert res.stdout.startswith("h02000_m0.30_f00_gup") and "Traceback" not in res.stderr


def test_run_fails_when_no_point_flies_and_limits_amplitudes(tmp_path, capsys, small_matrix):
    bad = tmp_path / "fast.toml"
    bad.write_text('[[points]]\ngear = "up"\nflap_deg = 40\nmach = 0.6\nalt_ft = 2000\n')
    assert main(["run", "--matrix", str(bad), "--out", str(tmp_path / "f")]) == 1
    assert "0 of 1 points ok" in capsys.readouterr().out
    big = tmp_path / "big.toml"
    big.write_text(small_matrix.read_text().replace("tail_s = 2.0", "tail_s = 2.0\namplitude_deg = 40"))
    one_line_error(
        capsys,
        ["run", "--matrix", str(big), "--out", str(tmp_path / "g")],
        str(big),
        "maneuvers.doublet",
        "amplitude_deg",
    )


def test_a_folder_a_running_campaign_holds_is_refused(tmp_path, capsys):
    """run, fly, identify and replay on a folder another command writes: one line, exit 2; the
    first run finishes intact."""
    m = tmp_path / "m.toml"
    m.write_text(matrix_toml([(g, 0, [0.3, 0.5], [2000, 10000]) for g in ("up", "down")]))
    out = tmp_path / "c"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "campaign.cli",
            "run",
            "--matrix",
            str(m),
            "--out",
            str(out),
            "--quiet",
            "--no-identify",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.time() + 60
    while time.time() < deadline and not (out / "manifest.json").exists():
        time.sleep(0.01)
    assert proc.poll() is None, "the run finished before it could be disturbed"
    for argv in (
        ["run", "--matrix", str(m), "--out", str(out), "--no-identify"],
        ["fly", "h02000_m0.30_f00_gup", "--matrix", str(m), "--out", str(out)],
        ["identify", str(out)],
        ["replay", str(out)],
    ):
        one_line_error(capsys, argv, str(out), "another campaign command")
    assert proc.wait(timeout=120) == 0, proc.stderr.read()
    man = json.loads((out / "manifest.json").read_text())
    assert man["complete"] and all(r["status"] == "ok" for r in man["points"])
    assert sorted(f for r in man["points"] for f in r["files"]) == sorted(p.name for p in out.glob("*.parquet"))
    assert not list(out.glob(".*.tmp"))
    assert main(["run", "--matrix", str(m), "--out", str(out), "--no-identify"]) == 0  # free again
