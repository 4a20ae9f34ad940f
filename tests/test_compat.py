"""Data compatibility: the instrument errors injected by a profile are found from the logs alone.

Each identifiable error must come back within 2 standard errors or 10 % of
its size, whichever is larger, in still air and in the flight-test profile's
turbulence; errors not injected must not be applied; what the manoeuvres
cannot separate is reported as such, with the reason. In turbulence the
air-data time shifts are such: the aircraft's answer to the gusts biases them.
"""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
from campaign.diagnosis.run import load_data
from identify.compat import estimate
from campaign.validation.hidden import DIAG_MATRIX
from campaign.validation.support import run_matrix

#: (channel.error, value in the profile's terms, value as the compatibility reports it)
INJECTED = {
    "alpha_deg.bias": ("alpha_deg", "bias", 0.5, 0.5),
    "alpha_deg.scale": ("alpha_deg", "scale", 1.05, 0.05),
    "alpha_deg.delay": ("alpha_deg", "delay_s", 0.05, 0.05),
    "theta_deg.scale": ("theta_deg", "scale", 1.02, 0.02),
    "theta_deg.delay": ("theta_deg", "delay_s", 0.04, 0.04),
    "q_dps.bias": ("q_dps", "bias", 0.05, 0.05),
    "p_dps.bias": ("p_dps", "bias", -0.03, -0.03),
    "ax_fps2.bias": ("ax_fps2", "bias", 0.05, 0.05),
    "az_fps2.bias": ("az_fps2", "bias", 0.15, 0.15),
}


def _profile(sigma_fps: float) -> str:
    channels = {}
    for ch, key, v, _ in INJECTED.values():
        channels.setdefault(ch, []).append(f"{key} = {v!r}")
    return (
        'extends = "flight-test"\n'
        + f"[turbulence]\nsigma_fps = {sigma_fps}\n"
        + "".join(f"[channels.{c}]\n" + "\n".join(kv) + "\n" for c, kv in channels.items())
    )


@pytest.mark.parametrize("sigma_fps", [0.0, 1.5], ids=["still-air", "turbulence"])
def test_injected_instrument_errors_are_recovered(tmp_path, sigma_fps):
    prof = tmp_path / "faulty.toml"
    prof.write_text(_profile(sigma_fps))
    data = run_matrix(tmp_path, DIAG_MATRIX, str(DEFAULT_AIRCRAFT), noise=str(prof), seed=41)
    res = estimate(load_data(data), jobs=2)
    by = {p.name: p for p in res.parameters}
    for name, (_, _, _, want) in INJECTED.items():
        p = by[name]
        if name == "theta_deg.delay":  # JSBSim integrates the attitude by rectangular Euler
            want += 0.5 / 120  # (simulation/integrator/position/rotational = 1): half a frame behind its rates
        if name == "alpha_deg.delay" and sigma_fps > 0:
            # the aircraft's answer to the gusts biases the kinematic time shift: said, not applied
            assert not p.identifiable and p.reason.startswith("turbulence"), p.reason
            assert ("alpha_deg", "delay") in res.unmeasured
            assert res.to_dict()["vertical_gust_rms_fps"] > 0.5
            continue
        assert p.identifiable, (name, p.reason)
        assert abs(p.estimate - want) <= max(2 * p.se, 0.1 * abs(want)), (name, p.estimate, p.se, want)
        assert p.correctable, name
    applied = {p.name for p in res.applied}
    assert applied >= {n for n in INJECTED if by[n].identifiable and by[n].z >= 5} - {"ax_fps2.bias"}
    # the x-accelerometer trades with a pitch-attitude bias through gravity: held back, the partner named
    assert by["ax_fps2.bias"].confounded_with == "theta_deg.bias" or "ax_fps2.bias" in applied
    for name in applied - set(INJECTED):
        raise AssertionError(f"{name} applied but not injected: {by[name].estimate} +- {by[name].se}")
    # what longitudinal manoeuvres cannot tell is said, with why
    for name in ("beta_deg.bias", "tas_kt.scale", "phi_deg.scale"):
        assert not by[name].identifiable and by[name].reason, name
    doc = res.to_dict()
    json.dumps(doc)
    assert {p["channel"] for p in doc["parameters"]} >= {"alpha_deg", "theta_deg", "az_fps2", "tas_kt"}
    assert doc["documented_positions_ft"]["alpha_deg"] == [62.0, 0.0, 0.0]
    assert res.residual_rms["alpha_deg"]["after"] < res.residual_rms["alpha_deg"]["before"]


