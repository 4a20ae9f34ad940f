"""Identification against known truths: the model's XML, JSBSim's own forces,
the stock 737, the reference overlay (read here, never by identify/)."""

import fcntl
import json
import os
import shutil
import subprocess
import sys

import jsbsim
import numpy as np
import pytest

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects
from campaign.cli import main
from campaign.simulation.engine import FlightConfig, fly, new_fdm
from campaign.simulation.matrix import load_matrix
from campaign.orchestration.runner import run_campaign
from identify.coefficients import coefficients
from identify.logs import LogError, read_campaign, read_csv
from identify.pipeline import identify_logs
from campaign.validation.hidden import reference_gear_truth
from campaign.validation.support import matrix_toml, pairs, z_scores

STOCK_737 = os.path.join(jsbsim.get_default_root_dir(), "aircraft", "737")
D2R = np.pi / 180
ARM = (638.95 - 635.84) / 155.81  # AERORP aft of the CG [cbar]

PAIRS = matrix_toml(pairs((0, 0.3, [2000, 10000]), (30, 0.2, 2000)), "pairs")


def _campaign(tmp_path_factory, name, text, aircraft=str(DEFAULT_AIRCRAFT), effects=None, noise="none", seed=0):
    folder = tmp_path_factory.mktemp(name)
    (folder / "m.toml").write_text(text)
    m = load_matrix(folder / "m.toml")
    cfg = FlightConfig(AircraftSource(aircraft, load_effects(effects)), seed, noise, m.maneuver_params, m.clmax_by_flap)
    run_campaign(m, cfg, folder / "out", jobs=2, progress=False)
    return folder / "out"


@pytest.fixture(scope="module")
def bare(tmp_path_factory):
    return identify_logs(read_campaign(_campaign(tmp_path_factory, "bare", PAIRS)))


def test_eq1_cm_matches_jsbsim_moment(matrix):
    from tests.conftest import config_for

    f = fly(matrix.point("h05000_m0.40_f05_gdn"), "doublet", config_for(record_truth=True))
    c = coefficients(f.log, f.meta)
    qsc = f.log.qbar_psf * 1341.0 * 155.81 / 12
    assert np.max(np.abs(c.Cm - f.log.truth_m_aero_lbfft / qsc)) < 1e-9
    assert np.max(np.abs(c.CL - f.log.truth_fwz_aero_lbf / (f.log.qbar_psf * 1341.0))) < 1e-9


def test_eq1_drag_in_sideslip_matches_jsbsim_wind_axis_drag(tmp_path):
    """JSBSim's DRAG is along the airspeed: in sideslip the side force has a share of it. The stock A320
    at flap 15 gear down in 3 ft/s sideslips by about a degree (the benchmark's null 9,404,310, where
    eq. (1b)'s drag was 5.6e-4 to 8.2e-4 below the model's on that condition's gear-down logs, named
    "CD vs flap_deg, gear_norm")."""
    a320 = os.path.join(jsbsim.get_default_root_dir(), "aircraft", "A320")
    (tmp_path / "m.toml").write_text(matrix_toml([("down", 15, 0.3, 5000)], "a320"))
    (tmp_path / "turbulent.toml").write_text("[turbulence]\nsigma_fps = 3.0\n")
    m = load_matrix(tmp_path / "m.toml")
    cfg = FlightConfig(
        AircraftSource(a320, load_effects(None)),
        9_404_310,
        str(tmp_path / "turbulent.toml"),
        m.maneuver_params,
        m.clmax_by_flap,
        record_truth=True,
    )
    f = fly(m.points[0], "doublet", cfg)
    c = coefficients(f.log, f.meta)
    qs = f.log.qbar_psf * f.meta["geometry"]["S_ft2"]
    drag = f.log.truth_fwx_aero_lbf / qs  # JSBSim holds the drag positive
    assert np.max(np.abs(c.CD - drag)) < 1e-9
    body = (
        -(
            f.log.truth_fx_aero_lbf * np.cos(f.log.alpha_deg * D2R)
            + f.log.truth_fz_aero_lbf * np.sin(f.log.alpha_deg * D2R)
        )
        / qs
    )
    assert np.abs(f.log.beta_deg).max() > 0.5 and np.mean(drag - body) > 3e-4  # eq. (1b) alone is off here


