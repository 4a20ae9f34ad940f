"""Hidden effects in the data: the diagnosis must find them from the logs alone.

The overlays are generated here at random (fixed seeds) and flown through the
shipped flight-test instruments (turbulence, 50 Hz, no qdot, nose-boom vanes,
noise); the diagnosis sees only the logs and the bare model. Sensor faults are
injected through instrument profiles and must be named as sensor faults, with
their size. Only these tests read the overlay or the profile, to score the answer.
"""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from campaign.cli import main
from campaign.validation.hidden import CASES, make, make_sensor, score, score_sensor

#: (family, coefficient, seed): each family once, and each coefficient in a gear family (the random
#: shapes of tests/test_verdict.py and the detection curve's hundreds cover the rest)


@pytest.mark.parametrize("family, coeff, seed", CASES, ids=[f"{f}-{c or 'any'}" for f, c, _ in CASES])
def test_hidden_effect_is_found_shaped_and_worth_it(tmp_path, family, coeff, seed):
    hidden = make(family, np.random.default_rng(seed), coeff)
    r = score(tmp_path, hidden, seed=seed)
    first = r["doc"]["causes"][0] if r["doc"]["causes"] else None
    assert r["discrepancy"], hidden.description
    assert r["coefficient_ok"] and r["variable_ok"], (hidden.description, first)
    assert r["shape_error"] < 0.10, (hidden.description, r["shape_error"])
    assert r["gain"] >= 2.0, (hidden.description, r["gain"])
    # the replays in the measured wind show the gain where the cause moves them most; a drag at one
    # Mach, flown at the measured thrust, drifts the altitude and the airspeed. An elevator derivative
    # moves the replays by a fifth of a tolerance, less than the wind errors: the truth itself
    # replays x1.07 better (benchmarks/replay_gain.py), so no x2 is there to show. x2 is asked of a
    # cause 20 times its floor: 10 times the floor as it was until the floor of a noisy variable was
    # no longer doubled (a CL step in alpha 16.6 times its floor now, 8.3 before, replays x1.93).
    g = r["doc"]["gain"]
    most = g["replay_moved_most"]
    if family == "mach":
        assert most in ("alt_ft", "tas_kt"), g["replay_moved"]
    if first["verdict"]["size_over_floor"] >= 20 and family != "elevator_derivative":
        assert g["replay_where_acts"][most]["gain"] >= 2.0, (most, g["replay_where_acts"])


SENSOR_CASES = [
    ("alpha_bias", 0.4, None),
    ("alpha_scale", 0.06, None),
    ("alpha_delay", 0.06, None),
    ("accel_bias", 0.06, "ax_fps2"),
    ("accel_bias", 0.15, "az_fps2"),
    ("thrust_scale", -0.05, None),
]


#: The vane bias alone is left to the tests that name it beside a drag (below), refine it from 2.6 standard errors
#: (our 737, 0.40 deg) and tell it from a drag in alpha (the A320, tests/test_verdict.py); each case keeps its seed.
FLOWN_SENSOR_CASES = [c for c in SENSOR_CASES if c[0] != "alpha_bias"]


@pytest.mark.parametrize(
    "family, value, channel", FLOWN_SENSOR_CASES, ids=[f"{f}-{c or v}" for f, v, c in FLOWN_SENSOR_CASES]
)
def test_sensor_fault_is_named_as_a_sensor_fault_with_its_size(tmp_path, family, value, channel):
    """No aerodynamic cause may be invented for it; the estimate holds the injected error within
    2 standard errors or 10 %. A vane's time shift is measurable in calm air only (see the next test)."""
    fault = make_sensor(family, np.random.default_rng(0), value, channel)
    fault.still_air = family == "alpha_delay"
    r = score_sensor(tmp_path, fault, seed=2000 + SENSOR_CASES.index((family, value, channel)))
    assert r["sensor_first"], (fault.description, [c.get("channel") or c["coefficient"] for c in r["doc"]["causes"]])
    assert r["within"], (fault.description, r["estimate"], r["se"])
    assert not r["aero_named"] and not r["other_sensors"], (fault.description, r["aero_named"], r["other_sensors"])
    cause = r["doc"]["causes"][0]
    assert cause["kind"] == "sensor" and {"channel", "error", "estimate", "se"} <= set(cause)


def test_a_vane_delay_in_turbulence_is_timed_by_the_aerodynamic_residuals(tmp_path):
    """In turbulence the kinematics cannot time the vane (they say so); the model's own answer to a
    late alpha, fitted to the residuals, times it, and no rate derivative is invented for it."""
    fault = make_sensor("alpha_delay", np.random.default_rng(0), 0.06)
    r = score_sensor(tmp_path, fault, seed=2200)
    comp = {p["channel"] + "." + p["error"]: p for p in r["doc"]["data_compatibility"]["parameters"]}
    delay = comp["alpha_deg.delay"]
    assert "turbulence" in delay["reason"] and delay["chosen_because"].startswith("timed by the aerodynamic")
    assert set(delay["methods"]) == {"residuals"}
    assert r["sensor_first"] and r["within"], (r.get("estimate"), r.get("se"))
    assert not r["aero_named"] and not r["other_sensors"], (r["aero_named"], r["other_sensors"])


def test_a_vane_scale_the_kinematics_leave_undecided_is_refined_by_the_residuals(tmp_path):
    """In turbulence the kinematics put a 4 % vane scale at about 3 standard errors, too few to
    correct on their word alone; the model's residuals call for the same scale, within the
    kinematics' error of their estimate: the vane is corrected, no aero cause named. (The kinematics
    put it at 3.6 % +- 0.6 %, not applied on their word alone; the residuals take it nearer the
    truth.)"""
    fault = make_sensor("alpha_scale", np.random.default_rng(0), 0.04)
    r = score_sensor(tmp_path, fault, seed=91_003)
    comp = {p["channel"] + "." + p["error"]: p for p in r["doc"]["data_compatibility"]["parameters"]}
    scale = comp["alpha_deg.scale"]
    assert set(scale["methods"]) == {"kinematics", "residuals"}, scale
    assert abs(scale["estimate"] - 0.04) < abs(scale["methods"]["kinematics"]["estimate"] - 0.04), scale
    assert scale["applied"] and scale["chosen_because"].startswith("the residuals of CL, CD"), scale
    assert r["sensor_first"] and r["within"], (r.get("estimate"), r.get("se"))
    assert not r["aero_named"] and not r["other_sensors"], (r["aero_named"], r["other_sensors"])


def test_a_vane_bias_the_kinematics_measure_short_is_refined_from_2_6_standard_errors(tmp_path):
    """Our 737 through a vane reading 0.40 deg high in 3 ft/s turbulence (null 4,500,069 of the
    detection curve). The kinematics measure 0.33 +- 0.08 deg; the CL and CD residuals need more, within
    3.5 standard errors (the 99th percentile of the kinematics' own errors on simulated flights) of the
    kinematics' estimate, so the bias is refined to what the residuals need, nearer the truth."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.validation.hidden import DIAG_MATRIX, diagnose_overlay, discrepancies

    doc = diagnose_overlay(
        tmp_path,
        None,
        DEFAULT_AIRCRAFT,
        DIAG_MATRIX,
        4500069,
        channels="[channels.alpha_deg]\nbias = 0.40241062049587184\n",
    )
    assert not discrepancies(doc), doc["summary"]
    comp = {p["channel"] + "." + p["error"]: p for p in doc["data_compatibility"]["parameters"]}
    bias = comp["alpha_deg.bias"]
    assert bias["applied"] and set(bias["methods"]) == {"kinematics", "residuals"}, bias
    assert abs(bias["estimate"] - 0.402) < 2 * bias["se"], bias
    assert abs(bias["estimate"] - 0.402) < abs(bias["methods"]["kinematics"]["estimate"] - 0.402), bias


def test_sensor_fault_and_aero_effect_are_both_named(tmp_path):
    fault = make_sensor("alpha_bias", np.random.default_rng(0), 0.4)
    hidden = make("gear_saturating", np.random.default_rng(7), "CD")
    r = score_sensor(tmp_path, fault, seed=2100, hidden=hidden)
    assert r["sensor_ok"] and r["within"], (r.get("estimate"), r.get("se"))
    assert len(r["aero_named"]) == 1 and r["coefficient_ok"] and r["variable_ok"], r["aero_named"]
    assert r["shape_error"] < 0.10 and r["gain"] >= 2.0, (r["shape_error"], r["gain"])
    kinds = {c["kind"] for c in r["doc"]["causes"]}
    assert kinds == {"sensor", "aero"}
    aero = next(c for c in r["doc"]["causes"] if c["kind"] == "aero")
    assert {"coefficient", "variables"} <= set(aero) and "channel" not in aero


def test_an_accelerometer_bias_beside_a_drag_rise_is_named_with_it(tmp_path):
    """The kinematics measure the x-accelerometer's bias precisely but cannot tell it from a pitch
    attitude bias; a drag rise with Mach in the same residual hides the correction's gain in the
    raw residual (the held-out RMS even grows), not beside the aero terms fitted to each version. The
    drag is measured along the airspeed, with the sideslip's share: without it the sideslip's drag
    hides the bias's gain on this realization."""
    rng = np.random.default_rng(95_003)
    fault = make_sensor("accel_bias", rng)
    hidden = make("mach", rng)
    assert fault.channel == "ax_fps2" and hidden.coefficient == "CD"
    r = score_sensor(tmp_path, fault, seed=96_003, hidden=hidden)
    assert r["sensor_ok"] and r["within"], (r.get("estimate"), r.get("se"), r["doc"]["rejected"][:1])
    assert r["coefficient_ok"] and r["variable_ok"], r["aero_named"]
    comp = {p["channel"] + "." + p["error"]: p for p in r["doc"]["data_compatibility"]["parameters"]}
    assert "beside aero terms" in comp["ax_fps2.bias"]["chosen_because"]


