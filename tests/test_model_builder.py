"""``campaign model``: a whole JSBSim aircraft from an identification of real flight records.

The ATTAS and HFB-320 records (tests/data/) are imported, identified and made into aircraft; each
must load in JSBSim, trim at its record's start and, through the diagnosis's model evaluator, give
back the identification's fitted coefficients (params x regressors) at every logged state. The
blend over conditions and the gear model are checked on point models written by hand.
"""

import json
import shutil
from pathlib import Path

import jsbsim
import numpy as np
import pytest
import scipy.io

import gearaero as ga
from campaign.cli import main
from campaign.modelling.trim import THRUST, trim_model
from campaign.validation.support import one_line_error
from diagnose.evaluate import ModelEvaluator
from identify.aircraft import Airframe, PointModel, aircraft_xml, point_models
from identify.coefficients import qhat
from identify.logs import read_parquet
from identify.models import fit_surface
from infra.model import control_schedules, load_fdm

DATA = Path(__file__).parent / "data"
DOCS = Path(__file__).parents[1] / "docs" / "examples"
N_TO_LBF = 0.224808943


def _built(root: Path, records: list[Path], map_path: Path, name: str, method: str = "ee", api: bool = False):
    """Import ``records``, identify them by ``method`` and make aircraft ``name``; its folder, the log of
    the first record and the point model identified from it."""
    assert main(["import", *map(str, records), "--map", str(map_path), "--out", str(root / "imported")]) == 0
    assert main(["identify", str(root / "imported"), "--plots", "none", "--method", method]) == 0
    ident, out = root / "imported" / "identification", root / "models" / name
    if api:
        result = ga.model(ga.IdentificationResult(ident), out)
        assert result.xml == out / f"{name}.xml" and result.trims == result.to_dict()["trims"]
        text = result.summary()
    else:
        assert main(["model", str(ident), "--out", str(out)]) == 0
        text = (out / "model.json").read_text()
    doc = json.loads((ident / "identification.json").read_text())
    point = point_models(doc, "identification.json")[0]
    return out, read_parquet(root / "imported" / f"{records[0].stem}.parquet"), point, text


def _probe(model: Path) -> Path:
    """A JSBSim root holding a copy of the aircraft folder, for :func:`infra.model.load_fdm`."""
    root = model.parent.parent / "probe"
    shutil.copytree(model, root / "aircraft" / model.name, dirs_exist_ok=True)
    return root


def _jsbsim_mach(model: Path, data) -> np.ndarray:
    """Mach as JSBSim's atmosphere has it at the logged altitude and true airspeed."""
    fdm = load_fdm(_probe(model), model.name)
    out = []
    for h, v in zip(data["alt_ft"], data["tas_kt"]):
        fdm["ic/h-sl-ft"], fdm["ic/vt-kts"] = h, v
        fdm.run_ic()
        out.append(fdm["velocities/mach"])
    return np.array(out)


def _reproduces(model: Path, log, point: PointModel) -> dict[str, float]:
    """Largest |JSBSim's coefficient - params x regressors| over the log, through the model evaluator."""
    ev = ModelEvaluator(model)
    assert ev.unset == []  # every input of the aircraft's lift, drag and moment comes from a log channel
    assert ev.aerorp_in == ev.cg_in  # the identified Cm is about the CG
    d = log.data
    predicted = ev.predict(d)
    mach = _jsbsim_mach(model, d)
    # the importer's ISA reads pressure altitude as geopotential, JSBSim's atmosphere as geometric
    assert np.abs(mach - d["mach"]).max() < 3e-5
    x = point.regressors(d["alpha_deg"], qhat(d, log.meta), d["elevator_deg"], d["stabilizer_deg"], mach)
    ev.close()
    return {c: float(np.abs(predicted[c] - point.fitted(c, x)).max()) for c in ("CL", "CD", "Cm")}


def _trims_and_holds(model: Path, log, pitch: str = "elevator") -> None:
    """The aircraft trims at the record's first second and stays there flying 5 s on its own."""
    d = log.data[log.data["t_s"] < 1.0].mean()
    fdm = load_fdm(_probe(model), model.name)
    t = trim_model(
        fdm,
        d["alt_ft"],
        d["tas_kt"],
        d["theta_deg"] - d["alpha_deg"],
        d["flap_deg"],
        d["gear_norm"],
        d["elevator_deg"],
        d["stabilizer_deg"],
        d["thrust_lbf"],
        d["alpha_deg"],
        d["mass_slug"] * 32.174049,
        pitch,
    )
    assert abs(t.alpha_deg - d["alpha_deg"]) < 0.5 and abs(t.thrust_lbf / d["thrust_lbf"] - 1) < 0.2, t
    assert fdm[THRUST] == t.thrust_lbf
    alpha = []
    for _ in range(600):
        fdm.run()
        alpha.append(fdm["aero/alpha-deg"])
    assert np.ptp(alpha) < 0.01, np.ptp(alpha)


