"""Trim over the whole matrix, the hold tolerances, physical invariants."""

import numpy as np
import pytest

from campaign.simulation import catalog as cat
from campaign.simulation.engine import fly, trimmed_fdm


def test_every_matrix_point_trims_gear_up_and_down(matrix, reference_config):
    failures = []
    for p in matrix.points:
        for gear in (0.0, 1.0) if p.gear_down else (0.0,):
            try:
                fdm, *_, tr = trimmed_fdm(reference_config.aircraft, p, gear)
            except Exception as exc:  # noqa: BLE001 - collect every failure
                failures.append((p.id, gear, str(exc)))
                continue
            assert fdm["gear/gear-pos-norm"] == pytest.approx(gear)
            assert fdm["fcs/flap-pos-deg"] == pytest.approx(p.flap_deg)
            assert abs(fdm["accelerations/udot-ft_sec2"]) < 1e-2
            assert abs(fdm["accelerations/wdot-ft_sec2"]) < 1e-2
            assert abs(fdm["accelerations/qdot-rad_sec2"]) < 1e-4
            assert fdm["velocities/mach"] == pytest.approx(p.mach, abs=1e-6)
            assert tr.elevator_deg == pytest.approx(0.0, abs=1e-9)  # the stabilizer trims
    assert not failures


def test_hold_tolerances_at_every_gear_down_point(matrix, reference_config):
    worst = np.zeros(3)
    for p in (p for p in matrix.points if p.gear_down):
        log = fly(p, "gear_extension", reference_config).log
        d = (log[["alpha_deg", "mach", "alt_ft"]] - log[["alpha_deg", "mach", "alt_ft"]].iloc[0]).abs().max()
        worst = np.maximum(worst, d.to_numpy())
        assert log.gear_norm.iloc[0] == 0.0 and log.gear_norm.iloc[-1] == 1.0
        t_done = log.t_s[log.gear_norm >= 1.0].iloc[0]
        assert log.t_s.iloc[-1] - t_done >= 15.0 - 1e-9
        assert (log.gear_norm[log.t_s < 5.0] == 0.0).all()
    assert worst[0] < 0.3, f"alpha excursion {worst[0]:.3f} deg"
    assert worst[1] < 0.002, f"Mach excursion {worst[1]:.5f}"
    assert worst[2] < 10.0, f"altitude excursion {worst[2]:.2f} ft"


def test_hold_moves_alpha_by_about_dcl_over_cla(matrix, reference_config):
    """The steady alpha change makes up the lift lost to the gear (dCL -0.013),
    less what the elevator and the extra thrust's vertical component give."""
    log = fly(matrix.point("h02000_m0.30_f00_gdn"), "gear_extension", reference_config).log
    before, after = log.iloc[:120].mean(), log.iloc[-120:].mean()
    d_alpha = after.alpha_deg - before.alpha_deg
    d_de = np.radians(after.elevator_deg - before.elevator_deg)
    d_thrust = (after.thrust_lbf - before.thrust_lbf) * np.sin(np.radians(before.alpha_deg))
    cla = 5.5  # per rad at M0.3, from 737.xml
    expected = np.degrees((0.013 - 0.40 * d_de - d_thrust / (before.qbar_psf * 1341.0)) / cla)
    assert d_alpha == pytest.approx(expected, abs=0.003)
    assert abs(d_alpha) < 0.3


def test_doublet_is_2311_scaled_to_stall_margin_with_no_lateral_response(matrix, reference_config):
    f = fly(matrix.point("h02000_m0.30_f00_gup"), "doublet", reference_config)
    log, meta = f.log, f.meta
    de = log.elevator_deg - log.elevator_deg.iloc[0]
    cmd_pulses = [(2.0, 4.0, -1), (4.0, 7.0, 1), (7.0, 8.0, -1), (8.0, 9.0, 1)]
    amp = 3.0 * meta["amplitude_scale"]
    for t0, t1, sign in cmd_pulses:
        settled = de[(log.t_s > t0 + 0.3) & (log.t_s < t1 - 0.01)]
        assert settled.to_numpy() == pytest.approx(sign * amp, abs=1e-6)
    assert (de[log.t_s < 2.0].abs() < 1e-12).all()
    margin = 1 - meta["trim"]["cl"] / 1.45
    assert meta["amplitude_scale"] == pytest.approx(min(1.0, margin / 0.35))
    # Longitudinal input, symmetric aircraft: no lateral-directional response
    # beyond the Earth's rotation seen by inertial gyros (0.0042 deg/s).
    assert log.beta_deg.abs().max() < 1e-3
    assert log.phi_deg.abs().max() < 1e-2
    assert log.p_dps.abs().max() < 6e-3 and log.r_dps.abs().max() < 6e-3
    assert log.ay_fps2.abs().max() < 1e-3
    assert log.alpha_deg.max() - log.alpha_deg.min() > 1.0


def test_doublet_amplitude_shrinks_near_stall(matrix, reference_config):
    near = fly(matrix.point("h05000_m0.20_f15_gup"), "doublet", reference_config).meta
    far = fly(matrix.point("h05000_m0.40_f00_gup"), "doublet", reference_config).meta
    assert near["amplitude_scale"] < 0.6 and far["amplitude_scale"] == 1.0