@pytest.mark.parametrize("seed", [21, 22])
def test_noise_alone_is_no_discrepancy(tmp_path, seed):
    r = score(tmp_path, None, seed=seed)
    assert not r["discrepancy"], r["doc"]["causes"]
    assert r["doc"]["extension"] is None


def test_diagnose_cli_writes_report_json_extension_and_plots(tmp_path, capsys):
    from campaign.validation.hidden import fly_data

    hidden = make("gear_bump", np.random.default_rng(5), "CD")
    data, _ = fly_data(tmp_path / "w", hidden, seed=5)
    out = tmp_path / "report"
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    assert main(["diagnose", "--data", str(data), "--model", str(DEFAULT_AIRCRAFT), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1. CD vs gear_norm" in text
    doc0 = json.loads((out / "diagnosis.json").read_text())
    for i, cause in enumerate(doc0["causes"], 1):  # every cause is in the report
        assert f"{i}. {cause['coefficient']} vs" in text
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["discrepancy"] is True
    c = doc["causes"][0]
    assert set(c) >= {"coefficient", "variables", "shape", "evidence", "peak"}
    assert c["evidence"]["p_value"] < 1e-6 and c["evidence"]["F"] > 10
    assert "hardly_separated_from" in c["evidence"]
    assert (out / "extended_aircraft" / "737" / "737.xml").exists() and doc["extension"].endswith("737")
    assert doc["gain"]["residual_gain"] >= 3 and "replay_max_error" in doc["gain"]
    for name in ("diagnosis.txt", "extension.xml", "plots/residuals_vs_cause.png"):
        assert (out / name).stat().st_size > 0
    assert list((out / "plots").glob("response_*.png"))
    # by default, plots of the held-out manoeuvres where the first cause acts, and only those
    plotted = sorted(Path(p).stem for p in doc["plotted_logs"])
    assert plotted == sorted(Path(p).stem for p in doc["gain"]["cause_exercised_in"])
    assert sorted(p.stem[len("response_") :] for p in (out / "plots").glob("response_*.png")) == plotted
    assert (
        sorted(
            p.stem[len("residuals_") :]
            for p in (out / "plots").glob("residuals_*.png")
            if p.stem != "residuals_vs_cause"
        )
        == plotted
    )
    # two workers (residuals, noise floor, replays and plots spread out) give the same diagnosis
    out2 = tmp_path / "report2"
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(data),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(out2),
                "--jobs",
                "2",
                "--quiet",
                "--plots",
                "all",
            ]
        )
        == 0
    )
    doc2 = json.loads((out2 / "diagnosis.json").read_text())
    _same(doc, doc2, "", skip={"path", "model", "extension", "extension_xml", "summary", "plotted_logs"})
    # --plots all: every held-out manoeuvre
    assert {p.name for p in (out / "plots").iterdir()} <= {p.name for p in (out2 / "plots").iterdir()}
    assert len(list((out2 / "plots").glob("response_*.png"))) == len(doc["gain"]["held_out_logs"])
    # the report is never written over
    capsys.readouterr()
    assert main(["diagnose", "--data", str(data), "--model", doc["model"], "--out", str(out)]) == 2
    assert "will not overwrite" in capsys.readouterr().err


def _same(a, b, where: str, skip=()) -> None:
    """Equal structure and text, numbers to 1e-6 relative (worker processes evaluate in another order)."""
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for k in a:
            if k not in skip:
                _same(a[k], b[k], f"{where}/{k}", skip)
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]", skip)
    elif isinstance(a, float) and isinstance(b, float):
        assert a == pytest.approx(b, rel=1e-6, abs=1e-12, nan_ok=True), where
    else:
        assert a == b, where


def test_diagnose_bad_inputs(tmp_path, capsys):
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.validation.hidden import fly_data

    data, _ = fly_data(tmp_path / "w", None, seed=3)
    # a CSV log with a bad value: file, column and row named
    from identify.logs import read_parquet

    log = read_parquet(min(data.glob("*.parquet")))
    csv_dir = tmp_path / "csv"
    csv_dir.mkdir()
    bad = log.data.astype({"qbar_psf": object})
    bad.loc[41, "qbar_psf"] = "n/a"
    bad.to_csv(csv_dir / "flight1.csv", index=False)
    (csv_dir / "flight1.json").write_text(json.dumps(log.meta))
    assert (
        main(["diagnose", "--data", str(csv_dir), "--model", str(DEFAULT_AIRCRAFT), "--out", str(tmp_path / "o1")]) == 2
    )
    err = capsys.readouterr().err
    assert "flight1.csv" in err and "'qbar_psf'" in err and "row 42" in err and err.count("\n") == 1
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(tmp_path / "missing"),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(tmp_path / "o2"),
            ]
        )
        == 2
    )
    assert (
        main(["diagnose", "--data", str(data), "--model", str(tmp_path / "nomodel"), "--out", str(tmp_path / "o3")])
        == 2
    )
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o3").exists()
    capsys.readouterr()
    one = min(data.glob("*.parquet"))  # one log: one flight condition, none to hold out
    assert main(["diagnose", "--data", str(one), "--model", str(DEFAULT_AIRCRAFT), "--out", str(tmp_path / "o4")]) == 2
    err = capsys.readouterr().err
    assert str(one) in err and "found 1 log(s) at 1 condition(s) (" in err and err.count("\n") == 1
    assert not (tmp_path / "o4").exists()


def test_replaying_a_log_on_its_own_aircraft_reproduces_it(tmp_path):
    """Same start, same recorded inputs, same aircraft: the flight comes back."""
    from campaign.diagnosis.run import replay
    from campaign.simulation.aircraft import (
        DEFAULT_AIRCRAFT,
        DEFAULT_EFFECTS,
        AircraftSource,
        load_effects,
    )
    from campaign.simulation.engine import FlightConfig, fly
    from campaign.simulation.matrix import load_matrix
    from identify.logs import Log

    m = load_matrix()
    src = AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(DEFAULT_EFFECTS))
    for man in ("gear_extension", "doublet"):
        f = fly(
            m.point("h10000_m0.30_f00_gdn"),
            man,
            FlightConfig(src, maneuver_params=m.maneuver_params, clmax_by_flap=m.clmax_by_flap),
        )
        again = replay(Log("x", f.log, f.meta), src)
        assert (again.gear_norm.to_numpy() == f.log.gear_norm.to_numpy()).all()
        assert np.max(np.abs(again.theta_deg - f.log.theta_deg)) < 0.01, man
        assert np.max(np.abs(again.alt_ft - f.log.alt_ft)) < 0.5, man