def test_attas_aircraft_trims_and_gives_back_the_fit(tmp_path):
    records = [DATA / "fAttasElv1.mat"]
    model, log, point, text = _built(tmp_path, records, DOCS / "attas-map.toml", "attas")
    raw = scipy.io.loadmat(records[0])["fAttasElv1"]
    # the map's summed thrust columns and the .mat's one array read whatever its name
    assert np.allclose(log.data["thrust_lbf"], (raw[:, 36] + raw[:, 37]) * N_TO_LBF, rtol=1e-9)
    fdm = jsbsim.FGFDMExec(None)
    fdm.set_aircraft_path(str(model.parent))
    assert fdm.load_model("attas")
    # the replays' and the diagnosis's controls move the surfaces the logs record, over their range
    schedules = control_schedules(load_fdm(_probe(model), "attas"), set())
    assert set(schedules) == {"elevator_deg", "stabilizer_deg", "flap_deg", "gear_norm"}
    for ch, s in schedules.items():
        lo, hi = s.range
        assert lo <= log.data[ch].min() and hi >= log.data[ch].max(), ch
    err = _reproduces(model, log, point)
    assert max(err.values()) < 1e-6, err
    _trims_and_holds(model, log)
    doc = json.loads(text)
    assert "nominal" in " ".join(doc["notes"]) and doc["trims"][0]["point"] == "fAttasElv1"
    xml = (model / "attas.xml").read_text()
    for said in (
        "nominal, not identified",
        "equation error",
        "external_reactions/thrust/magnitude",
        "One point model (fAttasElv1) at every condition",
    ):
        assert said in xml, said


def test_a_model_aircraft_trims_in_the_unsteady_flight_a_log_starts_in(tmp_path):
    """Trimmed pitching up at 0.3 deg/s while slowing at 0.5 ft/s^2 (where a record cut from a flight may
    start), the ATTAS aircraft holds that pitch rate with no pitch acceleration and its airspeed changes at that
    rate. Pulling up alone, its load factor is higher by q V / g and it needs more nose-up elevator and more
    thrust (the drag of the lift) than in steady flight there; slowing alone, less thrust by the mass times
    the deceleration along the flight path."""
    model, log, _, _ = _built(tmp_path, [DATA / "fAttasElv1.mat"], DOCS / "attas-map.toml", "attas")
    d = log.data[log.data["t_s"] < 1.0].mean()
    mass = d["mass_slug"]

    def trimmed(**unsteady):
        fdm = load_fdm(_probe(model), model.name)
        args = (d["alt_ft"], d["tas_kt"], d["theta_deg"] - d["alpha_deg"], d["flap_deg"], d["gear_norm"])
        firsts = (d["elevator_deg"], d["stabilizer_deg"], d["thrust_lbf"], d["alpha_deg"], mass * 32.174049)
        return fdm, trim_model(fdm, *args, *firsts, **unsteady)

    fdm0, steady = trimmed()
    fdm, both = trimmed(q_dps=0.3, accel_fps2=-0.5)
    alpha = np.radians(fdm["aero/alpha-deg"])
    along = fdm["accelerations/udot-ft_sec2"] * np.cos(alpha) + fdm["accelerations/wdot-ft_sec2"] * np.sin(alpha)
    assert along == pytest.approx(-0.5, abs=1e-5) and abs(fdm["accelerations/qdot-rad_sec2"]) < 1e-8
    assert fdm["velocities/q-rad_sec"] == pytest.approx(np.radians(0.3), rel=1e-9)
    fdm, pull = trimmed(q_dps=0.3)
    up = np.radians(0.3) * fdm["velocities/vt-fps"] / 32.174049
    assert fdm["accelerations/Nz"] - fdm0["accelerations/Nz"] == pytest.approx(up, rel=0.05)
    assert pull.elevator_deg < steady.elevator_deg  # the elevator deflects trailing edge up to pull up
    assert pull.thrust_lbf > steady.thrust_lbf
    _, slow = trimmed(accel_fps2=-0.5)
    assert steady.thrust_lbf - slow.thrust_lbf == pytest.approx(
        0.5 * mass / np.cos(np.radians(slow.alpha_deg)), rel=0.02
    )


def test_hfb320_aircraft_by_output_error(tmp_path):
    """The HFB-320 identified by output error (converged on this record), made through the Python API."""
    model, log, point, text = _built(
        tmp_path, [DATA / "hfb320_1_10.asc"], DOCS / "hfb320-map.toml", "hfb320", method="oe", api=True
    )
    assert point.methods == {"CL": "oe", "CD": "oe", "Cm": "oe"} and all(point.converged.values())
    assert "output error" in text and "trim at hfb320_1_10's start" in text, text
    err = _reproduces(model, log, point)
    assert max(err.values()) < 1e-6, err
    _trims_and_holds(model, log)


