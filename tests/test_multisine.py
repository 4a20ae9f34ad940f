"""Multisine inputs: orthogonal, low peak factor, zero at both ends, in the band, scaled like the
2-3-1-1; flown, they excite no lateral motion and identify the model's own derivatives."""

import numpy as np
import pytest

from campaign.errors import UserError
from campaign.simulation.matrix import load_matrix
from maneuvers.library import Multisine, make_maneuver
from maneuvers.multisine import multisine_signals, relative_peak_factor
from campaign.validation.support import matrix_toml, pairs

DT = 1 / 120


@pytest.mark.parametrize(
    "duration_s, f_lo, f_hi, rpf_max",
    [(12.0, 0.1, 1.5, 1.03), (20.0, 0.1, 1.5, 1.03), (12.0, 0.05, 2.0, 1.03), (18.0, 0.1, 0.5, 1.13)],
)
def test_multisines_are_orthogonal_flat_and_zero_at_both_ends(duration_s, f_lo, f_hi, rpf_max):
    """Relative peak factors: about 1.0 with 8 harmonics or more per input; with the default's 4 (the
    short period's band on our 737), 1.02 and 1.13."""
    n = int(round(duration_s / DT))
    sigs, rpf = multisine_signals(n, DT, f_lo, f_hi, (3.0, 1.0), start=10)
    u = [s.series(0, n + 20) for s in sigs]
    assert max(rpf) <= rpf_max, rpf
    for s, x, peak in zip(sigs, u, (3.0, 1.0)):
        assert np.max(np.abs(x)) == pytest.approx(peak, rel=1e-9)
        assert x[:10].tolist() == [0.0] * 10 and x[10 + n :].tolist() == [0.0] * 10
        assert abs(x[10]) < 1e-9 * peak  # starts at zero; periodic in T, so it ends there too
        assert relative_peak_factor(x[10 : 10 + n]) == pytest.approx(rpf[sigs.index(s)], rel=1e-9)
        # its energy is at its own harmonics of 1/T, in the band, and nowhere else
        spec = np.abs(np.fft.rfft(x[10 : 10 + n])) ** 2
        own = np.zeros(len(spec), bool)
        own[list(s.harmonics)] = True
        assert spec[~own].sum() < 1e-20 * spec.sum() + 1e-18
        assert min(s.harmonics) >= f_lo * duration_s - 1e-9 and max(s.harmonics) <= f_hi * duration_s + 1e-9
    assert set(sigs[0].harmonics).isdisjoint(sigs[1].harmonics)
    assert sorted(sigs[0].harmonics + sigs[1].harmonics) == list(
        range(min(sigs[0].harmonics), max(sigs[0].harmonics + sigs[1].harmonics) + 1)
    )
    assert abs(u[0] @ u[1]) < 1e-9 * np.sqrt((u[0] @ u[0]) * (u[1] @ u[1]))  # orthogonal over T
    assert [sigs[0].value(k) for k in range(5, 40)] == sigs[0].series(5, 40).tolist()


def test_the_program_scales_with_the_stall_margin_and_composes():
    m = make_maneuver("multisine", duration_s=10.0, f_hi_hz=1.0, lead_s=1.0, tail_s=3.0)
    full, half = m.program(DT, 1.0), m.program(DT, 0.5)
    assert full.n_steps == half.n_steps == round(14 / DT) and not full.hold and full.gear_cmd is None
    e, e2 = full.elevator_deg.series(0, full.n_steps), half.elevator_deg.series(0, half.n_steps)
    assert np.max(np.abs(e)) == pytest.approx(3.0) and np.allclose(e2, 0.5 * e)
    assert np.max(np.abs(full.stabilizer_deg.series(0, full.n_steps))) == pytest.approx(1.0)
    alone = Multisine(stabilizer_amplitude_deg=0.0).program(DT)
    assert not np.any(alone.stabilizer_deg.series(0, alone.n_steps))
    import pickle

    assert pickle.loads(pickle.dumps(m)) == m


@pytest.mark.parametrize(
    "table, says",
    [
        ("duration_s = 2.0", "fewer than 2 per input"),
        ("f_lo_hz = 2.0", "0 < f_lo_hz < f_hi_hz"),
        ("amplitude_deg = 12.0", "amplitude_deg"),
        ("period_s = 3.0", "period_s"),
    ],
)
def test_bad_multisine_parameters_name_the_field(tmp_path, table, says):
    p = tmp_path / "m.toml"
    p.write_text(
        matrix_toml(
            pairs((0, 0.3, 5000)),
            "ms",
            '[defaults]\nmaneuvers_gear_up = ["multisine"]\n'
            'maneuvers_gear_down = ["multisine"]\n'
            f"[maneuvers.multisine]\n{table}\n",
        )
    )
    with pytest.raises(UserError) as err:
        load_matrix(p)
    assert str(p) in str(err.value) and "maneuvers.multisine" in str(err.value) and says in str(err.value)


def test_a_flown_multisine_identifies_the_models_own_derivatives(tmp_path):
    """Noise-free, one condition gear up and down: the equation error on the multisine gives the XML's
    derivatives as the 2-3-1-1 does (tests/test_identify.py), and nothing lateral moves."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, AircraftSource, load_effects
    from campaign.simulation.engine import FlightConfig
    from campaign.orchestration.runner import run_campaign
    from identify.logs import read_campaign
    from identify.pipeline import identify_logs

    p = tmp_path / "m.toml"
    p.write_text(
        matrix_toml(
            pairs((0, 0.3, 5000)),
            "ms",
            '[defaults]\nmaneuvers_gear_up = ["multisine"]\nmaneuvers_gear_down = ["multisine"]\n',
        )
    )
    m = load_matrix(p)
    cfg = FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(None)), 0, "none", m.maneuver_params, m.clmax_by_flap
    )
    run_campaign(m, cfg, tmp_path / "out", jobs=2, progress=False)
    logs = read_campaign(tmp_path / "out")
    assert sorted(lg.maneuver for lg in logs) == ["multisine", "multisine"]
    for lg in logs:
        d = lg.data
        for ch in ("beta_deg", "p_dps", "r_dps", "phi_deg"):  # the Earth's rate is in p and r from the start
            assert (d[ch] - d[ch].iloc[0]).abs().max() < 1e-3, ch
        assert d.elevator_deg.max() - d.elevator_deg.min() > 3.0  # the input is there
    arm = (638.95 - 635.84) / 155.81
    for f in identify_logs(logs).fits:
        p = {c: f.fits[c].params for c in ("CL", "Cm")}
        assert p["CL"]["dalpha_rad"] == pytest.approx(5.5, rel=0.005), f.point
        assert p["Cm"]["dalpha_rad"] == pytest.approx(-1.3 - 5.5 * arm, rel=0.005), f.point
        assert p["Cm"]["delevator_rad"] == pytest.approx(-1.4 - 0.40 * arm, rel=0.005), f.point
        assert p["Cm"]["dstabilizer_rad"] == pytest.approx(-3.4 - 0.95 * arm, rel=0.01), f.point
        assert p["Cm"]["qhat_rad"] == pytest.approx(-25.0 - 4.5 * arm, rel=0.01), f.point


def test_a_point_flying_both_baseline_manoeuvres_is_refused(tmp_path):
    p = tmp_path / "m.toml"
    p.write_text(matrix_toml(pairs((0, 0.3, 5000)), "ms", '[defaults]\nmaneuvers_gear_up = ["doublet", "multisine"]\n'))
    with pytest.raises(UserError) as err:
        load_matrix(p)
    assert str(p) in str(err.value) and "defaults.maneuvers_gear_up" in str(err.value)