def test_logged_channels_match_jsbsim_forces(matrix):
    """Eq. (1) from the logged channels against JSBSim's own lift and drag: a lag,
    sign or axis mistake in the log shows here (~1e-2 for a one-step lag)."""
    from tests.conftest import config_for

    cfg = config_for(record_truth=True)
    log = fly(matrix.point("h05000_m0.40_f05_gdn"), "doublet", cfg).log
    a = np.radians(log.alpha_deg)
    qs = log.qbar_psf * 1341.0
    m = log.mass_slug
    cl = (-m * log.az_fps2 * np.cos(a) + (m * log.ax_fps2 - log.thrust_lbf) * np.sin(a)) / qs
    cd = (-(m * log.ax_fps2 - log.thrust_lbf) * np.cos(a) - m * log.az_fps2 * np.sin(a)) / qs
    assert np.max(np.abs(cl - log.truth_fwz_aero_lbf / qs)) < 1e-9
    assert np.max(np.abs(cd - log.truth_fwx_aero_lbf / qs)) < 1e-9


def test_log_metadata_matches_the_models_xml(matrix, reference_config):
    meta = fly(matrix.point("h02000_m0.30_f00_gup"), "doublet", reference_config).meta
    assert meta["inertia_slugft2"] == pytest.approx(
        {"ixx": 935248.38, "iyy": 2482936.0, "izz": 3315718.0, "ixz": 133692.41}
    )
    g = meta["geometry"]
    assert g["S_ft2"] == 1341.0 and g["b_ft"] == 112.57
    assert g["cbar_ft"] == pytest.approx(155.81 / 12)
    assert g["cg_x_in"] == pytest.approx(600 + 0.23 * 155.81, abs=0.01)
    assert g["thrust_z_arm_ft"] == pytest.approx(-3.0)
    assert meta["trim"]["weight_lb"] == pytest.approx(135000.0)


def test_catalog_catches_a_misspelled_property(reference_config, monkeypatch):
    from campaign.errors import UserError
    from campaign.simulation.engine import new_fdm

    fdm = new_fdm(reference_config.aircraft)
    monkeypatch.setitem(cat.STATE_CHANNELS, "mach", ("velocities/mahc", 1.0))
    with pytest.raises(UserError, match="velocities/mahc"):
        cat.check_catalog(cat.catalog_names(fdm), 2, "737")


@pytest.mark.parametrize("post_s", [2.0, 15.0])
def test_gear_transition_ends_post_s_after_travel(matrix, post_s):
    from tests.conftest import config_for

    cfg = config_for()
    cfg = type(cfg)(
        cfg.aircraft, maneuver_params=(("gear_retraction", (("post_s", post_s),)),), clmax_by_flap=cfg.clmax_by_flap
    )
    log = fly(matrix.point("h02000_m0.30_f05_gdn"), "gear_retraction", cfg).log
    assert log.gear_norm.iloc[0] == 1.0
    done = log.t_s[log.gear_norm <= 0.0].iloc[0]
    assert done == pytest.approx(5.0 + 8.0, abs=0.02)  # 5 s trimmed, 8 s travel
    assert log.t_s.iloc[-1] - done == pytest.approx(post_s, abs=1e-9)


@pytest.mark.parametrize("point", ["h02000_m0.30_f05_gdn", "h02000_m0.30_f05_gup"])
def test_doublet_holds_the_trimmed_gear(matrix, reference_config, point):
    log = fly(matrix.point(point), "doublet", reference_config).log
    expected = 1.0 if point.endswith("gdn") else 0.0
    assert (log.gear_norm == expected).all()


@pytest.mark.parametrize("weight", [120000.0, 170000.0])
def test_status_point_weight_is_flown(reference_config, weight):
    from campaign.simulation.matrix import StatusPoint

    log, meta = (lambda f: (f.log, f.meta))(
        fly(StatusPoint(2000.0, 0.35, 5, False, weight, ("doublet",)), "doublet", reference_config)
    )
    assert meta["trim"]["weight_lb"] == pytest.approx(weight)
    assert log.mass_slug.iloc[0] * 32.174049 == pytest.approx(weight, rel=1e-6)
    assert meta["inertia_slugft2"]["iyy"] == pytest.approx(2482936.0)  # the payload sits at the CG


@pytest.mark.parametrize("name", ["doublet", "gear_extension", "gear_retraction", "recorded"])
def test_signal_series_equal_their_values_bit_for_bit(name):
    """The flying loop takes its inputs from ``Signal.series``: it must give ``value(k)``'s floats
    exactly (the logs stay bit-identical), in chunks, past the end and for an empty range."""
    from maneuvers.library import Recorded, make_maneuver

    rng = np.random.default_rng(3)
    m = Recorded(0.0, *(tuple(rng.normal(size=50)) for _ in range(4))) if name == "recorded" else make_maneuver(name)
    prog = m.program(1 / 120, 0.7)
    signals = [s for s in (prog.elevator_deg, prog.stabilizer_deg, prog.gear_cmd, prog.throttle) if s is not None]
    assert len(signals) >= 2
    n = prog.max_steps + 40
    for s in signals:
        want = np.array([s.value(k) for k in range(n)], dtype=float)
        got = np.concatenate([s.series(a, min(a + 97, n)) for a in range(0, n, 97)])
        assert got.tobytes() == want.tobytes()
        assert s.series(5, 5).shape == (0,)
    assert np.ptp(np.array([prog.elevator_deg.value(k) for k in range(n)])) > 0 or name.startswith("gear")


