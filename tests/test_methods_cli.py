"""Output error and filter error on the user's path: real records imported with the documented
channel maps and identified through ``campaign identify``, against the published estimates and
independent runs (tests/data/README.md names the records and the published values)."""

import json
from pathlib import Path

import pytest

from campaign.cli import main
from test_estimators import ATTAS_PUBLISHED, HFB_PUBLISHED_FE, HFB_START, OutputError, hfb

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "tests" / "data"
EXAMPLES = ROOT / "docs" / "examples"
#: eq. (3) names of the four derivatives the HFB-320 checks compare, and the package's names for them
HFB_TERMS = {
    ("CL", "dalpha_rad"): "CLalpha",
    ("Cm", "dalpha_rad"): "Cmalpha",
    ("Cm", "qhat_rad"): "Cmqhat",
    ("Cm", "delevator_rad"): "Cmde_rad",
}
#: the dimensional derivatives the CLI reports and the package's short-period parameters
TC11 = {
    "Z_alpha_per_s": "Zalpha",
    "Z_q": "Zq",
    "Z_de_per_s": "Zde",
    "M_alpha_per_s2": "Malpha",
    "M_q_per_s": "Mq",
    "M_de_per_s2": "Mde",
}


def _import(out: Path, *pairs) -> Path:
    for data, mp in pairs:
        assert main(["import", str(DATA / data), "--map", str(EXAMPLES / mp), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def hfb_import(tmp_path_factory):
    return _import(tmp_path_factory.mktemp("hfb") / "hfb", ("hfb320_1_10.asc", "hfb320-map.toml"))


@pytest.fixture(scope="module")
def attas_import(tmp_path_factory):
    return _import(
        tmp_path_factory.mktemp("attas") / "attas",
        ("fAttasElv1.mat", "attas-elv1-map.toml"),
        ("fAttasElv2.mat", "attas-elv2-map.toml"),
    )


def _identify(folder: Path, out: Path, capsys, *options) -> tuple[int, str, dict]:
    capsys.readouterr()
    code = main(["identify", str(folder), "--out", str(out), "--plots", "none", *options])
    text = capsys.readouterr().out
    return code, text, json.loads((out / "identification.json").read_text())


@pytest.fixture(scope="module")
def hfb_fe(hfb_import, tmp_path_factory):
    out = tmp_path_factory.mktemp("fe") / "fe"
    code = main(["identify", str(hfb_import), "--out", str(out), "--plots", "none", "--method", "fe"])
    return code, out, json.loads((out / "identification.json").read_text())


def test_hfb320_filter_error_through_the_cli_lands_on_the_published_estimates(hfb_fe):
    code, out, doc = hfb_fe
    assert code == 0
    assert doc["method"] == "fe" and doc["not_converged"] == [] and doc["converged_points"] == 1
    pt = doc["points"]["hfb320_1_10"]
    assert pt["method"] == "fe" and pt["timedomain"]["converged"]
    for (c, term), name in HFB_TERMS.items():
        assert pt[c]["method"] == "fe"
        assert pt[c]["params"][term] == pytest.approx(HFB_PUBLISHED_FE[name], rel=0.05), (c, term)
    # the structure the record supports, each term left out with its reason: one alpha range too
    # narrow for a curvature, no stabilizer moved, and the elevator's lift not determined
    left = pt["timedomain"]["structure"]["left_out"]
    assert "alpha squared varies" in left["CL dalpha2_rad2"] and "std 0" in left["Cm dstabilizer_rad"]
    assert "disagree" in left["CL delevator_rad"]
    assert "dalpha2_rad2" not in pt["CL"]["params"] and "dalpha2_rad2" in pt["CL"]["unexcited"]
    head = (out / "summary.txt").read_text().split("Per-point fits")[0]
    assert "Method: filter error (fe)" in head and "1 point(s) converged, 0 not" in head


@pytest.fixture(scope="module")
def hfb_oe(hfb_import, tmp_path_factory):
    import io
    from contextlib import redirect_stdout

    out, said = tmp_path_factory.mktemp("oe") / "oe", io.StringIO()
    with redirect_stdout(said):
        code = main(["identify", str(hfb_import), "--out", str(out), "--plots", "none", "--method", "oe"])
    return code, said.getvalue(), json.loads((out / "identification.json").read_text())


def test_hfb320_output_error_through_the_cli_agrees_with_an_independent_run(hfb_oe):
    code, text, doc = hfb_oe
    assert code == 0 and "output error: 1 of 1 point(s) converged" in text
    pt = doc["points"]["hfb320_1_10"]
    assert pt["method"] == "oe"
    # the data set's own model structure and units, fitted by the estimator directly
    model, rec = hfb()
    ref = OutputError(model, [rec], HFB_START).fit()
    assert ref.converged
    for (c, term), name in HFB_TERMS.items():
        assert pt[c]["params"][term] == pytest.approx(ref.params[name], rel=0.10), (c, term)


def test_python_and_the_cli_run_one_estimator(hfb_oe, hfb_import, tmp_path):
    """gearaero.identify on the imported logs in memory and the command line give the same numbers:
    one code path (identify.timedomain through identify.pipeline)."""
    import gearaero

    _, _, doc = hfb_oe
    res = gearaero.identify(gearaero.read_logs(hfb_import), tmp_path / "py", method="oe", plots="none")
    assert res.not_converged == []
    fit = next(iter(res.identification.fits))
    assert fit.timedomain["method"] == "oe" and fit.failure is None
    for c in ("CL", "CD", "Cm"):
        cli = doc["points"]["hfb320_1_10"][c]["params"]
        assert fit.fits[c].params.to_dict() == pytest.approx(cli, rel=1e-9, abs=1e-12), c


def test_attas_output_error_through_the_cli_reproduces_the_published_short_period(attas_import, tmp_path, capsys):
    code, text, doc = _identify(
        attas_import, tmp_path / "sp", capsys, "--method", "oe", "--structure", str(EXAMPLES / "short-period.toml")
    )
    assert code == 0 and "output error: 2 of 2 point(s) converged" in text
    td = doc["points"]["fAttasElv1"]["timedomain"]
    assert td["records"] == ["fAttasElv1", "fAttasElv2"]  # the repeat is fitted together
    assert td["structure"]["states"] == ["alpha_deg", "q_dps"]
    for ours, theirs in TC11.items():
        assert td["derivatives"][ours] == pytest.approx(ATTAS_PUBLISHED[theirs], rel=0.02), ours
    # no drag in the short period: CD keeps the equation error's estimates, labelled so
    pt = doc["points"]["fAttasElv2"]
    assert pt["CD"]["method"] == "ee" and pt["Cm"]["method"] == "oe"


def test_attas_default_structure_converges(attas_import, tmp_path, capsys):
    code, text, doc = _identify(attas_import, tmp_path / "oe", capsys, "--method", "oe")
    assert code == 0 and "output error: 2 of 2 point(s) converged" in text
    td = doc["points"]["fAttasElv1"]["timedomain"]
    assert td["converged"] and td["structure"]["states"] == ["tas_kt", "alpha_deg", "theta_deg", "q_dps"]


def test_a_fit_that_does_not_converge_says_so_and_the_exit_code_too(hfb_import, tmp_path, capsys):
    code, text, doc = _identify(hfb_import, tmp_path / "one", capsys, "--method", "oe", "--max-iterations", "1")
    assert code == 1  # no point converged
    assert "NOT CONVERGED hfb320_1_10: output error: iteration limit (1) reached" in text
    assert "no point converged by output error" in text
    assert doc["method"] == "oe" and doc["converged_points"] == 0
    assert [d["point"] for d in doc["not_converged"]] == ["hfb320_1_10"]
    assert doc["not_converged"][0]["method"] == "oe" and "iteration limit (1)" in doc["not_converged"][0]["reason"]
    pt = doc["points"]["hfb320_1_10"]
    # the numbers are the equation error's, and say so
    assert pt["method"] == "ee" and pt["not_converged"]["method"] == "oe"
    assert {pt[c]["method"] for c in ("CL", "CD", "Cm")} == {"ee"}
    text = (tmp_path / "one" / "summary.txt").read_text()
    head, points = text.split("Per-point fits")
    assert "NOT CONVERGED: 1 point(s)" in head and "hfb320_1_10: output error: iteration limit (1)" in head
    assert "NOT CONVERGED by output error" in points


@pytest.mark.parametrize(
    "body, needle",
    [
        ("states = ['alpha_deg']\n[terms]\nCm = ['const']\n", "states:"),
        ("[terms]\nCL = ['const', 'dbeta_rad']\n", "terms.CL: 'dbeta_rad' is not one of"),
        ("inputs = ['thrust_lbf']\n[terms]\nCm = ['const', 'delevator_rad']\n", "needs the input 'elevator_deg'"),
        ("states = ['alpha_deg', 'q_dps']\n[terms]\nCD = ['const']\n", "terms.CD: the short-period model has no drag"),
        ("colour = 1\n", "colour: unknown key"),
        ("[terms\n", "not valid TOML"),
    ],
)
def test_bad_structure_files_are_one_line(hfb_import, tmp_path, capsys, body, needle):
    path = tmp_path / "s.toml"
    path.write_text(body)
    out = tmp_path / "never"
    assert main(["identify", str(hfb_import), "--out", str(out), "--method", "oe", "--structure", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and needle in err, err
    assert not out.exists()


def test_time_domain_options_are_refused_with_equation_error(hfb_import, tmp_path, capsys):
    assert main(["identify", str(hfb_import), "--out", str(tmp_path / "x"), "--max-iterations", "3"]) == 2
    assert "--max-iterations: applies to the time-domain methods" in capsys.readouterr().err
    assert (
        main(["identify", str(hfb_import), "--out", str(tmp_path / "x"), "--method", "oe", "--max-iterations", "0"])
        == 2
    )
    assert "--max-iterations" in capsys.readouterr().err


def test_worker_processes_fit_as_this_process_does(hfb_oe, tmp_path):
    """Two status points on two workers: each fitted as a single point is in this process, the
    default structure's decisions included (a structure crosses to a worker as a copy)."""
    import shutil

    from identify.logs import read_campaign
    from identify.pipeline import identify_logs

    shutil.copy(DATA / "hfb320_1_10.asc", tmp_path / "hfb_higher.asc")
    higher = tmp_path / "higher-map.toml"
    higher.write_text((EXAMPLES / "hfb320-map.toml").read_text().replace('alt_ft = "4300 m"', 'alt_ft = "4500 m"'))
    folder = _import(tmp_path / "two", ("hfb320_1_10.asc", "hfb320-map.toml"))
    assert main(["import", str(tmp_path / "hfb_higher.asc"), "--map", str(higher), "--out", str(folder)]) == 0
    # the single record had no data compatibility (one log): neither have these two copies of it
    ident = identify_logs(read_campaign(folder), compatibility=False, jobs=2, method="oe")
    fits = {f.point: f for f in ident.fits}
    assert set(fits) == {"hfb320_1_10", "hfb_higher"} and ident.converged == 2
    for f in fits.values():
        assert f.timedomain["records"] == [f.point]
        assert "disagree" in f.timedomain["structure"]["left_out"]["CL delevator_rad"]
    one = hfb_oe[2]["points"]["hfb320_1_10"]
    for c in ("CL", "CD", "Cm"):
        assert fits["hfb320_1_10"].fits[c].params.to_dict() == pytest.approx(one[c]["params"], rel=1e-9, abs=1e-12)
