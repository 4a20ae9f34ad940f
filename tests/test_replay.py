"""Replays: cases, three aircraft, open and closed loop, metrics, plots without JSBSim."""

import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from campaign.cli import main
from campaign.errors import UserError
from campaign.replays.replay import DEFAULT_CASES, load_cases, select
from campaign.validation.support import matrix_toml, pairs

MATRIX = matrix_toml(
    pairs((5, 0.3, [2000, 5000, 10000]), (5, 0.4, 5000), (30, 0.2, [2000, 5000]), (30, 0.3, [5000, 10000])),
    "replay-test",
)


@pytest.fixture(scope="module")
def replayed(tmp_path_factory):
    d = tmp_path_factory.mktemp("rp")
    (d / "m.toml").write_text(MATRIX)
    out = d / "c"
    assert main(["run", "--matrix", str(d / "m.toml"), "--out", str(out), "--jobs", "2"]) == 0
    return out


def test_default_cases_file_holds_the_five_cases():
    cases = load_cases()
    assert [c.name.split("-")[0] for c in cases] == ["takeoff", "landing", "takeoff", "landing", "cruise"]
    by = {c.name: c for c in cases}
    assert (by["takeoff-145kt"].ias_kt, by["takeoff-145kt"].flap_deg, by["takeoff-145kt"].gear) == (145, 5, "retract")
    assert (by["landing-135kt"].ias_kt, by["landing-135kt"].flap_deg, by["landing-135kt"].gear) == (135, 30, "extend")
    assert [c.name for c in select(cases, ["takeoff"])] == ["takeoff-145kt", "takeoff-heavy-160kt"]
    with pytest.raises(UserError, match="--case"):
        select(cases, ["taxi"])


@pytest.mark.parametrize(
    "edit, field",
    [
        ("ias_kt = 145", "ias_kt = 0"),
        ("flap_deg = 5", 'flap_deg = "5"'),
        ('gear = "retract"', 'gear = "up"'),
        ("alt_ft = 2000", "alt_fx = 2000"),
    ],
)
def test_bad_cases_file(tmp_path, edit, field):
    p = tmp_path / "cases.toml"
    p.write_text(DEFAULT_CASES.read_text().replace(edit, field, 1))
    with pytest.raises(UserError) as err:
        load_cases(p)
    assert str(p) in str(err.value) and "case[0]" in str(err.value)


def test_replays_meet_part60_and_beat_the_linear_model(replayed):
    df = pd.read_csv(replayed / "replays" / "metrics.csv")
    assert set(df.columns) >= {
        "case",
        "model",
        "loop",
        "max_err_theta_deg",
        "rms_err_theta_deg",
        "max_err_alpha_deg",
        "max_err_q_dps",
        "max_err_tas_kt",
        "max_err_alt_ft",
        "qtg_pass",
    }
    assert len(df) == 5 * 2 * 2  # cases x models x loops
    nl = df[df.model == "nonlinear"]
    assert nl.qtg_pass.all()
    main_cases = df[df.case.isin(["takeoff-145kt", "landing-135kt"])]
    for (case, loop), g in main_cases.groupby(["case", "loop"]):
        lin, non = g[g.model == "linear"].iloc[0], g[g.model == "nonlinear"].iloc[0]
        assert lin.max_err_theta_deg >= 3 * non.max_err_theta_deg, (case, loop)
        assert lin.max_err_alt_ft >= 3 * non.max_err_alt_ft, (case, loop)
    assert (replayed / "replays" / "metrics.txt").read_text().count("nonlinear") == 10
    logs = sorted(p.name for p in (replayed / "replays").glob("*.parquet"))
    assert len(logs) == 5 * 3 * 2 and "landing-135kt__reference__open.parquet" in logs


def test_replay_command_reflies_selected_cases(replayed, capsys):
    before = (replayed / "replays" / "takeoff-145kt__linear__open.parquet").read_bytes()
    assert main(["replay", str(replayed), "--case", "takeoff-145"]) == 0
    out = capsys.readouterr().out
    assert "takeoff-145kt" in out and "landing-135kt" not in out
    assert (replayed / "replays" / "takeoff-145kt__linear__open.parquet").read_bytes() == before  # deterministic