@pytest.mark.parametrize("aircraft", ["ours", "stock 737"])
def test_a_level_turn_circles_once_coordinated_at_its_altitude(reference_config, aircraft):
    """The bank hold flies a full circle from the trimmed speed (heading_deg 360 at 25 deg), with
    the altitude/speed hold on; a longitudinal channel sees the bank's load factor only."""
    from dataclasses import replace
    from pathlib import Path

    import jsbsim

    from campaign.simulation.aircraft import AircraftSource, load_effects
    from campaign.simulation.matrix import StatusPoint

    cfg = (
        reference_config
        if aircraft == "ours"
        else replace(
            reference_config,
            aircraft=AircraftSource(str(Path(jsbsim.get_default_root_dir()) / "aircraft" / "737"), load_effects(None)),
            clmax_by_flap=(),
        )
    )
    f = fly(StatusPoint(alt_ft=10000.0, mach=0.3, flap_deg=0.0, gear_down=False), "level_turn", cfg)
    log, meta = f.log, f.meta
    heading = np.unwrap(np.radians(log.psi_deg))
    turned = np.degrees(heading[-1] - heading[0])
    assert 330.0 <= turned <= 400.0, turned
    assert meta["maneuver_params"]["turn_s"] > 60.0  # set from the trimmed speed, not the default 0
    full = log[(log.t_s > 15.0) & (log.t_s < log.t_s.iloc[-1] - 15.0)]
    assert np.abs(full.phi_deg - 25.0).max() < 2.0
    assert np.abs(log.beta_deg).max() < 1.5  # coordinated
    assert np.abs(log.alt_ft - log.alt_ft.iloc[0]).max() < 60.0
    assert np.abs(log.mach - log.mach.iloc[0]).max() < 0.01
    assert log.gear_norm.eq(0.0).all()
    n = 1.0 / np.cos(np.radians(25.0))  # the load factor of a level turn
    assert -full.az_fps2.mean() / meta["gravity_fps2"] == pytest.approx(n, rel=0.03)


def test_a_level_turn_is_not_an_excitation(tmp_path):
    """Flown for the data compatibility (the air-data calibration): the eq. (3) fits leave it out."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.diagnosis.run import load_data
    from identify.pipeline import identify_logs
    from campaign.validation.support import run_matrix

    text = (
        'name = "turn"\n[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.level_turn]\nheading_deg = 90.0\n'
        '[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.3\nalt_ft = 10000\nmaneuvers = ["doublet", "level_turn"]\n'
        '[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.4\nalt_ft = 2000\nmaneuvers = ["doublet"]\n'
    )
    logs = load_data(run_matrix(tmp_path, text, str(DEFAULT_AIRCRAFT), noise="flight-test", seed=3))
    turn = [lg for lg in logs if lg.maneuver == "level_turn"]
    assert len(turn) == 1 and not turn[0].excitation and not turn[0].transition
    assert all(lg.excitation for lg in logs if lg.maneuver == "doublet")
    fits = identify_logs(logs, compatibility=False).fits
    assert sorted(f.path for f in fits) == sorted(str(lg.path) for lg in logs if lg.excitation)


def test_one_log_is_cut_into_segments_for_its_standard_errors_and_a_short_one_gets_none(tmp_path):
    """The reconstruction's standard errors are the spread between logs: one log is cut into segments that
    stand in for them, and with perfect instruments nothing is corrected; one too short for two segments
    has none (it gave 0, so z = inf, and a correction of nothing but noise was applied)."""
    from dataclasses import replace

    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT
    from campaign.diagnosis.run import load_data
    from identify.compat import estimate
    from campaign.validation.support import run_matrix

    text = (
        'name = "one"\n[maneuvers.doublet]\ntail_s = 2.0\n'
        '[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.3\nalt_ft = 10000\nmaneuvers = ["doublet"]\n'
    )
    (log,) = load_data(run_matrix(tmp_path, text, str(DEFAULT_AIRCRAFT), noise="flight-test", seed=3))
    res = estimate([log])
    assert res.segments >= 2 and not res.applied, res.summary()
    res = estimate([replace(log, data=log.data[log.data.t_s < log.data.t_s.iloc[0] + 12.0])])
    assert not res.applied and not res.segments
    assert all(not p.identifiable and "shorter than 4 segments" in p.reason for p in res.parameters)
    said = [line for line in res.summary().splitlines() if "not identifiable" in line]
    assert len(said) == 1 and said[0].split()[:2] == ["every", "error"], said  # once, not for each error