def test_perfect_instruments_in_turbulence_need_no_correction(tmp_path):
    """Seed 42 is a null whose clustered standard error of the alpha scale came out 4x small (z 4.5):
    the kinematics alone apply nothing below 5 standard errors, and the residuals refuse it."""
    from campaign.diagnosis.run import split
    from diagnose.corrected import Corrected
    from diagnose.diagnosis import diagnose
    from diagnose.evaluate import ModelEvaluator
    from diagnose.residuals import residual_data

    data = run_matrix(tmp_path, DIAG_MATRIX, str(DEFAULT_AIRCRAFT), noise="flight-test", seed=42)
    res = estimate(load_data(data))
    assert not res.applied, res.summary()
    train, held = split(load_data(data))
    evaluator = ModelEvaluator(DEFAULT_AIRCRAFT)
    diag = diagnose(train, evaluator, held)
    assert not diag.compat.applied and not diag.discrepancy, (diag.compat.summary(), diag.summary())
    # within a diagnosis the residuals of a correction are computed once; a frame with a delay's
    # signature serves the request without it, as a fresh computation gives it
    corrected = Corrected(train, held, evaluator)
    timed = corrected.residuals(res, delays=("alpha_deg",))
    served = corrected.residuals(res)
    assert len(corrected._memo) == 1 and "alphadelay_CL" in timed and "alphadelay_CL" not in served
    assert [lg.meta["corrections"] for lg in corrected.logs(res)] == [
        res.correct(lg).meta["corrections"] for lg in train
    ]
    fresh = residual_data([res.correct(lg) for lg in train], ModelEvaluator(DEFAULT_AIRCRAFT))
    pd.testing.assert_frame_equal(served, fresh, check_exact=False, rtol=1e-10, atol=1e-12)
    timed.loc[:, "r_CL"] = 0.0  # a caller's change does not reach the memo
    assert np.allclose(corrected.residuals(res)["r_CL"], fresh["r_CL"], rtol=1e-10, atol=1e-12)
    corrected.forget()
    assert not corrected._memo
    log = load_data(data)[0]
    corrected = res.correct(log)
    # the boom's documented position is still taken out: alpha at the CG
    assert not np.allclose(corrected.data.alpha_deg, log.data.alpha_deg)
    assert corrected.meta["positions_corrected"]["alpha_deg"] == [62.0, 0.0, 0.0]


def test_logs_without_the_kinematic_channels_say_why(tmp_path):
    from dataclasses import replace

    one = DIAG_MATRIX.split("[[points]]")
    data = run_matrix(tmp_path, one[0] + "[[points]]" + one[1], str(DEFAULT_AIRCRAFT))
    logs = [replace(lg, data=lg.data.drop(columns=["phi_deg"])) for lg in load_data(data)]
    res = estimate(logs)
    assert not res.applied and all("phi_deg is not logged" in p.reason for p in res.parameters)


