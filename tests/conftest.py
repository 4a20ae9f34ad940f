import os

import pytest

os.environ.setdefault("JSBSIM_DEBUG", "0")

from infra.pool import one_blas_thread  # noqa: E402

one_blas_thread()  # as the command line does: two test workers each with two BLAS threads wait on each other

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects  # noqa: E402
from campaign.simulation.engine import FlightConfig  # noqa: E402
from campaign.simulation.matrix import load_matrix  # noqa: E402
from campaign.validation.support import matrix_toml  # noqa: E402


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


SMALL_MATRIX = matrix_toml(
    [("up", 0, 0.3, [2000, 10000]), ("down", 5, 0.3, 2000)], "small",
    '[defaults]\nmaneuvers_gear_up = ["doublet"]\nmaneuvers_gear_down = ["doublet", "gear_extension"]\n'
    "[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.gear_extension]\npost_s = 5.0\n"
    "[stall.clmax_by_flap]\n0 = 1.45\n5 = 1.90\n")


@pytest.fixture
def small_matrix(tmp_path):
    p = tmp_path / "small.toml"
    p.write_text(SMALL_MATRIX)
    return p


@pytest.fixture
def short_tmp():
    """A temporary folder with a short path, removed afterwards, for a ``TMPDIR`` of processes the test
    kills (their aircraft copies stay there): the fork server's Unix socket goes in it, and a socket
    path longer than 107 bytes is refused (``tmp_path`` under a longer base temporary folder was)."""
    import shutil
    import tempfile
    from pathlib import Path
    d = Path(tempfile.mkdtemp(prefix="gt-"))
    yield d
    shutil.rmtree(d, ignore_errors=True)
