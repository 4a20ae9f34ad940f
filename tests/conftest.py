import json
import os
from pathlib import Path

import pytest

os.environ.setdefault("JSBSIM_DEBUG", "0")

from infra.pool import one_blas_thread  # noqa: E402

one_blas_thread()  # as the command line does: two test workers each with two BLAS threads wait on each other

from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS, AircraftSource, load_effects  # noqa: E402
from campaign.simulation.engine import FlightConfig  # noqa: E402
from campaign.simulation.matrix import load_matrix  # noqa: E402
from campaign.validation.support import matrix_toml  # noqa: E402


#: The fast tier (``pytest --fast``): tests that fly nothing, run no campaign and start no process, listed by
#: module in ``tests/fast_tier.json``; a listed test that flies fails there (:func:`_in_tmp`).
FAST_TIER = Path(__file__).with_name("fast_tier.json")


def pytest_addoption(parser):
    parser.addoption(
        "--fast",
        action="store_true",
        help="the fast tier only: no JSBSim flight, campaign or worker process (tests/fast_tier.json)",
    )
    parser.addoption(
        "--slow",
        action="store_true",
        help="also the long scenario tests (marked slow: about a minute each), which CI leaves out",
    )


def pytest_configure(config):
    config.addinivalue_line(
        "markers",
        "slow: a long scenario test (the paper's whole matrix, kill -9 at six moments, a planned turn flown): "
        "run with --slow; the capability it exercises has a shorter test in the default run",
    )


def pytest_collection_modifyitems(config, items):
    if not config.getoption("--slow"):
        skip = pytest.mark.skip(reason="a long scenario test: pytest --slow runs it")
        for it in items:
            if "slow" in it.keywords:
                it.add_marker(skip)
    if not config.getoption("--fast"):
        return
    listed = {m: set(names) for m, names in json.loads(FAST_TIER.read_text()).items()}
    keep = [it for it in items if it.originalname in listed.get(it.module.__name__.rpartition(".")[2], ())]
    config.hook.pytest_deselected(items=[it for it in items if it not in keep])
    items[:] = keep


class FlightInFastTier(AssertionError):
    """A test of the fast tier flew, ran a campaign or started a process: take it out of tests/fast_tier.json."""


def _refuse(what: str):
    def refuse(*args, **kwargs):
        raise FlightInFastTier(f"{what} in the fast tier: take this test out of {FAST_TIER.name}")

    return refuse


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch, request):
    monkeypatch.chdir(tmp_path)
    if request.config.getoption("--fast"):
        import subprocess

        import campaign.simulation.engine as engine
        import infra.pool as pool

        monkeypatch.setattr(engine, "fly", _refuse("a JSBSim flight"))
        monkeypatch.setattr(engine, "trimmed_fdm", _refuse("a JSBSim trim"))
        monkeypatch.setattr(pool, "executor", _refuse("a worker process"))
        monkeypatch.setattr(subprocess, "Popen", _refuse("a subprocess"))


@pytest.fixture(scope="session")
def matrix():
    return load_matrix()


def config_for(effects=DEFAULT_EFFECTS, **kw):
    m = load_matrix()
    return FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects(effects)),
        maneuver_params=m.maneuver_params,
        clmax_by_flap=m.clmax_by_flap,
        **kw,
    )


@pytest.fixture(scope="session")
def reference_config():
    return config_for()


@pytest.fixture(scope="session")
def bare_config():
    return config_for(None)


SMALL_MATRIX = matrix_toml(
    [("up", 0, 0.3, [2000, 10000]), ("down", 5, 0.3, 2000)],
    "small",
    '[defaults]\nmaneuvers_gear_up = ["doublet"]\nmaneuvers_gear_down = ["doublet", "gear_extension"]\n'
    "[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.gear_extension]\npost_s = 5.0\n"
    "[stall.clmax_by_flap]\n0 = 1.45\n5 = 1.90\n",
)


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