def test_a_50hz_recording_replays_over_its_whole_length(tmp_path):
    """A log recorded at 50 Hz (the flight-test profile, here in still air) is replayed over its
    own 28 s at the simulation's 120 Hz, not compressed into 1400 steps (11.7 s), and follows the
    data on its own aircraft within the instruments' errors."""
    from campaign.diagnosis.run import replay
    from campaign.simulation.aircraft import (
        DEFAULT_AIRCRAFT,
        AircraftSource,
        load_effects,
    )
    from campaign.simulation.engine import FlightConfig, fly
    from campaign.simulation.matrix import load_matrix
    from diagnose.gain import replay_errors
    from identify.logs import Log

    still = tmp_path / "still.toml"
    still.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 0.0\n')
    m = load_matrix()
    src = AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(None))
    f = fly(
        m.point("h10000_m0.30_f00_gup"), "doublet", FlightConfig(src, 3, str(still), m.maneuver_params, m.clmax_by_flap)
    )
    assert np.median(np.diff(f.log.t_s)) == pytest.approx(0.02)
    again = replay(Log("x", f.log, f.meta), src)
    assert again.t_s.iloc[-1] == pytest.approx(f.log.t_s.iloc[-1], abs=0.01)
    err = replay_errors(f.log, again)
    assert err["theta_deg"] < 0.5 and err["alt_ft"] < 30.0, err


def test_hat_basis_is_np_interp_of_each_knot_to_the_bit():
    """The smooth terms' piecewise-linear basis, built in one pass, against its definition (np.interp
    of each knot's indicator) on uneven knots, at the knots, outside them and at NaN."""
    from diagnose.terms import hats

    rng = np.random.default_rng(1)
    for _ in range(50):
        knots = tuple(np.sort(rng.choice(np.linspace(-5.0, 5.0, 1001), rng.integers(3, 12), replace=False)))
        x = np.r_[rng.uniform(knots[0] - 1.0, knots[-1] + 1.0, 3000), knots, np.nan]
        want = np.column_stack([np.interp(x, knots, np.eye(len(knots))[j]) for j in range(1, len(knots))])
        assert np.array_equal(hats(x, knots), want, equal_nan=True)


def test_a_smooth_term_resolves_any_shape_of_the_grammar_wherever_the_data_are():
    """Alpha as a matrix flies it: seven conditions trimmed between 0 and 3 deg, two slow ones at 8 and
    12, a doublet's swing in each. Knots at the quintiles, thinned, were -1.2, 0.65, 2.45, 7.4 and 13 deg:
    one interval across a third of the range, and a tenth of the grammar's shapes in alpha left more than
    a quarter of themselves unfitted (an A320 drag step in alpha, 12 times its floor, was named "CD vs CL"
    at seed 5,300,054). Every shape of the grammar is fitted to within 8 % at the 90th
    percentile, and the knots stay 10 % of the range apart."""
    import pandas as pd

    from campaign.validation.shapes import SHAPES, shape
    from diagnose.config import DEFAULTS
    from diagnose.terms import candidate_terms

    rng = np.random.default_rng(0)
    trims = [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 8.0, 12.0]
    alpha = np.concatenate([t + 1.2 * np.sin(np.linspace(0, 6 * np.pi, 600)) * rng.uniform(0.3, 1, 600) for t in trims])
    frame = pd.DataFrame({"alpha_deg": alpha})
    (smooth,) = [t for t in candidate_terms(frame) if t.label == "smooth(alpha_deg)"]
    assert np.diff(smooth.knots).min() >= DEFAULTS.min_knot_spacing * np.ptp(alpha) - 1e-9
    x = np.column_stack([np.ones(len(alpha)), smooth.design(frame)])
    left = []
    for i in range(180):
        y = shape(SHAPES[i % len(SHAPES)], np.clip((alpha - 1.0) / 9.0, 0, 1), rng)[0]
        y = y - y.mean()
        if y.std() > 1e-9:
            beta = np.linalg.lstsq(x, y, rcond=None)[0]
            left.append(np.sum((y - x @ beta) ** 2) / np.sum(y**2))
    assert np.quantile(left, 0.9) < 0.08, (smooth.knots, np.quantile(left, 0.9))


def _elevator_as_the_a320_flies_it(rng: np.random.Generator) -> np.ndarray:
    """Eleven conditions trimmed between -25 and -4 deg of elevator, a 2-3-1-1 of 2.4 deg in each through
    a rate-limited actuator, 0.03 deg of noise [deg]."""
    unit = np.r_[np.zeros(100), np.ones(180), -np.ones(120), np.ones(60), -np.ones(60), np.zeros(880)]
    swing = np.convolve(unit, np.ones(12) / 12, mode="same")
    trims = [-25.0, -23.0, -21.5, -19.0, -18.0, -17.5, -13.0, -12.0, -11.0, -4.8, -4.2]
    return np.concatenate([t + 2.4 * swing + 0.03 * rng.standard_normal(len(swing)) for t in trims])


def test_a_smooth_term_refined_with_the_tails_knots_resolves_a_shape_only_the_tail_reaches():
    """Elevator as the A320 flies it: eleven conditions trimmed between -25 and -4 deg, a 2-3-1-1 of
    2.4 deg in each through a rate-limited actuator. The grammar's shapes on -3 to 3 deg (our 737's
    range) act where only the two fastest conditions' upswings go, 3 % of the samples. On the quantile
    knots the tail above -4.8 deg is one interval, and the 90th percentile of the shapes leaves 47 % of
    itself unfitted (an A320 drag step there, 18 times its floor and 50 times the noise in those samples,
    was not named at seed 5,500,060); the term's twin with the tails' knots, under 8 %. The
    twin keeps the quantile knots and stays 2 % of the range apart."""
    import pandas as pd

    from campaign.validation.shapes import SHAPES, shape
    from diagnose.config import DEFAULTS
    from diagnose.terms import candidate_terms, tail_twin

    rng = np.random.default_rng(0)
    elev = _elevator_as_the_a320_flies_it(rng)
    frame = pd.DataFrame({"elevator_deg": elev})
    (smooth,) = [t for t in candidate_terms(frame) if t.label == "smooth(elevator_deg)"]
    twin = tail_twin(smooth, frame)
    assert twin.label == smooth.label and set(smooth.knots) < set(twin.knots)
    assert np.diff(twin.knots).min() >= DEFAULTS.tail_spacing * np.ptp(elev) - 1e-9
    left = {}
    for term in (smooth, twin):
        x = np.column_stack([np.ones(len(elev)), term.design(frame)])
        draws = np.random.default_rng(1)
        left[term] = []
        for i in range(180):
            y = shape(SHAPES[i % len(SHAPES)], np.clip((elev + 3.0) / 6.0, 0, 1), draws)[0]
            y = y - y.mean()
            if y.std() > 1e-9:
                beta = np.linalg.lstsq(x, y, rcond=None)[0]
                left[term].append(np.sum((y - x @ beta) ** 2) / np.sum(y**2))
    assert len(left[twin]) > 100
    assert np.quantile(left[smooth], 0.9) > 0.3
    assert np.quantile(left[twin], 0.9) < 0.08, (twin.knots, np.quantile(left[twin], 0.9))