def test_one_log_is_reconstructed_in_segments_that_stand_in_for_logs(tmp_path):
    """One log alone: cut into segments of at least ``one_log_segment_s``, each its own initial state, as
    the jackknife's clusters; the pitch gyro's injected bias comes back and is corrected, the vane's is not
    estimated (the segments misjudge the turbulence's hold on the air data). A log shorter than ``one_log_segments`` segments gets
    no reconstruction, and says why."""
    from dataclasses import replace

    from identify.compat import CompatSettings
    from identify.compat.fit import segments

    prof = tmp_path / "faulty.toml"
    prof.write_text(_profile(0.0))
    one = DIAG_MATRIX.split("[[points]]")
    data = run_matrix(tmp_path, one[0] + "[[points]]" + one[1], str(DEFAULT_AIRCRAFT), noise=str(prof), seed=41)
    log = max(load_data(data), key=lambda lg: lg.data.t_s.iloc[-1])
    span = log.data.t_s.iloc[-1] - log.data.t_s.iloc[0]
    least = CompatSettings().one_log_segment_s
    pieces = segments(log, least)
    assert len(pieces) == int(span // least) >= CompatSettings().one_log_segments
    assert sum(len(p.data) for p in pieces) == len(log.data)
    assert all(p.data.t_s.iloc[-1] - p.data.t_s.iloc[0] >= least - 0.1 for p in pieces)
    res = estimate([log])
    assert res.segments == len(pieces) and res.logs == [log.path]
    q = res.get("q_dps.bias")
    assert q.applied and abs(q.estimate - 0.05) <= max(2 * q.se, 0.005), (q.estimate, q.se)
    # the vane's bias, which the air data's turbulence holds, is not estimated from one log
    vane = res.get("alpha_deg.bias")
    assert not vane.identifiable and not vane.applied and vane.reason.startswith("one log"), vane.reason
    short = replace(log, data=log.data[log.data.t_s < log.data.t_s.iloc[0] + 1.5 * least])
    res = estimate([short])
    assert not res.applied and not res.segments
    assert all("shorter than 4 segments of 4 s" in p.reason for p in res.parameters)


def test_a_full_circle_measures_the_airspeed_error_in_turbulence(tmp_path):
    """A 3 % airspeed scale that no straight manoeuvre can tell from a steady wind, found from one
    360-deg level turn in the flight-test profile's turbulence: the prior on the gusts keeps the
    wind from trading with them, and the standard error holds the mean gust the splines leave out
    (on seeds 2-11 of benchmarks/turn_airspeed.py; seed 12 is this test's own)."""
    from campaign.validation.support import TURN_MATRIX

    prof = tmp_path / "p.toml"
    prof.write_text('extends = "flight-test"\n[channels.tas_kt]\nscale = 1.03\n')
    logs = load_data(run_matrix(tmp_path, TURN_MATRIX, str(DEFAULT_AIRCRAFT), noise=str(prof), seed=12))
    turn = next(lg for lg in logs if lg.maneuver == "level_turn").read()
    truth = 0.03 * float(np.median(turn.data.tas_kt)) / 1.03  # [kt] along the track at the turn's speed
    res = estimate(logs)
    by = {p.name: p for p in res.parameters}
    held = by["tas_kt.bias"]  # one speed: the bias holds the scale too (its partner named)
    assert held.identifiable and held.confounded_with == "tas_kt.scale", (held.estimate, held.reason)
    assert abs(held.estimate - truth) <= max(3 * held.se, 0.5), (held.estimate, held.se, truth)
    assert held.z >= 10 and 0.1 <= held.se <= 1.0, (held.estimate, held.se)
    scale = by["tas_kt.scale"]  # the other reading of the same data
    assert abs(scale.estimate - 0.03) <= max(3 * scale.se, 0.003), (scale.estimate, scale.se)
    assert not {p.name for p in res.applied} - {"tas_kt.bias", "tas_kt.scale"}, res.summary()


def test_logs_that_all_turn_leave_the_airspeed_error_unmeasured(tmp_path):
    """The gusts' prior comes from straight logs: with none, the airspeed error is not claimed."""
    text = (
        'name = "turns"\n[maneuvers.level_turn]\nheading_deg = 90.0\n'
        '[[points]]\ngear = "up"\nflap_deg = 0\nmach = [0.3, 0.4]\nalt_ft = 10000\nmaneuvers = ["level_turn"]\n'
    )
    res = estimate(load_data(run_matrix(tmp_path, text, str(DEFAULT_AIRCRAFT), noise="flight-test", seed=5)))
    by = {p.name: p for p in res.parameters}
    for name in ("tas_kt.bias", "tas_kt.scale"):
        assert not by[name].identifiable and "straight log" in by[name].reason, (name, by[name].reason)


def test_a_correction_chosen_over_its_confounded_partner_keeps_its_uncertainty():
    """The reach of instrument errors counts every correction applied. A vane scale the kinematics
    cannot tell from the vane's bias, chosen by the CL residual (the bias held at 0), is applied
    with the standard error of that reading; the covariance blocks hold only the bias. Left out,
    a 6.3 % scale corrected as 7.0 +- 0.8 % named "CL vs alpha" with nothing hidden."""
    from identify.compat.result import CompatResult, Parameter

    bias = Parameter(
        "alpha_deg",
        "bias",
        "deg",
        0.61,
        0.06,
        reason="confounded with alpha_deg.scale: the estimate holds both (not applied)",
        confounded_with="alpha_deg.scale",
    )
    scale = Parameter(
        "alpha_deg",
        "scale",
        "-",
        0.070,
        0.008,
        reason="not separable from alpha_deg.bias",
        confounded_with="alpha_deg.bias",
    )
    q = Parameter("q_dps", "bias", "deg/s", 0.05, 0.002)
    compat = CompatResult(
        [bias, scale, q], covariance=[(["alpha_deg.bias", "q_dps.bias"], np.diag([0.06, 0.002]) ** 2)]
    )
    names, cov = compat.uncertainty()
    assert ("alpha_deg", "scale") not in names  # not applied: the reach leaves it to the residuals
    names, cov = compat.choose("alpha_deg.scale", "the CL residual agrees").uncertainty()
    assert names[:2] == [("alpha_deg", "bias"), ("q_dps", "bias")]
    assert ("alpha_deg", "scale") in names
    np.testing.assert_allclose(np.sqrt(cov[names.index(("alpha_deg", "scale"))].max()), 0.008)
    np.testing.assert_allclose(np.diag(cov)[:2], [0.06**2, 0.002**2])


def test_no_instrument_error_is_taken_as_larger_than_plausible():
    """A sideslip vane's bias the kinematics hardly measure (+- 10 deg, correlated with an accelerometer
    bias) counts with the standard error that puts the plausible 5 deg at 2 of them, its correlation kept;
    a well-measured error keeps its own."""
    from identify.compat.result import CompatResult, Parameter

    beta = Parameter("beta_deg", "bias", "deg", 5.4, 10.3)
    ay = Parameter("ay_fps2", "bias", "ft/s^2", 0.0002, 0.0004)
    cov = np.array([[10.3**2, 0.5 * 10.3 * 0.0004], [0.5 * 10.3 * 0.0004, 0.0004**2]])
    compat = CompatResult([beta, ay], covariance=[(["beta_deg.bias", "ay_fps2.bias"], cov)])
    names, raw = compat.uncertainty()
    np.testing.assert_allclose(raw, cov)
    names, capped = compat.uncertainty(plausible_at=2.0)
    assert names == [("beta_deg", "bias"), ("ay_fps2", "bias")]
    np.testing.assert_allclose(np.sqrt(np.diag(capped)), [2.5, 0.0004])
    np.testing.assert_allclose(capped[0, 1] / np.sqrt(capped[0, 0] * capped[1, 1]), 0.5)


def test_a_correction_the_logs_do_not_all_carry_is_not_applied_on_the_kinematics_word_alone(tmp_path):
    """The A320 in 1.5 ft/s with no instrument error (seed 5,800,246 of the detection
    curve, a null that named "Cm vs alpha" beside a vane scale and bias). The one-step jackknife put
    the vane scale at +2.5 % +- 0.24 % and the bias at -0.10 +- 0.013 deg: both applied on the
    kinematics' word alone. Made again with each log left out, the estimate's own choices move
    with the log, and the spread is 5 to 10 times larger: neither is applied."""
    import jsbsim

    from campaign.diagnosis.run import split
    from campaign.validation.support import matrix_toml, pairs

    a320 = matrix_toml(pairs((0, 0.3, 5000), (0, 0.4, 10000), (0, 0.5, 10000), (15, 0.3, 5000)), "a320")
    prof = tmp_path / "turbulence.toml"
    prof.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 1.5\n')
    folder = str(Path(jsbsim.get_default_root_dir()) / "aircraft" / "A320")
    train, _ = split(load_data(run_matrix(tmp_path, a320, folder, noise=str(prof), seed=5_800_246)))
    res = estimate(train, jobs=2)
    for name in ("alpha_deg.scale", "alpha_deg.bias"):
        p = res.get(name)
        assert p.identifiable and abs(p.estimate) / p.se_one_step >= 5.0, (name, p.estimate, p.se_one_step)
        assert p.se > 3 * p.se_one_step and not p.applied, res.summary()
    doc = res.to_dict()
    assert (
        doc["parameters"][[q["channel"] + "." + q["error"] for q in doc["parameters"]].index("alpha_deg.scale")][
            "se_one_step"
        ]
        is not None
    )
    assert "one-step jackknife" in res.summary()


def test_the_estimate_is_the_same_bit_for_bit_without_its_shortcuts_and_as_if_converged_further(tmp_path, monkeypatch):
    """The estimate differences a Jacobian column in an air-data error on that channel's rows alone and
    keeps the attitude of its last few evaluations. Without either (every column differenced on every
    row, nothing kept) it gives the same estimates, standard errors and covariances, bit for bit (3 ft/s:
    the vane's delay moves); with the Jacobian of each fit's last point computed again, the same estimates
    and standard errors within 1e-4 of themselves (2e-5). Its fits stop where a step gains a millionth of
    the cost: fits taken on to a gain of 1e-12 make the same decisions, and move no estimate or standard
    error by a thousandth of the standard error. A jackknife replicate computes the other reading of two
    errors the data cannot tell apart only for an error it reads, and reads every other the same, bit for
    bit."""
    import identify.compat.fit as fit
    import identify.compat.reconstruction as rc

    prof = tmp_path / "p.toml"
    prof.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 3.0\n')
    logs = load_data(run_matrix(tmp_path, DIAG_MATRIX, str(DEFAULT_AIRCRAFT), noise=str(prof), seed=3))

    def seen(res) -> str:
        return repr([(p.name, p.estimate, p.se, p.identifiable, p.reason) for p in res.parameters]) + repr(
            [(names, cov.tobytes()) for names, cov in res.covariance]
        )

    fast = estimate(logs)
    assert fast.get("alpha_deg.delay").estimate != 0.0
    solve = fit._solve_stage
    monkeypatch.setattr(fit, "_solve_stage", lambda *a, column=None, **k: solve(*a[:17], **k))
    monkeypatch.setattr(fit, "KEPT_EVALUATIONS", 0)
    assert seen(estimate(logs)) == seen(fast)
    monkeypatch.setattr(rc, "REUSE_LAST_JACOBIAN", False)
    fresh = estimate(logs)  # the blocks of the last point with its own Jacobian: the same estimates
    assert [(p.name, p.estimate, p.identifiable, p.reason) for p in fresh.parameters] == [
        (p.name, p.estimate, p.identifiable, p.reason) for p in fast.parameters
    ]
    assert max(abs(p.se / q.se - 1.0) for p, q in zip(fast.parameters, fresh.parameters) if q.se > 0) < 1e-4
    monkeypatch.setattr(rc, "CONVERGED", 1e-12)
    further = estimate(logs)
    assert [(p.name, p.identifiable, p.reason) for p in further.parameters] == [
        (p.name, p.identifiable, p.reason) for p in fast.parameters
    ]
    moved = {
        p.name: (abs(p.estimate - q.estimate) / q.se, abs(p.se - q.se) / q.se)
        for p, q in zip(fast.parameters, further.parameters)
        if q.identifiable
    }
    assert moved and max(max(m) for m in moved.values()) < 1e-3, moved
    monkeypatch.undo()
    # a jackknife replicate reads only the corrections applied: the other reading of a confounded error is
    # computed only if that error is one of them
    every = estimate(logs[1:], replicate=True)
    paired = [p.name for p in every.parameters if p.confounded_with and p.identifiable]
    plain = frozenset(p.name for p in every.parameters if p.identifiable and not p.confounded_with)

    def read(res, names):
        return [(n, res.get(n).estimate, res.get(n).se, res.get(n).identifiable) for n in sorted(names)]

    some = estimate(logs[1:], replicate=True, wanted=plain)
    skipped = [n for n in paired if not some.get(n).identifiable]
    assert skipped and plain and read(some, plain) == read(every, plain), every.summary()
    both = plain | {skipped[0]}
    assert read(estimate(logs[1:], replicate=True, wanted=both), both) == read(every, both)
