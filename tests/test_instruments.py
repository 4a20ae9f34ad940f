"""Instrument profiles, turbulence and the derived pitch acceleration.

What the instrumentation records is checked against the flight JSBSim flew
(the recording never disturbs it): positions, lags, delays, scale and bias,
rate, omitted channels and noise; turbulence against its own definition and
against the wind JSBSim reports; bad profiles give one line and write nothing.
"""

import json

import numpy as np
import pandas as pd
import pytest

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, AircraftSource, load_effects
from campaign.cli import main
from campaign.simulation.engine import DT_S, FlightConfig, fly
from campaign.simulation.instruments import load_profile, record
from campaign.simulation.matrix import StatusPoint
from campaign.simulation.turbulence import dryden_gusts, scales
from identify.coefficients import coefficients
from identify.models import lowpass
from diagnose.residuals import kept
from campaign.validation.support import one_line_error

SHORT = (("doublet", (("tail_s", 2.0),)), ("gear_extension", (("post_s", 5.0),)))
POINT = StatusPoint(5000.0, 0.4, 0, False)


def _fly(instruments="none", point=POINT, maneuver="doublet", params=SHORT, **kw):
    cfg = FlightConfig(AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(None)), 0, instruments, params, (), **kw)
    return fly(point, maneuver, cfg)


def _profile(tmp_path, text: str, name="p.toml"):
    p = tmp_path / name
    p.write_text(text)
    return load_profile(p)


@pytest.fixture(scope="module")
def truth():
    """A 2-3-1-1 at JSBSim's rate, perfect instruments, still air."""
    return _fly()


def test_sensors_see_the_flight_where_they_sit(truth, tmp_path):
    """A vane 62 ft ahead reads atan((w - q x)/u); an accelerometer there adds -qdot x + p r x to az;
    lag, delay, scale and bias act as written; the recording leaves the flight alone."""
    boom = _fly(
        _profile(
            tmp_path,
            "[channels.alpha_deg]\nposition_ft = [62.0, 0.0, 0.0]\n"
            "[channels.az_fps2]\nposition_ft = [62.0, 0.0, 0.0]\n",
        )
    )
    t, log = truth.log, boom.log
    assert np.array_equal(t.theta_deg, log.theta_deg) and np.array_equal(t.q_dps, log.q_dps)
    v = t.tas_kt * 1.6878098571011957
    a, b, q = np.radians(t.alpha_deg), np.radians(t.beta_deg), np.radians(t.q_dps)
    u, w = v * np.cos(a) * np.cos(b), v * np.sin(a) * np.cos(b)
    want = np.degrees(np.arctan2(w - q * 62.0, u))
    assert np.abs(log.alpha_deg - want).max() < 1e-9
    assert np.abs(log.alpha_deg - t.alpha_deg).max() > 0.1  # the pitch rate shows at the boom
    pr = np.radians(t.p_dps) * np.radians(t.r_dps)
    want_az = t.az_fps2 - np.radians(t.qdot_dps2) * 62.0 + pr * 62.0
    # JSBSim's qdot is its body-axis angular acceleration, qidot the inertial one: equal to 1e-6 here
    assert np.abs(log.az_fps2 - want_az).max() < 1e-3
    assert np.abs(log.az_fps2 - t.az_fps2).max() > 0.5

    p = _profile(
        tmp_path,
        "[channels.theta_deg]\nlag_s = 0.4\n[channels.q_dps]\ndelay_s = 0.1\n"
        "[channels.alpha_deg]\nscale = 1.05\nbias = 0.5\n",
        "e.toml",
    )
    rec = record(t, None, p, DT_S, np.random.default_rng(0))
    x, y = t.theta_deg.to_numpy(), rec.theta_deg.to_numpy()
    ode = 0.4 * np.gradient(y, DT_S) + y - x  # tau dy/dt + y = x
    assert np.abs(ode[5:-5]).max() < 2e-3 * np.ptp(x) and np.abs(y - x).max() > 0.05
    assert np.allclose(rec.q_dps, np.interp(t.t_s - 0.1, t.t_s, t.q_dps), atol=1e-12)
    assert np.allclose(rec.alpha_deg, 1.05 * t.alpha_deg + 0.5, atol=1e-12)
    assert rec.drop(columns=["theta_deg", "q_dps", "alpha_deg"]).equals(
        t.drop(columns=["theta_deg", "q_dps", "alpha_deg"])
    )