def test_a_run_resumed_on_a_finished_folder_keeps_what_its_inputs_have_not_changed(replayed, tmp_path, capsys):
    """``campaign run`` again on a finished campaign flies nothing, keeps the identification made from
    these logs, and keeps each replay log flown from its case on the aircraft as they are. A log cut
    short is flown again, to the same bytes; the nonlinear model's folder changed (a comment), its
    replays are flown again and the rest stay as they were."""
    import shutil

    from campaign.orchestration.store import read_meta

    c = tmp_path / "c"
    shutil.copytree(replayed, c)  # the copy keeps its identification's stamp: paths are not in it
    rep = c / "replays"
    before = {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in rep.glob("*.parquet")}
    ident = (c / "identification" / "identification.json").stat().st_mtime_ns
    argv = ["run", "--matrix", str(replayed.parent / "m.toml"), "--out", str(c), "--jobs", "2", "--quiet"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "made from these logs already, kept" in out and "30 flights kept" in out, out
    assert {p.name: (p.read_bytes(), p.stat().st_mtime_ns) for p in rep.glob("*.parquet")} == before
    cut = rep / "landing-135kt__reference__open.parquet"
    cut.write_bytes(cut.read_bytes()[:-100])
    xml = next((c / "identification" / "aircraft_nonlinear").glob("*/*.xml"))
    xml.write_text(xml.read_text() + "<!-- edited -->\n")
    assert main(argv) == 0
    assert "19 flights kept" in capsys.readouterr().out
    assert (c / "identification" / "identification.json").stat().st_mtime_ns == ident
    for p in rep.glob("*.parquet"):
        again = p.stat().st_mtime_ns != before[p.name][1]
        assert again == (p == cut or "__nonlinear__" in p.name), p.name
        assert (p.read_bytes() == before[p.name][0]) == ("__nonlinear__" not in p.name), p.name
    assert read_meta(rep / "landing-135kt__nonlinear__open.parquet")["replay_of"]["model"] == "nonlinear"


def test_an_identifications_stamp_follows_the_logs_bytes_the_model_and_the_options_not_the_paths(tmp_path):
    import shutil

    from identify.pipeline import source_stamp

    a = tmp_path / "a"
    a.mkdir()
    (a / "manifest.json").write_text("{}")
    (a / "p__doublet.parquet").write_bytes(b"12345")
    (a / "notes.txt").write_text("not read by the identification")
    stamp = source_stamp(a, None, "paper", "ee")
    shutil.copytree(a, tmp_path / "b")
    assert source_stamp(tmp_path / "b", None, "paper", "ee") == stamp
    (tmp_path / "b" / "notes.txt").write_text("changed")
    assert source_stamp(tmp_path / "b", None, "paper", "ee") == stamp
    (tmp_path / "b" / "p__doublet.parquet").write_bytes(b"12346")
    assert source_stamp(tmp_path / "b", None, "paper", "ee") != stamp
    assert source_stamp(a, None, "all", "ee") != stamp and source_stamp(a, None, "paper", "oe") != stamp
    assert source_stamp(a, a, "paper", "ee") != stamp


def test_open_loop_freezes_controls_and_closed_loop_holds(replayed):
    from campaign.orchestration.store import read_log

    open_, _ = read_log(replayed / "replays" / "landing-135kt__reference__open.parquet")
    closed, _ = read_log(replayed / "replays" / "landing-135kt__reference__closed.parquet")
    assert open_.elevator_deg.nunique() == 1 and open_.throttle_norm.nunique() == 1
    assert open_.gear_norm.iloc[0] == 0 and open_.gear_norm.iloc[-1] == 1
    t_done = open_.t_s[open_.gear_norm >= 1].iloc[0]
    assert open_.t_s.iloc[-1] - t_done >= 15 - 1e-9 and (open_.gear_norm[open_.t_s < 5] == 0).all()
    assert (closed.alt_ft - closed.alt_ft.iloc[0]).abs().max() < 10
    assert (open_.alt_ft - open_.alt_ft.iloc[0]).abs().max() > 20


def test_plots_redraw_from_stored_logs_without_jsbsim(replayed, tmp_path):
    """A stub jsbsim package first on the path makes any import of JSBSim, in the
    command or in its plotting workers, fail: plots must not need it."""
    import os

    stub = tmp_path / "stub" / "jsbsim"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text("raise ImportError('campaign plots must not run JSBSim')\n")
    for png in (replayed / "replays" / "plots").glob("*.png"):
        png.unlink()
    env = {**os.environ, "PYTHONPATH": str(stub.parent)}
    res = subprocess.run(
        [sys.executable, "-m", "campaign.cli", "plots", str(replayed), "--case", "landing", "--jobs", "2"],
        capture_output=True,
        text=True,
        env=env,
    )
    assert res.returncode == 0, res.stderr
    pngs = sorted(p.name for p in (replayed / "replays" / "plots").glob("*.png"))
    assert pngs == [
        "landing-135kt__closed.png",
        "landing-135kt__open.png",
        "landing-heavy-160kt__closed.png",
        "landing-heavy-160kt__open.png",
    ]  # partial name
    check = subprocess.run([sys.executable, "-c", "import jsbsim"], env=env, capture_output=True, text=True)
    assert "must not run JSBSim" in check.stderr  # the stub is really in the way


def test_plots_without_replays_is_a_clear_error(tmp_path, capsys):
    assert main(["plots", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no replay logs" in err and err.count("\n") == 1


def test_a_case_figure_drawn_on_the_reused_axes_equals_a_new_figure(tmp_path):
    """The report draws every case on one emptied figure per process: nothing of the case
    before (lines, bands, legends, limits) may show in the next one's pixels."""
    import matplotlib.pyplot as plt
    import numpy as np

    from campaign.replays.report import CHANNELS, _save_plot, plot_case

    def log(t, scale, gear_at):
        d = {c: scale * np.sin(t * (i + 1) / 7.0) + 100.0 * i for i, (c, _) in enumerate(CHANNELS)}
        return pd.DataFrame({"t_s": t, "gear_norm": (t > gear_at).astype(float), **d})

    t1, t2 = np.arange(0, 30, 0.1), np.arange(0, 12, 0.05)
    big = {
        ("a", m, "open"): log(t1, 40.0 * (1 + k / 10), 5.0) for k, m in enumerate(("reference", "linear", "nonlinear"))
    }
    small = {("b", m, "open"): log(t2, 0.5 * (1 + k / 10), 20.0) for k, m in enumerate(("reference", "nonlinear"))}
    for replays, case in ((big, "a"), (small, "b")):
        _save_plot(replays, case, "open", tmp_path / f"{case}_reused.png")
        fig = plot_case(replays, case, "open")
        fig.savefig(tmp_path / f"{case}_new.png", dpi=100, format="png")
        plt.close(fig)
        assert np.array_equal(plt.imread(tmp_path / f"{case}_reused.png"), plt.imread(tmp_path / f"{case}_new.png"))


@pytest.fixture(scope="module")
def banded(replayed, tmp_path_factory):
    """A copy of the replayed campaign with 20-draw bands on one case (4 draws held back)."""
    import shutil

    from campaign.replays.replay import load_cases, select
    from campaign.replays.bands import replay_bands
    from campaign.replays.report import write_report

    out = tmp_path_factory.mktemp("bands") / "c"
    shutil.copytree(replayed, out)
    doc = replay_bands(out, select(load_cases(), ["landing-135kt"]), 20, jobs=2, held_back=4)
    write_report(out)
    return out, doc


def test_bands_cover_models_drawn_from_the_covariance_and_give_pass_probabilities(banded):
    """Four draws of each identified model, held back from its 20-draw band, fly inside it: the band
    covers a model whose parameters were perturbed within their covariance."""
    out, doc = banded
    assert sorted(doc["cases"]) == [
        f"landing-135kt__{m}__{lp}" for m in ("linear", "nonlinear") for lp in ("closed", "open")
    ]
    for name, e in doc["cases"].items():
        assert e["draws"] == 20 and e["draws_flown"] == 20, name
        assert e["held_back_inside"] >= 0.6, (name, e["held_back_inside"])
        assert 0.0 <= e["pass_probability"] <= 1.0
        assert (out / "replays" / "bands" / f"{name}.parquet").exists()
    nl = doc["cases"]["landing-135kt__nonlinear__open"]["width_max"]
    lin = doc["cases"]["landing-135kt__linear__open"]["width_max"]
    assert 0.0 < nl["theta_deg"] < 1.5 and 0.0 < nl["alt_ft"] < 100.0  # a band, narrower than the tolerance
    assert lin["theta_deg"] > 0.0
    df = pd.read_csv(out / "replays" / "metrics.csv")
    landing = df[df.case == "landing-135kt"]
    assert landing.pass_probability.between(0, 1).all() and (landing.band_draws == 20).all()
    assert df[df.case != "landing-135kt"].pass_probability.isna().all()
    # the nonlinear model meets Part 60 in every draw; the linear one's open loop is far from its band
    assert (landing[landing.model == "nonlinear"].pass_probability == 1.0).all()
    assert "pass_probability" in (out / "replays" / "metrics.txt").read_text()
    from campaign.reports.report import write_report as html_report

    page = Path(html_report(out)).read_text()
    assert page.count("% of 20 draws") == 4 and page.count("not drawn") == 16


def test_bands_are_shaded_in_the_case_plots_and_dropped_when_stale(banded, tmp_path):
    import shutil

    from campaign.replays.report import load_bands, load_replays, plot_case

    src, _ = banded
    out = tmp_path / "c"
    shutil.copytree(src, out)
    summary, frames = load_bands(out)
    replays = load_replays(out, ["landing-135kt"])
    fig = plot_case(
        {k: v for k, v in replays.items() if k[2] == "open"},
        "landing-135kt",
        "open",
        bands={k: v for k, v in frames.items() if k[2] == "open"},
    )
    assert all(len(ax.collections) == 2 for ax in fig.axes[:1])  # a band per identified model
    assert any("95 % band" in t.get_text() for t in fig.axes[0].get_legend().get_texts())
    # re-flying the case without --bands forgets its bands
    assert main(["replay", str(out), "--case", "landing-135kt"]) == 0
    assert load_bands(out) == ({}, {})
    assert pd.read_csv(out / "replays" / "metrics.csv").pass_probability.isna().all()


def test_bands_of_another_identification_are_not_shown(banded, tmp_path):
    import shutil

    from campaign.replays.report import load_bands

    src, _ = banded
    out = tmp_path / "c"
    shutil.copytree(src, out)
    assert load_bands(out)[0]
    f = out / "identification" / "gear_surfaces.json"
    f.write_text(f.read_text().replace('"arm_ft": [', '"arm_ft": [ '))
    assert load_bands(out) == ({}, {})
    from campaign.reports.report import write_report as html_report

    page = Path(html_report(out)).read_text()
    assert "% of 20 draws" not in page and page.count("not drawn") == 20


@pytest.mark.parametrize(
    "args, says",
    [
        (["--bands", "5"], "20 draws or more"),
        (["--bands", "20"], "gear_surfaces.json: missing"),
        (["--bands", "20"], "gear_surfaces.json: does not read"),
    ],
)
def test_bad_bands_request_is_one_line_and_writes_nothing(replayed, tmp_path, capsys, args, says):
    import shutil

    out = tmp_path / "c"
    shutil.copytree(replayed, out)
    surfaces = out / "identification" / "gear_surfaces.json"
    if "missing" in says:
        surfaces.unlink()
    elif "does not read" in says:
        surfaces.write_text(surfaces.read_text()[:1000])
    before = {p: p.read_bytes() for p in (out / "replays").rglob("*") if p.is_file()}
    assert main(["replay", str(out), "--case", "landing-135kt", *args]) == 2
    err = capsys.readouterr().err
    assert says in err and err.count("\n") == 1
    assert {p: p.read_bytes() for p in (out / "replays").rglob("*") if p.is_file()} == before


def test_a_draw_that_does_not_cover_the_whole_time_history_fails_part60():
    """Judged on its finite head only, a draw that diverged or ended early would pass."""
    import numpy as np

    from diagnose.uncertainty import pass_probability

    measured = {c: np.zeros(5) for c in ("tas_kt", "alt_ft", "theta_deg")}
    flown = {c: np.zeros((3, 5)) for c in measured}
    flown["tas_kt"][1, 3] = np.nan  # went non-finite partway
    flown["alt_ft"][2, :] = np.nan  # did not trim
    assert pass_probability(flown, measured) == pytest.approx(1 / 3)
    measured["theta_deg"][0] = np.nan  # a measured gap is not held against the draws
    flown = {c: np.zeros((2, 5)) for c in measured}
    flown["theta_deg"][:, 0] = np.nan
    assert pass_probability(flown, measured) == 1.0
