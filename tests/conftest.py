import os
import textwrap

import pytest

os.environ.setdefault("JSBSIM_DEBUG", "0")

from campaign.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects  # noqa: E402
from campaign.engine import FlightConfig  # noqa: E402
from campaign.matrix import load_matrix  # noqa: E402


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)


@pytest.fixture(scope="session")
def matrix():
    return load_matrix()


def config_for(effects=DEFAULT_EFFECTS, **kw):
    m = load_matrix()
    return FlightConfig(AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(effects)),
                        maneuver_params=m.maneuver_params, clmax_by_flap=m.clmax_by_flap, **kw)


@pytest.fixture(scope="session")
def reference_config():
    return config_for()


@pytest.fixture(scope="session")
def bare_config():
    return config_for(None)


SMALL_MATRIX = """
name = "small"
[defaults]
maneuvers_gear_up = ["doublet"]
maneuvers_gear_down = ["doublet", "gear_extension"]
[maneuvers.doublet]
tail_s = 2.0
[maneuvers.gear_extension]
post_s = 5.0
[stall.clmax_by_flap]
0 = 1.45
5 = 1.90
[[points]]
gear = "up"
flap_deg = 0
mach = 0.3
alt_ft = [2000, 10000]
[[points]]
gear = "down"
flap_deg = 5
mach = 0.3
alt_ft = 2000
"""


@pytest.fixture
def small_matrix(tmp_path):
    p = tmp_path / "small.toml"
    p.write_text(textwrap.dedent(SMALL_MATRIX))
    return p