def test_rate_omit_and_noise(truth, tmp_path):
    p = _profile(tmp_path, 'rate_hz = 40\nomit = ["qdot_dps2", "beta_deg"]\n[channels.alt_ft]\nnoise = 2.0\n')
    rec = record(truth.log, None, p, DT_S, np.random.default_rng(1))
    assert "qdot_dps2" not in rec and "beta_deg" not in rec
    assert np.allclose(np.diff(rec.t_s), 1 / 40) and rec.t_s.iloc[-1] <= truth.log.t_s.iloc[-1]
    at = lambda c: np.interp(rec.t_s, truth.log.t_s, truth.log[c])  # noqa: E731
    # the anti-alias filter passes the flight (the 2-3-1-1 lives below 2 Hz) and sampled gear/mass stay exact
    assert np.abs(rec.theta_deg - at("theta_deg")).max() < 0.01
    assert np.array_equal(rec.gear_norm, at("gear_norm"))
    assert (rec.alt_ft - at("alt_ft")).std() == pytest.approx(2.0, rel=0.1)
    again = record(truth.log, None, p, DT_S, np.random.default_rng(1))
    assert rec.equals(again)  # seeded: bit for bit


def test_flight_test_profile_is_what_the_readme_says():
    p = load_profile("flight-test")
    assert p.rate_hz == 50 and p.omit == ("qdot_dps2",) and p.sigma_fps == 1.5
    assert p.sensor("alpha_deg").position_ft == (62.0, 0.0, 0.0) and p.sensor("alpha_deg").noise == 0.05
    assert all(s.bias == 0 and s.scale == 1 and s.delay_s == 0 for _, s in p.sensors)  # calibrated
    assert load_profile("none").sensors == () and load_profile("none").rate_hz is None


def test_a_user_profile_extends_a_shipped_one(tmp_path):
    p = _profile(tmp_path, 'extends = "flight-test"\n[channels.alpha_deg]\nbias = 0.3\n[turbulence]\nsigma_fps = 0\n')
    base = load_profile("flight-test")
    a = p.sensor("alpha_deg")
    assert a.bias == 0.3 and a.noise == 0.05 and a.position_ft == (62.0, 0.0, 0.0)
    assert p.sigma_fps == 0.0 and p.rate_hz == 50 and p.sensor("q_dps") == base.sensor("q_dps")
    assert p.name == "p.toml" and p.sha256 != base.sha256
    assert _profile(tmp_path, 'extends = "flight-test"\n', "q.toml").sha256 == base.sha256  # what it does, not its name


BAD = [
    ("colour = 3\n", "colour"),
    ("[channels.alpha_vane]\nnoise = 0.1\n", "channels.alpha_vane"),
    ("[channels.alpha_deg]\nnoise = -0.1\n", "channels.alpha_deg.noise"),
    ("[channels.alpha_deg]\nnoise = 'high'\n", "channels.alpha_deg.noise"),
    ("[channels.alpha_deg]\nposition_ft = [62, 0]\n", "channels.alpha_deg.position_ft"),
    ("[channels.q_dps]\nposition_ft = [1, 0, 0]\n", "channels.q_dps.position_ft"),
    ("[channels.alpha_deg]\nlag = 0.1\n", "channels.alpha_deg.lag"),
    ('omit = ["alpha_deg"]\n', "omit"),
    ('extends = "wind-tunnel"\n', "extends"),
    ("rate_hz = 0\n", "rate_hz"),
    ("[turbulence]\nsigma_fps = -1\n", "turbulence.sigma_fps"),
    ("[turbulence]\nseverity = 3\n", "turbulence.severity"),
    ("rate_hz = = 50\n", "does not parse"),
]


@pytest.mark.parametrize("text, key", BAD, ids=[k for _, k in BAD])
def test_bad_profiles_are_one_line_and_fly_nothing(tmp_path, capsys, small_matrix, text, key):
    bad = tmp_path / "bad.toml"
    bad.write_text(text)
    out = tmp_path / "out"
    one_line_error(
        capsys,
        ["fly", "h02000_m0.30_f00_gup", "--matrix", str(small_matrix), "--out", str(out), "--instruments", str(bad)],
        "bad.toml",
        key,
    )
    assert not out.exists()


def test_resume_with_another_profile_is_refused(tmp_path, capsys, small_matrix):
    out = tmp_path / "c"
    argv = ["run", "--matrix", str(small_matrix), "--out", str(out), "--no-identify"]
    assert main(argv + ["--noise", "flight-test"]) == 0
    man = json.loads((out / "manifest.json").read_text())
    assert man["settings"]["instruments"] == "flight-test"
    assert man["hashes"]["instruments"] == load_profile("flight-test").sha256
    assert man["instruments"]["turbulence"]["sigma_fps"] == 1.5
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    other = tmp_path / "other.toml"
    other.write_text('extends = "flight-test"\n[channels.alpha_deg]\nbias = 0.5\n')
    capsys.readouterr()
    one_line_error(capsys, argv + ["--instruments", str(other)], "manifest.json", "instruments")
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert main(argv + ["--noise", "flight-test"]) == 0  # the same profile resumes: nothing to fly
    assert {p: p.read_bytes() for p in out.glob("*.parquet")} == {
        p: b for p, b in before.items() if p.suffix == ".parquet"
    }