def test_fits_recover_the_models_own_derivatives(bare):
    """XML values (per rad, about AERORP); Cm about the CG adds -CL_x * (x_arp - x_cg)/cbar."""
    cla = {0.3: 5.5, 0.2: 5.358}
    for f in bare.fits:
        mach = f.condition[1]
        p = {c: f.fits[c].params for c in ("CL", "CD", "Cm")}
        assert p["CL"]["dalpha_rad"] == pytest.approx(cla[mach], rel=0.005), f.point
        assert p["CL"]["delevator_rad"] == pytest.approx(0.40, rel=0.01), f.point
        assert p["CL"]["dstabilizer_rad"] == pytest.approx(0.95, rel=0.02), f.point
        assert p["CL"]["qhat_rad"] == pytest.approx(4.5, rel=0.1), f.point
        assert p["Cm"]["dalpha_rad"] == pytest.approx(-1.3 - cla[mach] * ARM, rel=0.005), f.point
        assert p["Cm"]["delevator_rad"] == pytest.approx(-1.4 - 0.40 * ARM, rel=0.005), f.point
        assert p["Cm"]["dstabilizer_rad"] == pytest.approx(-3.4 - 0.95 * ARM, rel=0.005), f.point
        assert p["Cm"]["qhat_rad"] == pytest.approx(-25.0 - 4.5 * ARM, rel=0.01), f.point
        assert p["CD"]["dalpha2_rad2"] == pytest.approx(0.045 * cla[mach] ** 2, rel=0.02), f.point
        assert f.fits["CL"].rsquared > 0.9999 and f.fits["Cm"].rsquared > 0.9999
        assert not f.fits["CL"].unexcited.get("dstabilizer_rad")


def test_linear_gear_model_recovers_the_models_increments_within_1pct(bare):
    assert len(bare.linear) == 3
    for cond, m in bare.linear.items():
        a = m.alpha_trim_deg * D2R
        assert m.increment("CL") == pytest.approx(-0.013, rel=0.01), cond
        assert m.increment("CD") == pytest.approx(0.031, rel=0.01), cond
        cm_cg = 0.030 - (-0.013 * np.cos(a) + 0.031 * np.sin(a)) * ARM
        assert m.increment("Cm") == pytest.approx(cm_cg, rel=0.01), cond


def test_stock_737_elevator_lift_and_gear_drag(tmp_path_factory):
    text = matrix_toml(pairs((0, 0.3, [2000, 10000])), "stock")
    ident = identify_logs(read_campaign(_campaign(tmp_path_factory, "stock", text, aircraft=STOCK_737)))
    for f in ident.fits:
        assert f.fits["CL"].params["delevator_rad"] == pytest.approx(0.2, rel=0.02)
        assert "dstabilizer_rad" in f.fits["CL"].unexcited  # the stock 737 has no stabilizer
        assert "dstabilizer_rad" not in f.fits["CL"].params.index
    for m in ident.linear.values():
        assert m.increment("CD") == pytest.approx(0.015, rel=0.02)


def test_flight_test_instruments_keep_95pct_of_parameters_within_3_se(tmp_path_factory, bare):
    """The flight-test installation (50 Hz, no qdot, nose-boom vanes, noise) in still air: the recording
    never disturbs the flight, so the noise-free fit is the truth each estimate must hold within its SE.
    (In turbulence each flight is another trajectory and the trim references move with it.)"""
    still = tmp_path_factory.mktemp("still") / "still.toml"
    still.write_text('extends = "flight-test"\n[turbulence]\nsigma_fps = 0.0\n')
    noisy = identify_logs(read_campaign(_campaign(tmp_path_factory, "noisy", PAIRS, noise=str(still), seed=3)))
    assert noisy.compat is not None and not noisy.compat.applied  # a calibrated installation: nothing to correct
    z = z_scores(bare.fits, noisy.fits)
    assert len(z) > 100
    assert np.mean(z <= 3.0) >= 0.95, f"{np.mean(z <= 3):.3f} within 3 SE"
    assert np.mean(z <= 1.0) < 0.95  # standard errors are not inflated into meaninglessness