def _point(name: str, mach: float, flap: float, gear_down: bool, k: float) -> PointModel:
    """A point model whose parameters scale with ``k``, all regressors identified."""
    params = {
        c: {
            "const": s * k,
            "dalpha_rad": 5.0 * s,
            "qhat_rad": 10.0 * s,
            "delevator_rad": 0.5 * s * k,
            "dstabilizer_rad": 0.8 * s,
            "dmach": 0.1 * s * k,
            "dalpha2_rad2": 0.3 * s,
        }
        for c, s in (("CL", 1.0), ("CD", 0.1), ("Cm", -0.2))
    }
    return PointModel(
        name,
        (5000.0, mach, flap),
        gear_down,
        {"alpha_deg": 2.0 + k, "elevator_deg": -1.0, "stabilizer_deg": 0.5, "mach": mach},
        params,
        {c: "ee" for c in params},
        {c: True for c in params},
    )


def _coefficients(root: Path, name: str, mach: float, flap_deg: float, gear: float) -> tuple[np.ndarray, dict]:
    """The aircraft's identified CL, CD, Cm at a state, and the state as JSBSim has it (its regressors'
    inputs): alpha 4 deg, a pitch rate, the controls through the flight controls."""
    fdm = load_fdm(root, name)
    fdm["ic/h-sl-ft"], fdm["ic/mach"], fdm["ic/alpha-deg"], fdm["ic/q-rad_sec"] = 5000.0, mach, 4.0, 0.02
    fdm["fcs/elevator-cmd-norm"], fdm["fcs/pitch-trim-cmd-norm"] = -0.1, 0.05
    fdm["fcs/flap-cmd-norm"], fdm["gear/gear-cmd-norm"] = flap_deg / 40.0, gear
    fdm.set_trim_status(True)  # the gear at its command at once
    fdm.run_ic()
    state = {
        "alpha_deg": fdm["aero/alpha-deg"],
        "qhat_rad": fdm["aero/ci2vel"] * fdm["velocities/q-aero-rad_sec"],
        "elevator_deg": fdm["fcs/elevator-pos-deg"],
        "stabilizer_deg": fdm["fcs/stabilizer-pos-deg"],
        "mach": fdm["velocities/mach"],
    }
    assert fdm["fcs/flap-pos-deg"] == pytest.approx(flap_deg) and fdm["gear/gear-pos-norm"] == pytest.approx(gear)
    return np.array([fdm[f"aero/function/{c}-identified"] for c in ("CL", "CD", "Cm")]), {**state, "fdm": fdm}


def _expected(p: PointModel, state: dict, mach: float | None = None) -> np.ndarray:
    x = p.regressors(
        state["alpha_deg"],
        state["qhat_rad"],
        state["elevator_deg"],
        state["stabilizer_deg"],
        state["mach"] if mach is None else mach,
    )
    return np.array([p.fitted(c, x) for c in ("CL", "CD", "Cm")])


GEAR_SURFACE = [
    (
        (5000.0, 0.3, 0.0),
        3.0,
        np.array([0.0, 1.0]),
        {"CL": np.array([0.0, -0.02]), "CD": np.array([0.0, 0.03]), "Cm": np.array([0.0, 0.01])},
    )
]
AIRFRAME = Airframe(
    500.0, 8.0, 60.0, 30000.0, 30000.0, {"ixx": 1e5, "iyy": 2e5, "izz": 3e5, "ixz": 0.0}, (100.0, 0.0), 0.0
)


def _write(tmp_path: Path, name: str, points, surface=None) -> list[str]:
    tree, notes = aircraft_xml(name, points, AIRFRAME, surface, "linear" if surface is not None else None)
    (tmp_path / "aircraft" / name).mkdir(parents=True)
    tree.write(tmp_path / "aircraft" / name / f"{name}.xml")
    return notes