def test_dryden_gusts_have_the_asked_intensity_and_scale():
    """Stationary from the first step, RMS as asked, autocorrelation exp(-c V tau / L) (MIL-F-8785C)."""
    v, h, sigma = 450.0, 10000.0, 3.0
    g = dryden_gusts(1_500_000, DT_S, v, h, sigma, np.random.default_rng(2))
    l_u, l_w, s_u = scales(h, sigma)
    assert (l_u, l_w, s_u) == (1750.0, 1750.0, sigma)
    assert g[:, 2].std() == pytest.approx(sigma, rel=0.03) and g[:, 0].std() == pytest.approx(s_u, rel=0.03)
    lag = int(round(1.0 / DT_S))  # one second
    for j, c in ((0, 1.0), (2, 2.0)):
        x = g[:, j] - g[:, j].mean()
        rho = float(x[:-lag] @ x[lag:] / (x @ x))
        assert rho == pytest.approx(np.exp(-c * v * 1.0 / l_w), abs=0.02)
    starts = dryden_gusts(2, DT_S, v, h, sigma, np.random.default_rng(np.arange(4000)))
    assert np.std(
        [dryden_gusts(2, DT_S, v, h, sigma, np.random.default_rng(k))[0, 2] for k in range(4000)]
    ) == pytest.approx(sigma, rel=0.05) and starts.shape == (2, 3)
    # low altitude: shorter scales, stronger horizontal gusts
    l_u, l_w, s_u = scales(500.0, sigma)
    assert l_w == 500.0 and l_u > l_w and s_u > sigma
    assert not dryden_gusts(100, DT_S, v, h, 0.0, np.random.default_rng(0)).any()


def test_sigma_fps_is_the_vertical_gust_jsbsim_flies_in(tmp_path):
    """Three and a half minutes of a held gear extension in sigma_fps = 3: JSBSim's own total wind has
    that RMS, and the air data it computes answer to it (wind = inertial - air-relative velocity)."""
    p = _profile(tmp_path, "[turbulence]\nsigma_fps = 3.0\n")
    f = _fly(
        p,
        StatusPoint(10000.0, 0.4, 0, True),
        "gear_extension",
        (("gear_extension", (("post_s", 200.0),)),),
        record_truth=True,
    )
    d = f.log
    assert d.truth_wind_down_fps.std() == pytest.approx(3.0, rel=0.15)
    assert d.truth_wind_north_fps.std() > 1.0 and d.truth_wind_east_fps.std() > 1.0
    from identify.kinematics import measured_wind

    wind = measured_wind(d)  # what the diagnosis's replays fly in
    truth = d[["truth_wind_north_fps", "truth_wind_east_fps", "truth_wind_down_fps"]].to_numpy()
    assert np.abs(wind - truth).max() < 0.05
    # the flight starts in equilibrium with its first gust: trimmed in it, the speed through the air the point's
    assert d.mach.iloc[0] == pytest.approx(0.4, abs=2e-3) and abs(d.q_dps.iloc[0]) < 0.05


def test_derived_pitch_acceleration_costs_little_in_cm(tmp_path):
    """No qdot channel at 50 Hz: the spline derivative of q half a JSBSim frame ahead, through the
    identification's 3 Hz filter, against the true qdot through the same filter."""
    p = _profile(tmp_path, "rate_hz = 50\n")
    worst = []
    for man, point in (("doublet", POINT), ("gear_extension", StatusPoint(3000.0, 0.3, 0, True))):
        f = _fly(p, point, man)
        d = f.log
        true = coefficients(d, f.meta)["Cm"].to_numpy()
        derived = coefficients(d.drop(columns=["qdot_dps2"]), f.meta)["Cm"].to_numpy()
        err = (lowpass(derived, 0.02) - lowpass(true, 0.02))[kept(len(d), 0.02)]
        worst.append((float(np.sqrt(np.mean(err**2))), float(np.abs(err).max())))
    rms, peak = np.max(worst, axis=0)
    assert rms < 1e-5 and peak < 5e-5, worst


def test_the_shipped_profile_flies_and_logs_what_it_says(small_matrix, tmp_path):
    from campaign.orchestration.store import read_log

    assert (
        main(
            [
                "fly",
                "h02000_m0.30_f00_gup",
                "--matrix",
                str(small_matrix),
                "--out",
                str(tmp_path / "o"),
                "--noise",
                "flight-test",
            ]
        )
        == 0
    )
    log, meta = read_log(tmp_path / "o" / "h02000_m0.30_f00_gup__doublet.parquet")
    assert meta["sensor_positions_ft"]["alpha_deg"] == [62.0, 0.0, 0.0]
    assert meta["dt_s"] == 0.02 and "qdot_dps2" not in log
    assert isinstance(log, pd.DataFrame) and {"vn_fps", "ve_fps", "vd_fps", "psi_deg"} <= set(log.columns)