def _reference_truth(alpha_deg, gear, mach, fdm_cache={}):  # noqa: B006 (one JSBSim model for the module)
    if "fdm" not in fdm_cache:
        fdm_cache["fdm"] = new_fdm(AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(DEFAULT_EFFECTS)))
    return reference_gear_truth(fdm_cache["fdm"], alpha_deg, gear, mach, ARM)


def _flown_once(tmp_path_factory, name: str, fly):
    """A campaign folder ``fly(folder)`` writes, flown once per test run: pytest-xdist's workers share
    it, the first flying it under a lock while the others wait, then read it (the workers' temporary
    folders sit in one per run); without xdist, in this process's own."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent
    folder, done = root / name, root / f"{name}.done"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            fly(folder)
            done.touch()
    return folder


@pytest.fixture(scope="module")
def reference_gear_down(tmp_path_factory):
    """Every gear-down point of the default matrix (and its gear-up twin) on the reference aircraft."""
    m = load_matrix()
    down = [p for p in m.points if p.gear_down]
    conds = {(p.alt_ft, p.mach, p.flap_deg) for p in down}
    pts = down + [p for p in m.points if not p.gear_down and (p.alt_ft, p.mach, p.flap_deg) in conds]
    cfg = FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(DEFAULT_EFFECTS)),
        0,
        "none",
        m.maneuver_params,
        m.clmax_by_flap,
    )
    folder = _flown_once(
        tmp_path_factory,
        "reference_gear_down",
        lambda out: run_campaign(m, cfg, out, jobs=2, progress=False, points=pts),
    )
    logs = read_campaign(folder)
    return folder, logs, identify_logs(logs)


def test_nonlinear_increments_reproduce_the_overlay_within_5pct_of_peak(reference_gear_down):
    _, _, ident = reference_gear_down
    assert len(ident.increments) == 41
    worst = {}
    for pid, inc in ident.increments.items():
        truth = [_reference_truth(inc.alpha_trim_deg, g, inc.condition[1]) for g in inc.grid]
        for c in ("CL", "CD", "Cm"):
            t = np.array([x[c] for x in truth])
            err = np.max(np.abs(inc.smooth[c] - t)) / np.max(np.abs(t))
            worst[c] = max(worst.get(c, 0.0), err)
    assert max(worst.values()) < 0.05, worst


def test_identification_streams_from_log_heads_to_the_same_answer(reference_gear_down, tmp_path):
    """From the logs' heads (metadata and column names, no samples) each log is read where it is
    fitted, on the workers: the same identification, to the bit, as from every log held at once;
    the fits keep their series only for the points asked, and the increments only the gear's travel."""
    from identify.logs import LogHead, read_heads
    from identify.pipeline import write_outputs

    folder, logs, ident = reference_gear_down
    heads = read_heads(folder)
    assert all(isinstance(h, LogHead) for h in heads) and [h.path for h in heads] == [lg.path for lg in logs]
    assert [h.condition for h in heads] == [lg.condition for lg in logs]
    assert tuple(heads[0].columns) == tuple(logs[0].data.columns)
    keep = ident.fits[0].point
    streamed = identify_logs(heads, jobs=2, series={keep})
    assert [f.t_s is None for f in streamed.fits] == [f.point != keep for f in ident.fits]
    assert all(f.fits["CL"].y is None for f in streamed.fits if f.point != keep)
    for inc in streamed.increments.values():
        assert not inc.raw and np.all((inc.gear_norm > 0) & (inc.gear_norm < 1))
    for name, result in (("held", ident), ("streamed", streamed)):
        write_outputs(result, tmp_path / name, None, plots="none")
    for f in (
        "identification.json",
        "baseline_parameters.csv",
        "baseline_fit_statistics.csv",
        "linear_gear_model.csv",
        "gear_increments.csv",
        "summary.txt",
        "gear_nonlinear.xml",
    ):
        assert (tmp_path / "held" / f).read_bytes() == (tmp_path / "streamed" / f).read_bytes(), f