@pytest.mark.parametrize("gear_model", [False, True], ids=["without gear model", "with a gear model"])
def test_point_models_blend_over_mach_flap_and_gear(tmp_path, gear_model):
    a, b, c, d, e = (
        _point("a", 0.3, 0.0, False, 1.0),
        _point("b", 0.5, 0.0, False, 2.0),
        _point("c", 0.3, 0.0, True, 3.0),
        _point("d", 0.3, 10.0, False, 4.0),
        _point("e", 0.3, 10.0, False, 6.0),
    )
    notes = _write(tmp_path, "blend", [a, b, c, d, e], fit_surface(GEAR_SURFACE) if gear_model else None)
    assert any("linear in Mach" in n for n in notes)
    # gear up, Mach 0.4, flap 0: halfway between a and b
    got, s = _coefficients(tmp_path, "blend", 0.4, 0.0, 0.0)
    assert np.allclose(got, (_expected(a, s) + _expected(b, s)) / 2, rtol=0, atol=1e-12)
    # flap 10: the mean of d and e (one condition flown twice); flap 5: halfway between flap 0 and 10
    got, s = _coefficients(tmp_path, "blend", 0.3, 10.0, 0.0)
    assert np.allclose(got, (_expected(d, s) + _expected(e, s)) / 2, rtol=0, atol=1e-12)
    got, s = _coefficients(tmp_path, "blend", 0.3, 5.0, 0.0)
    assert np.allclose(got, (2 * _expected(a, s) + _expected(d, s) + _expected(e, s)) / 4, rtol=0, atol=1e-12)
    got, s = _coefficients(tmp_path, "blend", 0.3, 0.0, 1.0)
    if gear_model:  # gear down: the gear-up model and the gear increment (the gear-down fit went into the gear model)
        fdm = s["fdm"]
        gear = np.array([fdm[f"aero/coefficient/id-linear-d{k}-gear"] for k in ("CL", "CD", "Cm")])
        assert np.allclose(gear / (fdm["aero/qbar-psf"] * 500.0 * np.array([1.0, 1.0, 8.0])), [-0.02, 0.03, 0.01])
        assert np.allclose(got, _expected(a, s), rtol=0, atol=1e-12)
    else:  # gear up and gear down blended linearly in gear position
        assert np.allclose(got, _expected(c, s), rtol=0, atol=1e-12)
        got, s = _coefficients(tmp_path, "blend", 0.3, 0.0, 0.5)
        assert np.allclose(got, (_expected(a, s) + _expected(c, s)) / 2, rtol=0, atol=1e-12)


def test_a_condition_flown_gear_down_only_enters_without_its_gear_increment(tmp_path):
    c = _point("c", 0.3, 0.0, True, 3.0)
    _write(tmp_path, "down", [c], fit_surface(GEAR_SURFACE))
    got, s = _coefficients(tmp_path, "down", 0.3, 0.0, 0.0)
    assert np.allclose(got, _expected(c, s) - [-0.02, 0.03, 0.01], rtol=0, atol=1e-12)


def _identified(tmp_path: Path) -> Path:
    """A genuine identification folder (the ATTAS's first record), to spoil."""
    assert (
        main(
            [
                "import",
                str(DATA / "fAttasElv1.mat"),
                "--map",
                str(DOCS / "attas-map.toml"),
                "--out",
                str(tmp_path / "imp"),
            ]
        )
        == 0
    )
    assert main(["identify", str(tmp_path / "imp"), "--plots", "none"]) == 0
    return tmp_path / "imp" / "identification"


def test_bad_identifications_are_one_line_and_write_nothing(tmp_path, capsys):
    ident = _identified(tmp_path)
    capsys.readouterr()
    out = tmp_path / "models" / "m"
    one_line_error(capsys, ["model", str(tmp_path / "imp"), "--out", str(out)], "imp/identification.json", "missing")
    doc = json.loads((ident / "identification.json").read_text())
    spoilt = {
        "no point fits": ({**doc, "points": {}}, "points: no point fits"),
        "no lift parameters": (
            {**doc, "points": {"fAttasElv1": {k: v for k, v in doc["points"]["fAttasElv1"].items() if k != "CL"}}},
            "points.fAttasElv1.CL.params",
        ),
        "log gone": (
            {**doc, "points": {"gone": {**doc["points"]["fAttasElv1"], "log": "../gone.parquet"}}},
            "points.gone.log",
        ),
    }
    for what, (bad, needle) in spoilt.items():
        (ident / "identification.json").write_text(json.dumps(bad))
        one_line_error(capsys, ["model", str(ident), "--out", str(out)], "identification.json", needle)
        assert not out.exists() and not (out.parent / ".m.partial").exists(), what
    (ident / "identification.json").write_text("{not json")
    one_line_error(capsys, ["model", str(ident), "--out", str(out)], "identification.json", "not valid JSON")
    (ident / "identification.json").write_text(json.dumps(doc))
    one_line_error(capsys, ["model", str(ident), "--out", str(out), "--name", "other"], "--name other")
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("mine")
    one_line_error(capsys, ["model", str(ident), "--out", str(out)], str(out), "will not overwrite")
    assert [f.name for f in out.iterdir()] == ["keep.txt"]
    with pytest.raises(ga.UserError, match="points: no point fits"):
        (ident / "identification.json").write_text(json.dumps({**doc, "points": {}}))
        ga.model(ident, tmp_path / "models" / "n")
