"""Effect overlays change JSBSim's forces exactly as written."""

import numpy as np
import pytest

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects, merged_xml
from campaign.simulation.engine import new_fdm
from campaign.errors import UserError

OVERLAY = """<effects>
  <axis name="DRAG">
    <function name="aero/coefficient/test-dCD">
      <product>
        <property>aero/qbar-psf</property>
        <property>metrics/Sw-sqft</property>
        <table>
          <independentVar>gear/gear-pos-norm</independentVar>
          <tableData>
            0.0 0.000
            0.5 0.020
            1.0 0.010
          </tableData>
        </table>
      </product>
    </function>
  </axis>
  <axis name="PITCH">
    <function name="aero/coefficient/test-dCm">
      <product>
        <property>aero/qbar-psf</property>
        <property>metrics/Sw-sqft</property>
        <property>metrics/cbarw-ft</property>
        <value>0.0125</value>
      </product>
    </function>
  </axis>
</effects>
"""


def _at_state(effects, gear):
    fdm = new_fdm(AircraftSource(str(DEFAULT_AIRCRAFT), effects))
    theta = 2 / np.pi * np.arcsin(gear)  # our 737: gear-pos-norm = sin(theta_LG)
    for k, v in {
        "ic/h-sl-ft": 5000.0,
        "ic/mach": 0.4,
        "ic/alpha-deg": 3.0,
        "gear/gear-cmd-norm": theta,
        "gear/theta-lg-norm": theta,
    }.items():
        fdm[k] = v
    fdm.run_ic()
    assert fdm["gear/gear-pos-norm"] == pytest.approx(gear, abs=1e-12)
    return fdm


@pytest.mark.parametrize("gear, dcd", [(0.0, 0.0), (0.25, 0.010), (0.5, 0.020), (1.0, 0.010)])
def test_overlay_adds_exactly_the_written_function(tmp_path, gear, dcd):
    f = tmp_path / "fx.xml"
    f.write_text(OVERLAY)
    bare = _at_state(load_effects(None), gear)
    fx = _at_state(load_effects(f), gear)
    qs = fx["aero/qbar-psf"] * fx["metrics/Sw-sqft"]
    assert fx["aero/qbar-psf"] == bare["aero/qbar-psf"] and fx["aero/alpha-rad"] == bare["aero/alpha-rad"]
    # wind-axis drag grows by exactly dCD * qbar * S
    assert fx["forces/fwx-aero-lbs"] - bare["forces/fwx-aero-lbs"] == pytest.approx(dcd * qs, rel=1e-12, abs=1e-7)
    assert fx["aero/coefficient/test-dCD"] == pytest.approx(dcd * qs, rel=1e-12, abs=1e-9)
    assert fx["forces/fwz-aero-lbs"] == pytest.approx(bare["forces/fwz-aero-lbs"], rel=1e-14)
    # the pitching moment about the CG grows by dCm * qbar * S * cbar, less the extra
    # drag's normal component acting at AERORP, 3.11 in behind the CG
    dm = fx["moments/m-aero-lbsft"] - bare["moments/m-aero-lbsft"]
    arm_ft = (fx["metrics/aero-rp-x-in"] - fx["inertia/cg-x-in"]) / 12
    expected = 0.0125 * qs * fx["metrics/cbarw-ft"] - dcd * qs * np.sin(fx["aero/alpha-rad"]) * arm_ft
    assert dm == pytest.approx(expected, rel=1e-9)


def test_reference_overlay_vanishes_gear_up_and_down_and_peaks_between():
    fx = load_effects(DEFAULT_EFFECTS)
    for gear in (0.0, 1.0):
        ref = _at_state(fx, gear)
        bare = _at_state(load_effects(None), gear)
        assert ref["forces/fwx-aero-lbs"] == pytest.approx(bare["forces/fwx-aero-lbs"], rel=1e-12)
        assert ref["forces/fwz-aero-lbs"] == pytest.approx(bare["forces/fwz-aero-lbs"], rel=1e-12)
    ref, bare = _at_state(fx, 0.5), _at_state(load_effects(None), 0.5)
    qs = ref["aero/qbar-psf"] * ref["metrics/Sw-sqft"]
    total_dcd = 0.031 * 0.5 + (ref["forces/fwx-aero-lbs"] - bare["forces/fwx-aero-lbs"]) / qs
    assert total_dcd == pytest.approx(0.031, abs=1e-6)  # saturated at delta_LG = 0.5


def test_empty_overlay_is_valid_and_changes_nothing(tmp_path):
    f = tmp_path / "empty.xml"
    f.write_text("<effects/>")
    assert load_effects(f).functions == ()
    a, b = _at_state(load_effects(f), 0.5), _at_state(load_effects(None), 0.5)
    assert a["forces/fwx-aero-lbs"] == b["forces/fwx-aero-lbs"]


@pytest.mark.parametrize(
    "text, field",
    [
        ("<effects><axis name='DRAG'>", "not well-formed"),
        ("<effect/>", "root element"),
        ("<effects><axis name='THRUST'/></effects>", 'axis name="THRUST"'),
        ("<effects><axis name='DRAG'><table/></axis></effects>", "expected <function>"),
        ("<effects><axis name='DRAG'><function><value>1</value></function></axis></effects>", "missing name"),
    ],
)
def test_malformed_overlay_names_file_and_field(tmp_path, text, field):
    f = tmp_path / "bad.xml"
    f.write_text(text)
    with pytest.raises(UserError) as err:
        load_effects(f)
    assert str(f) in str(err.value) and field in str(err.value)


def test_stock_737_loses_its_network_ports():
    import os

    import jsbsim

    stock = os.path.join(jsbsim.get_default_root_dir(), "aircraft", "737")
    text = merged_xml(AircraftSource(stock, load_effects(None)))
    assert "<input port" not in text and "port=" not in text and "QTJSBSIM" not in text
    fdm = new_fdm(AircraftSource(stock, load_effects(None)))
    assert np.isfinite(fdm["aero/qbar-psf"])


def test_a_long_lived_process_keeps_only_its_latest_merged_roots(tmp_path, monkeypatch):
    """A worker or a benchmark flies one overlay after another: each source's merged root is written
    once and reused, and beyond the latest ROOTS_KEPT the oldest goes (it had piled up in the
    temporary folder until the process ended, or for good if it was killed)."""
    import tempfile

    from campaign.simulation import engine

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    roots = lambda: sorted(p.name for p in (tmp_path / "tmp").iterdir())  # noqa: E731
    sources = []
    for i in range(engine.ROOTS_KEPT + 3):
        fx = tmp_path / f"fx{i}.xml"
        fx.write_text(OVERLAY.replace("0.0125", f"{0.001 * i:.4f}"))
        sources.append(AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(fx)))
        first = new_fdm(sources[-1])
        assert roots() and new_fdm(sources[-1]) is not first and len(roots()) == min(i + 1, engine.ROOTS_KEPT)
        assert np.isfinite(first["aero/qbar-psf"])
    kept = roots()
    new_fdm(sources[-engine.ROOTS_KEPT])  # one still kept: loaded from its root again, nothing written
    assert roots() == kept
    new_fdm(sources[0])  # one removed: written again, the least recently loaded goes
    assert len(roots()) == engine.ROOTS_KEPT and roots() != kept