def test_exported_xml_flies_exactly_the_identified_model(reference_gear_down, tmp_path):
    """Round trip: the model with its gear terms replaced by the export, loaded in
    JSBSim, gives the identified increments at states inside the tables."""
    folder, logs, ident = reference_gear_down
    from identify.pipeline import write_outputs

    files = write_outputs(ident, tmp_path / "id", DEFAULT_AIRCRAFT, plots="none")
    for kind, surface in (("linear", ident.linear_surface), ("nonlinear", ident.nonlinear_surface)):
        src = AircraftSource(files[f"aircraft_{kind}"], load_effects(None))
        fdm = new_fdm(src)
        rng = np.random.default_rng(1)
        for _ in range(12):
            flap = int(rng.choice(surface.flaps))
            (a_lo, a_hi), (m_lo, m_hi) = surface.table_range(flap)
            alpha, mach, gear = rng.uniform(a_lo, a_hi), rng.uniform(m_lo, m_hi), rng.uniform(0, 1)
            states = {}
            for g in (0.0, gear):
                theta = 2 / np.pi * np.arcsin(g)
                for k, v in {
                    "ic/h-sl-ft": 5000.0,
                    "ic/mach": mach,
                    "ic/alpha-deg": alpha,
                    "gear/gear-cmd-norm": theta,
                    "gear/theta-lg-norm": theta,
                    "fcs/flap-cmd-norm": [0, 1, 2, 5, 10, 15, 25, 30, 40].index(flap) / 8,
                    "fcs/flap-pos-norm": [0, 1, 2, 5, 10, 15, 25, 30, 40].index(flap) / 8,
                }.items():
                    fdm[k] = v
                fdm.run_ic()
                states[g] = (
                    fdm["forces/fwz-aero-lbs"],
                    fdm["forces/fwx-aero-lbs"],
                    fdm["moments/m-aero-lbsft"],
                    fdm["aero/qbar-psf"] * 1341.0,
                    fdm["aero/alpha-deg"],
                )
            (l1, d1, m1, qs, a1), (l0, d0, m0, *_) = states[gear], states[0.0]
            want = {c: surface(c, gear, a1, mach, flap) - surface(c, 0.0, a1, mach, flap) for c in ("CL", "CD", "Cm")}
            assert (l1 - l0) / qs == pytest.approx(want["CL"], abs=1e-9)
            assert (d1 - d0) / qs == pytest.approx(want["CD"], abs=1e-9)
            assert (m1 - m0) / (qs * 155.81 / 12) == pytest.approx(want["Cm"], abs=1e-9)