def test_the_stepwise_search_refines_a_smooth_term_with_the_tails_knots_only_if_they_fit_better():
    """A residual that is the elevator shape above (a hinge at -3 deg) plus noise: smooth(elevator) is
    chosen and refined to its twin. A wave over the whole range, which the quantile knots follow, keeps
    them."""
    import pandas as pd

    from diagnose.stepwise import stepwise
    from diagnose.terms import candidate_terms, tail_twin

    rng = np.random.default_rng(2)
    elev = _elevator_as_the_a320_flies_it(rng)
    log = np.repeat(np.arange(11), len(elev) // 11)
    noise = 3e-4 * rng.standard_normal(len(elev))
    wave = 3e-3 * np.sin(2 * np.pi * (elev + 25.0) / 24.0)
    for y, refined in ((-0.02 * np.clip((elev + 3.0) / 2.0, 0, 1) + noise, True), (wave + noise, False)):
        frame = pd.DataFrame({"elevator_deg": elev, "log": log, "r_CD": y})
        terms = [t for t in candidate_terms(frame, "CD") if t.variables == ("elevator_deg",)]
        (smooth,) = [t for t in terms if t.kind == "smooth"]
        res = stepwise(frame, "CD", terms)
        assert [tail_twin(smooth, frame) if refined else smooth] == res.terms, [t.knots for t in res.terms]


@pytest.mark.parametrize("seed", [0, 3])
def test_the_stepwise_search_puts_first_of_terms_as_wide_the_one_that_leaves_least(seed):
    """A drag in gear x Mach beside a slow error (a thrust error, the gusts' low frequencies) in twelve logs
    at three Mach numbers, gear up and down, the lift swinging with a manoeuvre. Gear x CL fits it from the
    trimmed lift, which falls with Mach, and leaves the swing's misfit, fast and white; gear x Mach leaves
    the slow error, of few independent samples. On each term's own effective sample size gear x CL came
    first (by 10^40 and 10^3 at these seeds), though it leaves four to seven times the residual with as
    many columns (seed 9,400,050: gear x CL and smooth(Mach) named for a gear x Mach 29 times its
    floor). Of terms as wide, the better fit comes first, and enters on its own test."""
    import pandas as pd
    from scipy.signal import lfilter

    from diagnose.stepwise import stepwise
    from diagnose.terms import candidate_terms

    rng = np.random.default_rng(seed)
    frames, n = [], 600
    for i, (mach, gear) in enumerate([(m, g) for m in (0.3, 0.4, 0.5) for g in (0.0, 1.0)] * 2):
        t = np.arange(n) / 60.0
        cl = 0.5 * (0.3 / mach) ** 2 + 0.06 * np.sin(2 * np.pi * 0.4 * t) + rng.normal(0, 0.003, n)
        slow = lfilter([1.0], [1.0, -0.995], rng.normal(0, 4e-5, n))
        frames.append(
            pd.DataFrame(
                {
                    "log": i,
                    "gear_norm": gear,
                    "mach": mach + rng.normal(0, 0.001, n),
                    "CL": cl,
                    "r_CD": 0.01 * gear * (mach - 0.2) / 0.3 + slow + rng.normal(0, 1e-4, n),
                }
            )
        )
    frame = pd.concat(frames, ignore_index=True)
    res = stepwise(frame, "CD", candidate_terms(frame, "CD"))
    first = {a["term"]: a for a in res.alternatives}
    right, wrong = first["gear_norm x mach"], first["gear_norm x CL"]
    assert wrong["p_value"] < 1e-3 * right["p_value"]  # what ranked it first on its own test
    assert right["rss_reduction_pct"] > wrong["rss_reduction_pct"] + 2.0
    assert res.alternatives[0]["term"] == "gear_norm x mach"
    assert [t.label for t in res.terms] == ["gear_norm x mach"]
    # with one term (later steps here took gear x CL back out; in 9,400,050 they named it)
    assert [t.label for t in stepwise(frame, "CD", candidate_terms(frame, "CD"), max_terms=1).terms] == [
        "gear_norm x mach"
    ]


def test_the_f_distribution_tail_is_exact_where_scipy_underflows():
    """F(2, d) and F(4, d) have closed-form tails, (1 + 2f/d)^(-d/2) and x^a (1 + a(1 - x)) with a = d/2,
    x = d / (d + 4f); for any width the tail is the prefactor times the hypergeometric series
    2F1(a + b, 1; a + 1; x), b = width/2, whose terms are all positive (a check independent of the
    continued fraction, whose deeper terms the closed forms never reach). The log tail matches them to
    1e-10 relative from p = 1e-5 down to 1e-3000 (the series to 1e-12 below 1e-280), where scipy's sf
    is 0, and its curvature in f has no step where it switches from scipy to the continued fraction
    (at p = 1e-280)."""
    from scipy import special, stats

    from diagnose.stepwise import f_logsf

    for d2 in (12.0, 80.0, 400.0, 1900.0, 9000.0):
        for f in np.geomspace(20.0, 1e6, 60):
            a, x = d2 / 2, d2 / (d2 + 4 * f)
            for d1, closed in ((2, -(d2 / 2) * np.log1p(2 * f / d2)), (4, a * np.log(x) + np.log1p(a * (1 - x)))):
                if -3000 * np.log(10.0) < closed < np.log(1e-5):
                    assert f_logsf(f, d1, d2) == pytest.approx(closed, rel=1e-10), (f, d1, d2)
        for d1 in (3, 9, 15):
            for f in np.geomspace(20.0, 1e4, 25):
                a, b = d2 / 2, d1 / 2
                x = d2 / (d2 + d1 * f)
                series = (
                    a * np.log(x)
                    + b * np.log1p(-x)
                    - np.log(a)
                    - special.betaln(a, b)
                    + np.log(special.hyp2f1(a + b, 1.0, a + 1.0, x))
                )
                if -3000 * np.log(10.0) < series < np.log(1e-280):  # the continued fraction's range
                    assert f_logsf(f, d1, d2) == pytest.approx(series, rel=1e-12), (f, d1, d2)
    assert stats.f.sf(1791.0, 2, 1900.0) == 0.0 and f_logsf(1791.0, 2, 1900.0) == pytest.approx(-1006.635306, abs=1e-5)
    for d1, d2 in ((3, 500.0), (14, 1900.0), (9, 300.0)):
        fs = np.linspace(1.0, 4000.0, 4000)
        v = np.array([f_logsf(f, d1, d2) for f in fs])
        assert np.all(np.diff(v) < 0), (d1, d2)
        switch = int(np.argmax(v < np.log(1e-280)))
        assert switch > 10, (d1, d2)
        bend = np.diff(v, 2)[switch - 6 : switch + 4]  # the curvature is smooth across the switch: no step
        k = np.arange(len(bend))
        off = bend - np.polyval(np.polyfit(k, bend, 2), k)
        assert bend.min() > 0 and np.max(np.abs(off)) < 1e-5 * bend.mean(), (d1, d2, off / bend.mean())
    assert f_logsf(np.inf, 3, 100.0) == -np.inf


def _cm_step_in_alpha_growing_with_mach(seed):
    """Twelve logs at six Mach numbers trimmed at falling alpha, the alpha swinging half a degree, and a
    pitching moment step in alpha growing with Mach, 10 times the noise: p-values that underflow."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    frames, n = [], 600
    for i, (mach, trim) in enumerate([(0.25, 8.0), (0.3, 6.5), (0.4, 4.5), (0.5, 3.2), (0.6, 2.4), (0.7, 1.8)] * 2):
        swing = 0.5 * np.sin(2 * np.pi * 0.3 * np.arange(n) / 60.0)
        a = trim + swing + rng.normal(0, 0.05, n)
        m = mach - 0.004 * swing + rng.normal(0, 0.001, n)
        frames.append(
            pd.DataFrame(
                {
                    "log": i,
                    "alpha_deg": a,
                    "mach": m,
                    "r_Cm": 0.01 * (a > 5.0) * (m - 0.2) / 0.5 + rng.normal(0, 1e-3, n),
                }
            )
        )
    return pd.concat(frames, ignore_index=True)


def test_a_cause_whose_p_value_underflows_reports_it_in_logs():
    """scipy's p-value is 0 below 1e-308; the evidence (and the summary) give its exact log instead."""
    from diagnose.causes import name_causes
    from diagnose.stepwise import Lags, stepwise
    from diagnose.terms import candidate_terms

    frame = _cm_step_in_alpha_growing_with_mach(0)
    pool = candidate_terms(frame, "Cm")
    res = stepwise(frame, "Cm", pool)
    first = res.alternatives[0]
    assert first["p_value"] == 0.0 and -1e4 < first["log10_p"] < -308
    assert all(
        a["log10_p"] == pytest.approx(np.log10(a["p_value"]), rel=1e-9) for a in res.alternatives if a["p_value"] > 0
    )
    only = stepwise(frame, "Cm", [t for t in pool if t.label == "smooth(alpha_deg) x mach"])
    (cause,) = name_causes({"Cm": only}, frame, Lags(frame["log"].to_numpy()))
    assert cause.evidence["p_value"] == 0.0 and -1e4 < cause.evidence["log10_p"] < -308


@pytest.mark.xfail(
    strict=True,
    reason="ranked by the exact log p this case would be named right, but among "
    "fits alike the log p follows the effective sample sizes and wider terms come first (the "
    "stock-737 gear-drag test would name gear x elevator); the ranking keeps the F-test's order",
)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_stepwise_search_ranks_candidates_whose_p_values_underflow_by_their_exact_logs(seed):
    """A pitching moment step in alpha, growing with Mach (:func:`_cm_step_in_alpha_growing_with_mach`).
    Four candidates' p-values are below 1e-308, 0 in floating point; ranked among them by F, whose size
    per column favours narrow terms, smooth(Mach) enters first and smooth(alpha) beside it: two causes for
    one (seed 9,400,043: quadratic(Mach) and smooth(alpha) for an A320 Cm step in alpha x Mach). In
    logs the effect's form is the strongest."""
    from diagnose.stepwise import stepwise
    from diagnose.terms import candidate_terms

    frame = _cm_step_in_alpha_growing_with_mach(seed)
    res = stepwise(frame, "Cm", candidate_terms(frame, "Cm"))
    first = {a["term"]: a for a in res.alternatives}
    right = first["smooth(alpha_deg) x mach"]
    narrow = [a for a in res.alternatives if a["p_value"] == 0.0 and a["F"] > right["F"]]
    assert right["p_value"] == 0.0 and narrow, "the case needs p-values that underflow, a narrower one with more F"
    assert all(right["log10_p"] < a["log10_p"] for a in narrow)
    assert res.alternatives[0]["term"] == "smooth(alpha_deg) x mach"
    assert [t.label for t in res.terms] == ["smooth(alpha_deg) x mach"]


@pytest.mark.parametrize("truth, term", [("alpha_deg", ("mach", "alpha_deg")), ("mach", ("alpha_deg", "mach"))])
def test_a_smooth_term_that_varies_with_another_variable_is_named_by_the_one_that_carries_it(truth, term):
    """Four conditions, each trimmed at its own alpha (the faster, the lower), with a 2-3-1-1's alpha
    swing in each: a dead band in alpha, or a step in Mach, fitted by a smooth term in the other
    variable that varies linearly with the first (seeds 4,600,055 and 2,000,282 of the
    detection curve: "Cm vs mach, alpha_deg" for a dead band in alpha, and "Cm vs alpha_deg, mach" for
    a step in Mach). The variable whose function alone makes the cause comes first."""
    import pandas as pd

    from diagnose.causes import name_causes
    from diagnose.stepwise import Lags, StepwiseResult, fit_terms
    from diagnose.terms import Term

    rng = np.random.default_rng(4)
    frames = []
    for i, (mach, trim) in enumerate([(0.2, 9.0), (0.3, 6.0), (0.4, 4.0), (0.5, 2.5)]):
        swing = 1.5 * np.sin(np.linspace(0.0, 6 * np.pi, 600))
        frames.append(
            pd.DataFrame(
                {
                    "log": i,
                    "alpha_deg": trim + swing + rng.normal(0, 0.05, 600),
                    "mach": mach - 0.004 * swing + rng.normal(0, 0.001, 600),
                }
            )
        )
    data = pd.concat(frames, ignore_index=True)
    a, m = data.alpha_deg.to_numpy(), data.mach.to_numpy()
    effect = {"alpha_deg": np.sign(a - 5.0) * np.clip(np.abs(a - 5.0) - 1.0, 0.0, None), "mach": 0.02 * (m > 0.33)}[
        truth
    ]
    data["r_Cm"] = effect + rng.normal(0, 0.002, len(data))
    smooth, linear = term
    knots = tuple(np.quantile(data[smooth], np.linspace(0, 1, 6)))
    t = Term(
        "smooth_x_linear",
        term,
        knots,
        (0.0, float(data[linear].median())),
        (
            (float(data[smooth].min()), float(data[smooth].max())),
            (float(data[linear].min()), float(data[linear].max())),
        ),
    )
    fit = fit_terms(data.r_Cm.to_numpy(), [t.design(data)], [t])
    res = StepwiseResult("Cm", [t], fit.beta, {t.label: {}}, [], 0.0, 0.0, len(data))
    (cause,) = name_causes({"Cm": res}, data, Lags(data["log"].to_numpy()))
    assert cause.variables == [truth, linear if truth == smooth else smooth]


def _needing_a_vane_scale(coefficient: str, needs: float, se: float, explains_pct: float):
    """A significant aero cause above its floor, and its reach: an alpha-vane scale of ``needs`` (the
    kinematics' standard error ``se``) explains ``explains_pct`` % of it."""
    from types import SimpleNamespace

    c = SimpleNamespace(
        kind="aero", coefficient=coefficient, evidence={"p_value": 0.0}, size=0.02, verdict={"noise_floor": 0.001}
    )
    return c, {
        "alternatives": [
            {
                "channel": "alpha_deg",
                "error": "scale",
                "needs": needs,
                "needs_se": needs / se,
                "se": se,
                "explains_pct": explains_pct,
            }
        ]
    }


def test_a_cause_that_would_need_a_correction_the_kinematics_rule_out_does_not_block_a_refinement():
    """The residuals of CL and Cm each need a vane scale of about 3.7 %, 2 standard errors from the
    kinematics' 1.1 +- 1.3 % (null 4,600,183: an A320 with a 3.7 % scale in 3 ft/s). A
    "CD vs CL" beside them would need -63 %, 48 standard errors the other way: it is some other cause's,
    and the scale is refined. Had CD needed -2 % (2.4 standard errors), the coefficients would disagree."""
    from diagnose.arbitration import residual_refinement
    from identify.compat.result import CompatResult, Parameter

    scale = Parameter("alpha_deg", "scale", "-", 0.01105, 0.01318)
    compat = CompatResult([Parameter("alpha_deg", "bias", "deg", 0.1208, 0.0502), scale])

    def cause(coefficient, needs):
        return _needing_a_vane_scale(coefficient, needs, 0.01318, 97.0)

    for far, refined in ((-0.6295, True), (-0.02, False)):
        pairs = [cause("Cm", 0.0357), cause("CD", far), cause("CL", 0.0380)]
        out = residual_refinement(compat, [c for c, _ in pairs], [r for _, r in pairs])
        out = out and out.compat
        assert (out is not None) == refined
        if refined:
            assert out.get("alpha_deg.scale").estimate == pytest.approx(0.03685)
            assert out.get("alpha_deg.scale").applied


def test_two_coefficients_that_agree_refine_beside_a_third_that_needs_more_of_the_same():
    """An A320 null's 7.2 % vane scale, corrected as -5.7 +- 2.2 % (validation seed 4,300,078): CL and Cm
    each need a further -1.7 %, CD -2.8 % (1.7 times as much: its cause partly a drag change). The two
    that agree refine it to -7.4 %; the third no longer vetoes. Needing +2.8 %, it still would."""
    from diagnose.arbitration import residual_refinement
    from identify.compat.result import CompatResult, Parameter

    compat = CompatResult(
        [
            Parameter(
                "alpha_deg",
                "scale",
                "-",
                -0.05682,
                0.02233,
                chosen="2.5 standard errors from the kinematics; the CL residual agrees",
            )
        ]
    )
    assert compat.get("alpha_deg.scale").applied
    for cd, refined in ((-0.02797, True), (0.02797, False)):
        pairs = [
            _needing_a_vane_scale("Cm", -0.01658, 0.02233, 100.0),
            _needing_a_vane_scale("CL", -0.01727, 0.02233, 97.0),
            _needing_a_vane_scale("CD", cd, 0.02233, 89.0),
        ]
        out = residual_refinement(compat, [c for c, _ in pairs], [r for _, r in pairs])
        assert (out is not None) == refined
        if refined:
            assert set(out.coefficients) == {"CL", "Cm"}
            assert out.compat.get("alpha_deg.scale").estimate == pytest.approx(-0.05682 - 0.016925)


def test_a_refinement_may_shrink_a_correction_the_data_carry_toward_none_but_not_grow_it_as_far():
    """A vane scale of +2.9 +- 0.52 % applied on the kinematics' word (5.6 standard errors); CL, CD and Cm
    need a further -2.8, -1.9 and -2.8 % (null 4,900,238): refined to +0.1 %, 5.4 standard
    errors from the kinematics' estimate but between it and none. The same needs with the opposite sign
    would grow the correction to 5.7 %, 5.4 standard errors past it: not refined."""
    from diagnose.arbitration import residual_refinement
    from identify.compat.result import CompatResult, Parameter

    compat = CompatResult([Parameter("alpha_deg", "scale", "-", 0.02897, 0.005212)])
    assert compat.get("alpha_deg.scale").applied

    def cause(coefficient, needs):
        return _needing_a_vane_scale(coefficient, needs, 0.005212, 99.0)

    for sign, refined in ((1.0, True), (-1.0, False)):
        pairs = [cause("CL", -0.02845 * sign), cause("CD", -0.01908 * sign), cause("Cm", -0.02787 * sign)]
        out = residual_refinement(compat, [c for c, _ in pairs], [r for _, r in pairs])
        out = out and out.compat
        assert (out is not None) == refined
        if refined:
            assert out.get("alpha_deg.scale").estimate == pytest.approx(0.0011, abs=1e-4)


def test_three_coefficients_that_agree_may_refine_a_correction_further_than_two():
    """A vane scale the kinematics measure at 1.19 +- 0.75 % (not applied); Cm, CL and CD need 4.04, 4.47
    and 3.04 % (null 4,100,188, a 4.2 % scale): the median is 3.8 standard errors away, within
    the 5.3 three may refine (``agree_all_se``) and past the 3.5 two may (``agree_se``)."""
    from diagnose.arbitration import residual_refinement
    from identify.compat.result import CompatResult, Parameter

    compat = CompatResult([Parameter("alpha_deg", "scale", "-", 0.01192, 0.0075)])

    def cause(coefficient, needs):
        return _needing_a_vane_scale(coefficient, needs, 0.0075, 95.0)

    three = [cause("Cm", 0.04039), cause("CL", 0.04469), cause("CD", 0.03036)]
    out = residual_refinement(compat, [c for c, _ in three], [r for _, r in three])
    assert out is not None and out.compat.get("alpha_deg.scale").estimate == pytest.approx(0.04039)
    two = three[:2]
    assert residual_refinement(compat, [c for c, _ in two], [r for _, r in two]) is None


def test_a_cause_its_own_held_out_logs_refute_does_not_veto_what_two_others_agree_on():
    """Our 737 in 3 ft/s with a +4.8 % vane scale and nothing else hidden (null 6,700,233). The kinematics
    put the scale at -0.16 +- 2.7 %; CL and Cm each need +4.9 and +4.5 %. A "CD vs qhat" 3 times its floor,
    which its held-out logs refute (x1.012 with each left out), would need -1.75 %, and its opposite sign
    vetoed the scale: "CL vs alpha" and "Cm vs alpha" were named on a null. Refuted, it does not veto; held
    out with a gain, it still does."""
    from diagnose.arbitration import residual_refinement
    from identify.compat.result import CompatResult, Parameter

    compat = CompatResult(
        [
            Parameter("alpha_deg", "bias", "deg", 0.2123, 0.06395, chosen="the CL residual agrees"),
            Parameter("alpha_deg", "scale", "-", -0.001627, 0.02729),
        ]
    )
    for replicate, refined in ((1.012, True), (1.3, False)):
        pairs = [
            _needing_a_vane_scale("CL", 0.04863, 0.02729, 100.0),
            _needing_a_vane_scale("Cm", 0.04541, 0.02729, 100.0),
            _needing_a_vane_scale("CD", -0.01754, 0.02729, 100.0),
        ]
        pairs[2][0].verdict.update(replicate_gain=replicate, replicate_gain_where_departs=1.038)
        out = residual_refinement(compat, [c for c, _ in pairs], [r for _, r in pairs])
        assert (out is not None) == refined
        if refined:
            assert out.name == "alpha_deg.scale" and set(out.coefficients) == {"CL", "Cm"}
            assert out.compat.get("alpha_deg.scale").estimate == pytest.approx(0.04702, abs=1e-5)


def test_a_refinement_several_coefficients_need_is_vetoed_by_a_residual_growing_about_its_mean_only():
    """A -4.95 +- 1.27 % vane scale chosen where there is none, beside a lift offset it masked (seed
    6,700,032): CL, CD and Cm each need it undone. Undone, CL's residual grows 1.7-fold with its mean (the
    offset, which the stepwise search's intercept takes up) and shrinks about it: the refinement stands.
    A residual that grows about its mean by more than 1.1 still refuses it."""
    import pandas as pd

    from diagnose.arbitration import refinement_stands, residual_refinement
    from identify.compat.result import CompatResult, Parameter

    compat = CompatResult(
        [
            Parameter(
                "alpha_deg",
                "scale",
                "-",
                -0.04951,
                0.0127,
                chosen="3.9 standard errors from the kinematics; the CL residual agrees",
            )
        ]
    )
    assert compat.get("alpha_deg.scale").applied
    pairs = [_needing_a_vane_scale(c, 0.0489, 0.0127, 100.0) for c in ("CL", "CD", "Cm")]
    out = residual_refinement(compat, [c for c, _ in pairs], [r for _, r in pairs])
    assert out is not None and set(out.coefficients) == {"CL", "CD", "Cm"}
    assert out.compat.get("alpha_deg.scale").estimate == pytest.approx(-0.0006, abs=1e-4)
    t = np.linspace(0.0, 20.0, 2000)

    def residuals(cl_mean, cl, cd, cm):
        return pd.DataFrame(
            {"r_CL": cl_mean + cl * np.sin(t), "r_CD": cd * np.sin(1.3 * t), "r_Cm": cm * np.sin(0.7 * t)}
        )

    before = residuals(0.016, 0.014, 0.0023, 0.0021)
    unmasked = residuals(0.0318, 0.0054, 0.00035, 0.0011)
    assert np.sqrt(np.mean(unmasked.r_CL**2)) > 1.6 * np.sqrt(np.mean(before.r_CL**2))
    assert refinement_stands(out, before, unmasked) is out.compat
    assert refinement_stands(out, before, residuals(0.0318, 0.0054, 0.0026, 0.0011)) is None  # CD x1.13


def test_one_coefficient_adjusts_only_a_correction_the_kinematics_made_and_needs_another_as_witness():
    """CD alone needs a further +0.075 deg of vane bias (null 5,000,150: -0.589 +- 0.031 deg
    applied, the truth -0.51): refined, since the kinematics made that correction. It stands only if
    another coefficient's whole residual gets 1.1 times smaller with it (CL's offset did, 4.8-fold), and
    no coefficient's grows by more than 1.1. A correction the kinematics did not make (the vane scale,
    3.3 standard errors and confounded with the bias) is never added on one coefficient's word."""
    import pandas as pd

    from diagnose.arbitration import refinement_stands, residual_refinement
    from identify.compat.result import CompatResult, Parameter

    bias = Parameter("alpha_deg", "bias", "deg", -0.5892, 0.03064)
    scale = Parameter(
        "alpha_deg", "scale", "-", 0.01977, 0.005911, confounded_with="alpha_deg.bias", reason="confounded"
    )
    assert bias.applied and not scale.applied
    c, r = _needing_a_vane_scale("CD", 0.0746, 0.03064, 100.0)
    r["alternatives"] = [
        dict(r["alternatives"][0], error="bias"),
        dict(r["alternatives"][0], error="scale", needs=0.006573, se=0.005911),
    ]
    out = residual_refinement(CompatResult([bias, scale]), [c], [r])
    assert out.name == "alpha_deg.bias" and out.coefficients == ("CD",)
    assert out.compat.get("alpha_deg.bias").estimate == pytest.approx(-0.5146)
    assert out.compat.get("alpha_deg.scale").estimate == scale.estimate
    assert (
        residual_refinement(CompatResult([bias.__class__("alpha_deg", "bias", "deg", -0.02, 0.03064), scale]), [c], [r])
        is None
    )

    def residuals(cl, cd, cm):
        return pd.DataFrame({"r_CL": cl, "r_CD": cd, "r_Cm": cm})

    before = residuals([0.006, -0.0061], [5e-4, 6e-4], [8e-4, 9e-4])
    stands = refinement_stands(out, before, residuals([0.0013, -0.0012], [2e-4, 2e-4], [7e-4, 7e-4]))
    assert stands is not None and "CL's residual RMS x4.84" in stands.get("alpha_deg.bias").chosen
    assert refinement_stands(out, before, residuals([0.0058, -0.006], [2e-4, 2e-4], [8e-4, 9e-4])) is None
    assert refinement_stands(out, before, residuals([0.0013, -0.0012], [2e-4, 2e-4], [1e-3, 1e-3])) is None


def test_channel_noise_finds_each_channels_white_noise_under_smooth_signals():
    """Known sigmas on smooth manoeuvre-like signals at 50 Hz, channels missing from some logs,
    a spike: each level within 5 %, and only the channels some log has."""
    import pandas as pd

    from diagnose.noise_floor import channel_noise
    from identify.logs import Log

    rng = np.random.default_rng(3)
    sigma = {"alpha_deg": 0.05, "q_dps": 0.2, "tas_kt": 0.5, "thrust_lbf": 40.0}
    logs = []
    for k in range(9):
        t = np.arange(0.0, 28.0, 0.02)
        cols = {"t_s": t}
        for j, (ch, s) in enumerate(sigma.items()):
            if ch == "thrust_lbf" and k % 3 == 0:
                continue
            cols[ch] = 20 * s * np.sin(0.7 * t + j + k) + rng.normal(0.0, s, len(t))
        cols["alpha_deg"][500] += 30.0
        logs.append(Log(f"log{k}", pd.DataFrame(cols), {}))
    found = channel_noise(logs)
    assert set(found) == set(sigma)
    for ch, s in sigma.items():
        assert abs(found[ch] / s - 1.0) < 0.05, (ch, found[ch], s)


def test_noise_floor_realizations_drawn_together_equal_each_drawn_alone(tmp_path, small_matrix):
    """The noise floor computes several realizations at once (one spline for their pitch
    accelerations: the flight-test logs have no qdot); each must be the one drawn alone, bit
    for bit, and fresh noise each."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from diagnose.evaluate import ModelEvaluator
    from diagnose.noise_floor import NoiseFloor, channel_noise
    from identify.logs import read_campaign

    assert (
        main(
            [
                "run",
                "--matrix",
                str(small_matrix),
                "--out",
                str(tmp_path / "c"),
                "--noise",
                "flight-test",
                "--no-identify",
                "--quiet",
            ]
        )
        == 0
    )
    logs = read_campaign(tmp_path / "c")
    assert logs and all("qdot_dps2" not in lg.data for lg in logs)
    ev = ModelEvaluator(DEFAULT_AIRCRAFT)
    try:
        floor = NoiseFloor(logs, ev, channel_noise(logs), realizations=3)
        columns = {"alpha_deg", "gear_norm", "qhat_rad", "CL"}
        together = floor.realization_batch(columns, [{"k": k} for k in range(3)])
        for k, frame in enumerate(together):
            alone = floor.realization(k, columns)
            assert list(frame.columns) == list(alone.columns)
            assert all(np.array_equal(frame[c].to_numpy(), alone[c].to_numpy()) for c in frame.columns), k
        assert not np.array_equal(together[0]["r_Cm"].to_numpy(), together[1]["r_Cm"].to_numpy())
        assert 0 < float(np.std(together[2]["r_Cm"])) < 0.05
    finally:
        ev.close()


def test_the_errors_in_variables_factor_is_measured_per_variable(tmp_path, small_matrix):
    """The floor's realizations add fresh noise to regressors that already hold noise, which
    under-simulates errors-in-variables by (V + 2 s2) / (V + s2): about 1 for the flight-test
    instruments' alpha, Mach and CL (their noise is small beside what the manoeuvres make them
    vary), exactly 1 for gear without noise, and near 2 for a Mach whose noise swamps its variation
    within each log."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from diagnose.evaluate import ModelEvaluator
    from diagnose.noise_floor import NoiseFloor, channel_noise
    from identify.logs import Log, read_campaign

    assert (
        main(
            [
                "run",
                "--matrix",
                str(small_matrix),
                "--out",
                str(tmp_path / "c"),
                "--noise",
                "flight-test",
                "--no-identify",
                "--quiet",
            ]
        )
        == 0
    )
    logs = read_campaign(tmp_path / "c")
    rng = np.random.default_rng(7)
    swamped = []
    for lg in logs:
        d = lg.data.copy()
        d["mach"] = d["mach"] + rng.normal(0.0, 0.1, len(d))
        swamped.append(Log(lg.path, d, lg.meta))
    ev = ModelEvaluator(DEFAULT_AIRCRAFT)
    try:
        variables = ["alpha_deg", "mach", "gear_norm", "CL"]
        found = NoiseFloor(logs, ev, channel_noise(logs), realizations=1).eiv_factors(variables)
        assert found["gear_norm"] == 1.0
        assert all(1.0 < found[v] < 1.05 for v in ("alpha_deg", "mach", "CL")), found
        worse = NoiseFloor(swamped, ev, channel_noise(swamped), realizations=1).eiv_factors(variables)
        assert 1.8 < worse["mach"] <= 2.0 and worse["alpha_deg"] < 1.05, worse
    finally:
        ev.close()