def test_identify_cli_writes_tables_json_xml_plots(reference_gear_down, capsys, tmp_path):
    folder, _, _ = reference_gear_down
    out = tmp_path / "id"
    assert main(["identify", str(folder), "--out", str(out)]) == 0
    for name in (
        "baseline_parameters.csv",
        "baseline_fit_statistics.csv",
        "linear_gear_model.csv",
        "gear_increments.csv",
        "summary.txt",
        "gear_linear.xml",
        "gear_nonlinear.xml",
        "plots/gear_increments.png",
        "plots/alpha_during_gear_transitions.png",
        "plots/fit_h02000_m0.30_f00_gup.png",
    ):
        assert (out / name).stat().st_size > 0, name
    doc = json.loads((out / "identification.json").read_text())
    pt = doc["points"]["h02000_m0.30_f00_gdn"]
    assert set(pt["CL"]) >= {"params", "bse", "rsquared", "resid_max", "resid_rms", "unexcited"}
    inc = doc["increments"]["h02000_m0.30_f00_gdn"]
    assert len(inc["gear_norm"]) == len(inc["dCD"]) == len(inc["dCL"]) == len(inc["dCm"])
    assert set(doc["linear"]["h02000_m0.30_f00"]["C0_gearDn"]) == {"CL", "CD", "Cm"}
    assert "Table 2 style" in (out / "summary.txt").read_text()
    capsys.readouterr()
    assert main(["identify", str(folder / "nope")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and err.count("\n") == 1


def test_csv_logs_with_sidecar_and_their_errors(reference_gear_down, tmp_path):
    _, logs, _ = reference_gear_down
    log = logs[0]
    csv = tmp_path / "a.csv"
    log.data.to_csv(csv, index=False)
    csv.with_suffix(".json").write_text(json.dumps(log.meta))
    back = read_csv(csv)
    assert np.allclose(back.data.alpha_deg, log.data.alpha_deg)
    bad = log.data.copy()
    bad["alpha_deg"] = bad["alpha_deg"].astype(object)
    bad.loc[7, "alpha_deg"] = "oops"
    bad.to_csv(csv, index=False)
    with pytest.raises(LogError, match=r"a.csv: column 'alpha_deg', row 8"):
        read_csv(csv)
    log.data.drop(columns=["qbar_psf"]).to_csv(csv, index=False)
    with pytest.raises(LogError, match="qbar_psf"):
        read_csv(csv)
    radians = log.data.copy()
    radians["alpha_deg"] = radians["alpha_deg"] * 57.3  # a unit mistake
    radians.to_csv(csv, index=False)
    with pytest.raises(LogError, match=r"column 'alpha_deg', row \d+: .* outside -30..60"):
        read_csv(csv)


def test_identify_never_imports_the_flying_code():
    code = (
        "import sys, identify.pipeline, identify.plots, diagnose.diagnosis, diagnose.extension, "
        "infra.model, identify.kinematics, diagnose.residuals, diagnose.noise_floor, "
        "diagnose.plots, diagnose.evaluate; "
        "bad = [m for m in sys.modules if m.split('.')[0] in ('campaign', 'maneuvers', 'jsbsim')]; "
        "assert not bad, bad"
    )
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0


def _fit_args(scale, n):
    from types import SimpleNamespace

    t = np.linspace(0.0, n / 10.0, n)
    fits = {
        c: SimpleNamespace(
            fitted=scale * np.sin(t + i),
            y=scale * np.sin(t + i) + 0.01 * np.cos(9 * t),
            resid=0.01 * scale * np.cos(9 * t),
            resid_max=0.01 * scale,
            resid_rms=0.007 * scale,
            rsquared=0.999,
        )
        for i, c in enumerate(("CL", "CD", "Cm"))
    }
    return (SimpleNamespace(fits=fits, point=f"p{n}", gear_down=n > 100), t)


def _history_args(scale, n):
    import pandas as pd

    t = np.linspace(0.0, n / 10.0, n)
    frame = pd.DataFrame(
        {"t_s": t, **{f"r_{c}": scale * np.sin(t * (i + 1)) for i, c in enumerate(("CL", "CD", "Cm"))}}
    )
    return (frame, frame * 0.5 if n > 100 else None, f"held out {n}")


def _response_args(scale, n):
    import pandas as pd

    t = np.linspace(0.0, n / 10.0, n)
    frame = pd.DataFrame(
        {
            "t_s": t,
            **{
                c: 100.0 * i + scale * np.sin(t)
                for i, c in enumerate(("theta_deg", "alpha_deg", "q_dps", "tas_kt", "alt_ft"))
            },
        }
    )
    return (frame, frame * 1.01, None if n > 100 else frame * 0.99, f"response {n}")


@pytest.mark.parametrize("kind", ["fit", "residual_history", "response"])
def test_a_figure_drawn_on_reused_axes_equals_a_new_one(tmp_path, kind):
    """Fit, residual-history and response figures are drawn, one after another, on one emptied
    figure per process: the second must show nothing of the first (lines, legend, limits)."""
    import matplotlib.pyplot as plt

    from diagnose import plots as dp
    from identify import plots as ip
    from identify.figures import emptied_axes

    plot, size, layout, make = {
        "fit": (ip.plot_fit, ip.FIT_SIZE, ip.fit_axes, _fit_args),
        "residual_history": (dp.plot_residual_history, dp.HISTORY_SIZE, dp.history_axes, _history_args),
        "response": (dp.plot_response, dp.RESPONSE_SIZE, dp.response_axes, _response_args),
    }[kind]
    for i, args in enumerate((make(50.0, 300), make(0.2, 40))):
        plot(*args, axes=emptied_axes(f"test_{kind}", size, layout)).savefig(tmp_path / f"reused{i}.png", dpi=90)
        fig = plot(*args)
        fig.savefig(tmp_path / f"new{i}.png", dpi=90)
        plt.close(fig)
        assert np.array_equal(plt.imread(tmp_path / f"reused{i}.png"), plt.imread(tmp_path / f"new{i}.png"))


@pytest.mark.parametrize("shape", [(40,), (1400,), (1400, 3), (3360, 7)])
def test_lowpass_is_scipys_filtfilt_to_the_bit(shape):
    """lowpass computes filtfilt's steady-state start once per filter: the same numbers as scipy's own."""
    from scipy.signal import butter, filtfilt

    from identify.kinematics import ANCHOR_S, odd_extension
    from identify.models import CUTOFF_HZ, lowpass

    x = np.random.default_rng(len(shape)).standard_normal(shape).cumsum(axis=0)
    for dt in (0.02, 1 / 120):
        b, a = butter(4, CUTOFF_HZ * 2.0 * dt)
        pad = min(len(x) - 1, 3 * max(len(a), len(b)) * 20)
        for layout in (x, np.asfortranarray(x)):  # the last bits depend on the memory layout, in scipy's too
            ext = odd_extension(layout, pad, int(round(ANCHOR_S / dt)))
            assert np.array_equal(lowpass(layout, dt), filtfilt(b, a, ext, axis=0, padtype=None)[pad : pad + len(x)])


@pytest.mark.parametrize("n", [0, 1, 5])
def test_outputs_written_piece_by_piece_equal_the_whole_to_the_byte(tmp_path, n):
    """identification.json's points and the CSV tables are written one point (one chunk) at a time, so
    that thousands of points are never held together: the bytes must be those of the whole written at once."""
    import io
    import json

    import pandas as pd

    from identify.pipeline import _LATER, _csv_in_chunks, _dump_streaming

    points = [
        (
            f"p{i}",
            {
                "gear": "up",
                "CL": {"params": {"const": 0.1 * i, "q": float("nan")}, "nobs": i, "unexcited": {}},
                "list": [1.5, i],
            },
        )
        for i in range(n)
    ]
    doc = {
        "points": dict(points),
        "linear": {"a": [1, 2]},
        "increments": dict(points[:2]),
        "notes": ["x\ny"],
        "files": {},
    }
    f = io.StringIO()
    _dump_streaming({**doc, "points": _LATER[0], "increments": _LATER[1]}, [iter(points), iter(points[:2])], f)
    assert f.getvalue() == json.dumps(doc, indent=1, default=float) + "\n"
    rows = [
        {"point": f"p{i}", "estimate": 0.1 * i if i % 2 else float("nan"), "ok": i % 2 == 1, "note": ""}
        for i in range(n * 3)
    ]
    pd.DataFrame(rows).to_csv(tmp_path / "b.csv", index=False)
    for chunk in (1, 2, 4096):  # a chunk of one row has columns all NaN, all False: the same text
        _csv_in_chunks(tmp_path / "a.csv", iter(rows), chunk=chunk)
        assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes(), chunk


def _curves(rng, n, grid, sd_shift=0.002, sd_node=0.001):
    """Curves of a known eq. (9) surface, CL = (0.01 + 0.002 alpha) g^2, each condition with a random
    offset along the curve and noise at every node."""
    alpha, mach = rng.uniform(2, 8, n), rng.uniform(0.2, 0.5, n)
    return [
        (
            (5000, m, 5),
            a,
            grid,
            {
                c: (0.01 + 0.002 * a) * grid**2 + rng.normal(0, sd_shift) * grid + rng.normal(0, sd_node, len(grid))
                for c in ("CL", "CD", "Cm")
            },
        )
        for a, m in zip(alpha, mach)
    ]


def test_gear_surface_draws_cover_the_true_surface_95pct_of_the_time():
    """The surfaces' covariance is calibrated: over 200 simulated identifications, the 95 % interval
    of 300 draws holds the true coefficients 95 % of the time (not 70 %: draws too narrow; not
    100 %: too wide), and the draws' spread is the standard error the surface reports."""
    from identify.models import fit_surface

    rng = np.random.default_rng(7)
    grid = np.linspace(0.0, 1.0, 11)
    inside, ratio = [], []
    for _ in range(200):
        s = fit_surface(_curves(rng, 7, grid))
        if s.designs[(5, "CL")] != "alpha":
            continue
        d = np.array([s.draw(rng).coef[(5, "CL")][-1] for _ in range(300)])
        lo, hi = np.percentile(d, [2.5, 97.5], axis=0)
        inside.append((lo <= [0.01, 0.002]) & ([0.01, 0.002] <= hi))
        ratio.append(np.median(np.abs(d - s.coef[(5, "CL")][-1]), axis=0) / (0.6745 * s.se(5, "CL")[-1]))
    assert len(inside) >= 100
    assert 0.91 <= np.mean(inside) <= 0.99, np.mean(inside, axis=0)
    assert np.allclose(np.median(ratio, axis=0), 1.0, atol=0.15)  # Student's t: wider tails, the same middle


def test_gear_surface_round_trips_through_json_and_falls_back_on_the_curves_errors():
    from identify.models import GearSurface, fit_surface

    rng = np.random.default_rng(3)
    grid = np.linspace(0.0, 1.0, 11)
    s = fit_surface(_curves(rng, 5, grid))
    back = GearSurface.from_arrays(json.loads(json.dumps(s.to_arrays())))
    for k in s.coef:
        assert np.array_equal(back.coef[k], s.coef[k]) and np.array_equal(back.basis[k], s.basis[k])
        assert back.dof[k] == s.dof[k] and back.designs[k] == s.designs[k]
    assert np.array_equal(
        back.draw(np.random.default_rng(1)).coef[(5, "CD")], s.draw(np.random.default_rng(1)).coef[(5, "CD")]
    )
    # one condition: no scatter to learn from, so the curve's own standard error is the band
    one = _curves(rng, 1, grid)[0]
    single = fit_surface([(*one, {c: np.full(len(grid), 0.004) for c in ("CL", "CD", "Cm")})])
    assert single.designs[(5, "CL")] == "constant" and single.dof[(5, "CL")] == np.inf
    assert np.allclose(single.se(5, "CL"), 0.004)
    assert np.allclose(fit_surface([one]).se(5, "CL"), 0.0)


def test_identification_writes_the_surfaces_with_their_covariance(reference_gear_down, tmp_path):
    """gear_surfaces.json rebuilds the exported surfaces exactly, and every surface fit has an
    uncertainty (nonzero standard errors away from gear up)."""
    from identify.models import GearSurface
    from identify.pipeline import write_outputs

    out = tmp_path / "id"
    write_outputs(reference_gear_down[2], out, None, plots="none")
    doc = json.loads((out / "gear_surfaces.json").read_text())
    assert set(doc) == {"arm_ft", "linear", "nonlinear"}
    ident = json.loads((out / "identification.json").read_text())
    for kind in ("linear", "nonlinear"):
        s = GearSurface.from_arrays(doc[kind])
        assert doc[kind]["designs"] == ident["surfaces"][kind]["designs"]
        for k in s.coef:
            assert np.all(s.se(*k)[-1] > 0), (kind, k)