def test_refine_oe_in_still_air_keeps_a_right_extension_and_measures_it(tmp_path, capsys):
    """``--refine oe`` on data flown through the flight-test instruments in still air: the
    equation-error extension of a hidden gear-drag bump is refined through JSBSim replays of the
    fitted logs, written beside it, and its gain reported beside the first one's."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.validation.hidden import fly_data

    still = tmp_path / "still.toml"
    still.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 0.0\n')
    hidden = make("gear_bump", np.random.default_rng(5), "CD")
    data, _ = fly_data(tmp_path / "w", hidden, seed=5, instruments=str(still))
    out = tmp_path / "report"
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(data),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(out),
                "--no-plots",
                "--quiet",
                "--jobs",
                "2",
                "--refine",
                "oe",
            ]
        )
        == 0
    )
    text = capsys.readouterr().out
    doc = json.loads((out / "diagnosis.json").read_text())
    r = doc["refine"]
    assert r["method"] == "oe" and r["caveat"] is None and r["fitted_logs"]
    # the scales stay within 0.7 of 1 (today 1.51 +- 0.19: the replays' speed drift, from the trim
    # taken off noisy data and the thrust channel's noise, leans on the only free knob); with the
    # replays time-compressed (a 50 Hz log played at 120 Hz) it was 2.3
    for name, scale in r["scales"].items():
        assert abs(scale - 1.0) < 0.7 and r["se_coloured"][name] > 0, (name, scale, r["se_coloured"][name])
    # both extensions fly the held-out gear extension closer to the data than the model does
    for g in (doc["gain"], r["gain"]):
        assert g["replay_max_error"]["theta_deg"]["gain"] > 1.3 and g["residual_gain"] > 1.0
    assert (out / "extension_oe.xml").stat().st_size > 0 and (out / "extended_aircraft_oe" / "737" / "737.xml").exists()
    assert "Refined by output error" in text and "equation-error extension -> refined" in text
    assert not (out / ".refine").exists()  # the trial aircraft are cleaned up


def test_held_out_replays_fly_in_the_measured_wind(tmp_path, capsys):
    """Our 737 in 3 ft/s turbulence through the flight-test instruments, diagnosed against itself:
    the held-out replays fly in the wind measured in each log (inertial minus air-relative
    velocity) and follow the data within 0.5 deg of pitch and 50 ft (half the Part 60 gear-change
    tolerance) over the whole log; the same replays in still air do not."""
    from campaign.diagnosis.run import log_wind, replay
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, AircraftSource, load_effects
    from campaign.validation.support import matrix_toml, pairs, run_matrix
    from diagnose.gain import replay_errors
    from identify.compat import estimate
    from identify.kinematics import measured_wind
    from identify.logs import read_campaign

    prof = tmp_path / "t3.toml"
    prof.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 3.0\n')
    data = run_matrix(
        tmp_path / "w",
        matrix_toml(pairs((0, 0.3, [2000, 10000])), "w3"),
        str(DEFAULT_AIRCRAFT),
        noise=str(prof),
        seed=4,
    )
    out = tmp_path / "report"
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(data),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(out),
                "--no-plots",
                "--quiet",
                "--jobs",
                "2",
            ]
        )
        == 0
    )
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["wind"] and all(w["replayed_in"] == "measured wind" for w in doc["wind"].values())
    assert set(doc["replays"]) == set(doc["wind"])
    for name, r in doc["replays"].items():
        assert r["theta_deg"]["model"] < 0.5 and r["alt_ft"]["model"] < 50.0, (name, r)
        assert r["theta_deg"]["extended"] is None  # nothing to extend
    assert "flown in the wind measured in their log" in capsys.readouterr().out
    # the same logs replayed in still air miss by much more
    logs = read_campaign(data)
    compat = estimate(logs)
    src = AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(None))
    still = [replay_errors(c.data, replay(c, src, wind=False)) for c in map(compat.correct, logs[:3])]
    assert max(e["theta_deg"] for e in still) > 1.0
    # noise-free logs carry no wind: their replays stay in still air, exact
    clean = read_campaign(run_matrix(tmp_path / "c", matrix_toml(pairs((0, 0.3, [2000])), "c"), str(DEFAULT_AIRCRAFT)))[
        0
    ]
    assert np.abs(measured_wind(clean.data)).max() < 1e-3 and log_wind(clean) is None


def test_bands_from_the_extensions_covariance_cover_a_perturbed_model(tmp_path, capsys):
    """``--bands 20``: the extension's terms drawn from their covariance, the held-out replays where
    the cause acts flown for each draw in the measured wind. A 21st draw, held back from the band,
    lies inside it nearly all the time; the pass probability and the shaded plot are reported."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.validation.hidden import fly_data

    hidden = make("gear_bump", np.random.default_rng(5), "CD")
    data, _ = fly_data(tmp_path / "w", hidden, seed=5)
    out = tmp_path / "report"
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(data),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(out),
                "--quiet",
                "--jobs",
                "2",
                "--bands",
                "20",
            ]
        )
        == 0
    )
    doc = json.loads((out / "diagnosis.json").read_text())
    assert set(doc["bands"]) == set(doc["gain"]["cause_exercised_in"])
    for name, b in doc["bands"].items():
        assert b["draws"] == 20 and 0.0 <= b["pass_probability"] <= 1.0
        assert b["held_back_draw_inside"] >= 0.8, (name, b)
        assert b["width_max"]["alt_ft"] > 0 and b["width_max"]["theta_deg"] > 0
        assert (out / "plots" / f"response_{Path(name).stem}.png").exists()
    assert "Monte Carlo bands" in capsys.readouterr().out
    assert not (out / ".bands").exists()
    capsys.readouterr()
    assert (
        main(
            [
                "diagnose",
                "--data",
                str(data),
                "--model",
                str(DEFAULT_AIRCRAFT),
                "--out",
                str(tmp_path / "x"),
                "--bands",
                "5",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "--bands" in err and err.count("\n") == 1 and not (tmp_path / "x").exists()


def _alpha_slope_logs(rng: np.random.Generator, offsets: list[float]):
    """Residual data of one log per offset: a CL slope of 0.01 per deg of alpha (2 to 8 deg), 1e-4 of noise,
    and the log's offset."""
    import pandas as pd

    frames = []
    for i, off in enumerate(offsets):
        a = rng.uniform(2.0, 8.0, 500)
        frames.append(
            pd.DataFrame({"log": i, "alpha_deg": a, "r_CL": 0.01 * (a - 5.0) + off + rng.normal(0.0, 1e-4, 500)})
        )
    return pd.concat(frames, ignore_index=True)


def test_the_held_out_check_takes_the_fit_off_and_tells_what_it_does_not_carry():
    """A CL slope in alpha fitted on three logs: on held-out logs that carry the same slope nothing is told;
    an offset of 0.002 on one of them, which the fit does not carry, is told there, with its size. Without
    the fit taken off, the slope (0.017 RMS) would hide the offset from the ratio."""
    from diagnose.config import DEFAULTS
    from diagnose.held_out import held_out_check
    from diagnose.stepwise import StepwiseResult
    from diagnose.terms import Term

    rng = np.random.default_rng(0)
    data = _alpha_slope_logs(rng, [0.0, 0.0, 0.0])
    term = Term("linear", ("alpha_deg",), (), (5.0,), ((2.0, 8.0),))
    beta = np.linalg.lstsq(np.column_stack([np.ones(len(data)), term.design(data)]), data["r_CL"], rcond=None)[0]
    fit = {"CL": StepwiseResult("CL", [term], beta, {}, [], 0.0, 0.0, 1000.0)}
    fitted, held = ["a.parquet", "b.parquet", "c.parquet"], ["d.parquet", "e.parquet"]
    carried = held_out_check(data, _alpha_slope_logs(rng, [0.0, 0.0]), fit, fitted, held)["CL"]
    assert not carried["told"] and carried["ratio"] < 1.2, carried
    assert set(carried["held_out_rms"]) == set(held) and carried["fitted_worst_log"] in fitted
    assert carried["fitted_worst_rms"] == pytest.approx(1e-4, rel=0.2)
    told = held_out_check(data, _alpha_slope_logs(rng, [0.0, 0.002]), fit, fitted, held)["CL"]
    assert told["told"] and told["worst_log"] == "e.parquet", told
    assert told["held_out_rms"]["e.parquet"] == pytest.approx(0.002, rel=0.05)
    assert told["ratio"] == pytest.approx(told["held_out_rms"]["e.parquet"] / told["fitted_worst_rms"])
    assert told["ratio"] > 5 * DEFAULTS.held_out_ratio
    assert held_out_check(data, None, fit, fitted, []) == {}


def test_the_held_out_condition_is_one_the_fitted_ones_bracket():
    """Three conditions, one Mach 0.5 and one flap 15: holding out either leaves the fit without
    that Mach or flap, and an effect there is visible in held-out data only (a Mach step hidden in
    the A320's data gave no candidate at all). The third is held out; a condition that alone
    flew the gear down stays in the fit."""
    from types import SimpleNamespace

    from campaign.diagnosis.run import split

    def log(c, gear="up"):
        return SimpleNamespace(condition=c, transition=False, gear_down=gear == "down")

    a320 = [log(c) for c in ((5000.0, 0.3, 0.0), (10000.0, 0.5, 0.0), (5000.0, 0.3, 15.0))]
    assert [lg.condition for lg in split(a320)[1]] == [(5000.0, 0.3, 0.0)]
    four = [log(c) for c in ((2000.0, 0.2, 30.0), (2000.0, 0.3, 0.0), (10000.0, 0.3, 0.0), (10000.0, 0.5, 0.0))]
    assert [lg.condition for lg in split(four)[1]] == [(10000.0, 0.3, 0.0)]  # as every third: nothing lost
    down = four + [log((10000.0, 0.3, 0.0), "down")]
    train, held = split(down)
    assert any(lg.gear_down for lg in train) and len({lg.condition for lg in held}) == 1


def _trimmed(condition, lo, mid, hi, gear="up"):
    """A log at ``condition`` whose angle of attack [deg] runs from ``lo`` to ``hi`` about ``mid``."""
    import pandas as pd

    alpha = np.concatenate([np.linspace(lo, mid, 50), np.full(100, mid), np.linspace(mid, hi, 50)])
    return SimpleNamespace(
        condition=condition, transition=False, gear_down=gear == "down", data=pd.DataFrame({"alpha_deg": alpha})
    )


def test_the_fit_keeps_every_mach_number_apart_from_the_flap_and_the_highest_alpha():
    """The benchmark's matrices with the trim alphas they fly (fresh 9,402,611 and 9,402,594). The A320's
    six conditions: every pair held out takes something (Mach 0.3 left at flap 15 only, a Mach number,
    the lowest trim alpha or the highest altitude), and a Mach step was named in the flap; one condition
    is held out, and it leaves every Mach number clean in the fit. Our 737's five: its Mach 0.3 at
    10,000 ft trims above what the rest fly, and a Cm rise above 9 deg had F 3 in the fit; the
    condition held out is one the fit brackets."""
    from campaign.diagnosis.run import split

    a320 = [
        _trimmed(*c)
        for c in (
            ((5000.0, 0.3, 0.0), 6.1, 8.0, 9.5),
            ((5000.0, 0.3, 15.0), 4.8, 5.9, 7.0),
            ((10000.0, 0.4, 0.0), 3.4, 4.7, 5.6),
            ((10000.0, 0.5, 0.0), 0.5, 1.9, 3.2),
            ((19500.0, 0.4, 0.0), 6.5, 8.0, 9.4),
            ((21000.0, 0.5, 0.0), 3.1, 4.8, 5.8),
        )
    ]
    train, held = split(a320)
    assert [lg.condition for lg in held] == [(10000.0, 0.4, 0.0)]
    clean = {lg.condition[1] for lg in train if lg.condition[2] == 0.0}
    assert clean == {0.3, 0.4, 0.5}
    # four of them: the only Mach 0.4 held out blurs no more than Mach 0.3 left at flap 15, and stays
    four = [lg for lg in a320 if lg.condition[0] in (5000.0, 10000.0)]
    assert [lg.condition for lg in split(four)[1]] == [(10000.0, 0.4, 0.0)]
    ours = [
        _trimmed(*c)
        for c in (
            ((2000.0, 0.2, 30.0), 3.6, 6.0, 8.7),
            ((2000.0, 0.3, 0.0), 3.6, 6.6, 9.3),
            ((10000.0, 0.3, 0.0), 6.2, 9.5, 12.4),
            ((10000.0, 0.5, 0.0), -1.6, 1.9, 4.6),
            ((17000.0, 0.4, 0.0), 2.7, 6.4, 9.1),
        )
    ]
    train, held = split(ours)
    assert [lg.condition for lg in held] == [(2000.0, 0.3, 0.0)]
    assert max(float(lg.data.alpha_deg.max()) for lg in train) > 12.0
    # without the angles of attack (logs that do not carry them) the choice is by the conditions alone
    bare = [SimpleNamespace(condition=lg.condition, transition=False, gear_down=False) for lg in ours]
    assert [lg.condition for lg in split(bare)[1]] == [(10000.0, 0.3, 0.0)]
