"""Local worker processes (infra.pool): forks of a warm server, in order, deaths survived."""

import json
import os
import subprocess
import sys
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from infra.pool import BLAS_THREAD_VARIABLES, Ahead, WorkerDied, alone, pmap, submit

ROOT = Path(__file__).resolve().parents[1]


def _square(x):
    return os.getpid(), x * x


def _fail(x):
    raise ValueError(f"bad {x}")


def _die(x):
    if x == 1:
        os._exit(3)
    return x


def _cwd():
    return os.getcwd()


def _abort():
    os.abort()


def test_results_come_back_in_order_from_two_workers():
    out = pmap(_square, [(i,) for i in range(40)], 2)
    assert [v for _, v in out] == [i * i for i in range(40)]
    assert os.getpid() not in {p for p, _ in out}


def test_a_tasks_exception_reaches_the_caller():
    with pytest.raises(ValueError, match="bad 3"):
        pmap(_fail, [(3,), (4,)], 2)


def test_a_dead_worker_breaks_that_call_only(tmp_path):
    with pytest.raises(BrokenProcessPool):
        pmap(_die, [(0,), (1,), (2,)], 2)
    assert [v for _, v in pmap(_square, [(2,), (3,)], 2)] == [4, 9]  # a new pool


def _timed(x, s, mark=None):
    import time

    if mark:
        Path(mark, f"{x}").touch()
    t0 = time.monotonic()
    time.sleep(s)
    return x * x, t0, time.monotonic(), os.getpid()


def _fail_marked(x, mark):
    Path(mark, "fail").touch()
    _fail(x)


def test_work_ahead_runs_one_task_at_a_time_and_gives_its_results_by_index():
    import time

    ahead = Ahead(_timed, [(i, 0.02) for i in range(8)], 2)
    time.sleep(2.0)
    done = ahead.finished()
    assert sorted(done) == list(range(8)) and all(v[0] == i * i for i, v in done.items())
    spans = sorted((t0, t1) for _, t0, t1, _ in done.values())
    assert all(b[0] >= a[1] for a, b in zip(spans, spans[1:]))  # never two at once: a core stays free
    assert len({v[3] for v in done.values()} | {os.getpid()}) == 2  # one process, not this one


def test_work_ahead_stops_when_told_and_is_nothing_with_one_job(tmp_path):
    import time

    ahead = Ahead(_timed, [(i, 0.2, str(tmp_path)) for i in range(20)], 2)
    for _ in range(600):  # the second task has started
        if (tmp_path / "1").exists():
            break
        time.sleep(0.05)
    ahead.stop()
    done = ahead.finished()  # the task running is finished, no other starts
    assert 2 <= len(done) < 20 and set(done) == set(range(len(done)))
    assert Ahead(_timed, [(1, 0.0)], 1).finished() == {}
    ahead = Ahead(_fail_marked, [(3, str(tmp_path))], 2)
    for _ in range(600):
        if (tmp_path / "fail").exists():
            break
        time.sleep(0.05)
    with pytest.raises(ValueError, match="bad 3"):
        ahead.finished()


def test_workers_run_in_the_callers_directory(tmp_path):
    assert set(pmap(_cwd, [()] * 4, 2)) == {str(tmp_path)}
    sub = tmp_path / "sub"
    sub.mkdir()
    os.chdir(sub)
    assert set(pmap(_cwd, [()] * 4, 2)) == {str(sub)}


WARM = """
import sys, time
from infra.pool import submit, warm

def probe():
    return "identify.pipeline" in sys.modules

if __name__ == "__main__":
    warm(["identify.pipeline"])
    [first] = submit(probe, [()], 2)  # waits for the server to have imported
    t0 = time.perf_counter()
    [f] = submit(probe, [()], 3)  # a new pool: new forks of the warm server
    print(first.result(), f.result(), time.perf_counter() - t0)
"""


def test_a_worker_is_a_fork_of_the_warm_server_with_the_modules_imported(tmp_path):
    """A new worker has identify.pipeline (scipy, pandas, numpy) imported before its task asks for
    it, and is ready far sooner than an import of it takes (over a second on this machine class)."""
    script = tmp_path / "warm.py"
    script.write_text(WARM)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    first, loaded, delay = out.stdout.split()
    assert first == loaded == "True"
    t_import = subprocess.run(
        [
            sys.executable,
            "-c",
            "import time; t = time.perf_counter(); import identify.pipeline; print(time.perf_counter() - t)",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )
    assert float(delay) < 0.5 * float(t_import.stdout), (delay, t_import.stdout)


LIBRARY = """
import sys, time
from infra.pool import Ahead, alone, pmap

def probe(marker=None):
    seen = [m in sys.modules for m in ("identify.pipeline", "pandas", "campaign.design.plan")]
    if marker:
        open(marker, "w").close()
    return seen

if __name__ == "__main__":
    import os
    import identify.pipeline  # what the caller uses; campaign.design.plan it does not
    ahead = Ahead(probe, [("probed",)], 2)
    for _ in range(2400):
        if os.path.exists("probed"):
            break
        time.sleep(0.05)
    print([ahead.finished()[0], pmap(probe, [()] * 2, 2)[0], alone(probe, ())])
"""


def test_a_library_callers_workers_are_forks_of_a_server_with_its_modules_imported(tmp_path):
    """A script that imports the package and then fans out (a pool, work ahead, a process alone), with no
    command to warm the server: each worker starts with the modules of the package the caller has
    imported (and what they import), not those it has not."""
    script = tmp_path / "library.py"
    script.write_text(LIBRARY)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=150, cwd=tmp_path
    )
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1].lower()) == [[True, True, False]] * 3


def test_one_job_runs_here():
    assert {p for p, _ in pmap(_square, [(1,), (2,)], 1)} == {os.getpid()}
    assert len(submit(_square, [(1,), (2,)], 2)) == 2


def test_alone_answers_raises_and_names_the_signal_that_killed_it(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    pid, sq = alone(_square, (7,))
    assert sq == 49 and pid != os.getpid()
    assert alone(_cwd, ()) == str(tmp_path)
    with pytest.raises(ValueError, match="bad 2"):
        alone(_fail, (2,))
    with pytest.raises(WorkerDied, match=r"exit code SIGABRT\(-6\)"):
        alone(_abort, ())
    with pytest.raises(WorkerDied, match="exit code 3"):
        alone(_die, (1,))


def test_the_command_line_comes_up_without_the_numerics():
    """The worker server starts as a command begins, before the main process imports numpy,
    pandas, scipy or JSBSim: the command line module must not import them itself."""
    out = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, campaign.cli\nprint([m for m in ('numpy', 'pandas', 'scipy', 'jsbsim') if m in sys.modules])",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=True,
    ).stdout.strip()
    assert out == "[]", out
    from campaign.cli.main import shipped
    from campaign.simulation.instruments import shipped as profiles

    assert shipped() == profiles() and "flight-test" in shipped()


BLAS = """
import sys
from infra.pool import pmap

def threads():
    import numpy, scipy.linalg  # each loads its own OpenBLAS
    from threadpoolctl import threadpool_info
    return sorted(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas")

if __name__ == "__main__":
    if sys.argv[1] == "alone":
        print(threads())
    elif sys.argv[1] == "workers":  # a pool without warm(): the workers import numpy and scipy themselves
        print(pmap(threads, [()] * 2, 2)[0])
    elif sys.argv[1] == "caller":  # a library caller beside its pool: one thread once the pool is made
        pmap(threads, [()] * 2, 2)
        print(threads())
    else:
        from campaign.cli import main
        main(["points"])
        print(threads())
"""


@pytest.mark.parametrize("where", ["workers", "cli", "caller"])
def test_linear_algebra_runs_on_one_blas_thread_in_workers_and_the_command(tmp_path, where):
    """numpy's and scipy's OpenBLAS, both loaded after the limit was set (scipy's on the first
    scipy.linalg import), each run one thread, in the workers, the command line and a library
    caller that made a pool: beside busy workers a second one makes the fits several times slower."""
    script = tmp_path / "blas.py"
    script.write_text(BLAS)
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    env["PYTHONPATH"] = str(ROOT)

    def threads(*args) -> list:
        out = subprocess.run(
            [sys.executable, str(script), *args], capture_output=True, text=True, env=env, timeout=120, cwd=tmp_path
        )
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout.strip().splitlines()[-1])

    alone = threads("alone")
    if max(alone) == 1:
        pytest.skip("BLAS starts one thread here without any limit (one core)")
    assert len(alone) == 2
    assert threads(where) == [1, 1]


def test_the_folders_of_dead_processes_are_swept_and_the_living_ones_kept(tmp_path, monkeypatch):
    import tempfile
    import time

    import infra.pool as w

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # reaped: its pid names no process (unless reused meanwhile, a chance of one in tens of thousands)
    zombie = subprocess.Popen([sys.executable, "-c", "pass"])
    while not Path(f"/proc/{zombie.pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
        time.sleep(0.001)  # until it has ended, not yet reaped: the state of workers just killed with their run
    names = [
        f"gearid-{dead.pid}-abc",
        f"gearid-eval-{dead.pid}-x_1",
        f"gearid-started-{zombie.pid}-q",
        f"gearid-replay-aircraft-{dead.pid}-r",
        f"gearid-{os.getpid()}-mine",
        "gearid-cluster",
        "gearid-k2j4l5m6",
        "pymp-123-x",
        f"other-{dead.pid}-a",
    ]
    for n in names:
        (tmp_path / n / "aircraft").mkdir(parents=True)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(w, "_SWEPT", [])
    made = w.owned_tmpdir("eval")
    zombie.wait()
    assert made.parent == tmp_path and made.name.startswith(f"gearid-eval-{os.getpid()}-")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names[4:] + [made.name])
    (tmp_path / f"gearid-{dead.pid}-abc").mkdir()
    w.owned_tmpdir()  # once per process
    assert (tmp_path / f"gearid-{dead.pid}-abc").exists()


UNGUARDED = """
import operator
from infra.pool import alone, pmap

def own(x):  # defined in the caller's __main__: travels by value
    return x + 100

print(pmap(operator.add, [(1, 2), (3, 4)], 2), pmap(own, [(1,), (2,)], 2), alone(own, (3,)))
"""


@pytest.mark.parametrize("how", ["file", "stdin", "-c"])
def test_a_script_without_a_main_guard_fans_out_from_a_file_stdin_or_c(tmp_path, how):
    """The workers never import the caller's ``__main__``: a script without an ``if __name__ ==
    "__main__"`` guard, run as a file, read from standard input (``python -``) or given with ``-c``,
    runs its pool once, and its own functions travel to the workers by value."""
    script = tmp_path / "unguarded.py"
    script.write_text(UNGUARDED)
    argv = {"file": [str(script)], "stdin": ["-"], "-c": ["-c", UNGUARDED]}[how]
    out = subprocess.run(
        [sys.executable, *argv],
        input=UNGUARDED if how == "stdin" else None,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
        cwd=tmp_path,
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines() == ["[3, 7] [101, 102] 103"], out.stdout


REPLAY_COPY = """
import sys
import jsbsim
from pathlib import Path
from campaign.simulation.aircraft import AircraftSource
from campaign.simulation.replay_log import flying_source
from infra.pool import pmap

def made(_):
    kind, src = flying_source(AircraftSource(str(Path(jsbsim.get_default_root_dir()) / "aircraft" / "c172x"), ()))
    return kind, Path(src.folder).exists()

if __name__ == "__main__":
    print(made(0), pmap(made, [(0,), (1,)], jobs=2))
"""


def test_the_aircraft_copies_replays_fly_are_removed_when_their_processes_end(tmp_path, short_tmp):
    script = tmp_path / "copies.py"
    script.write_text(REPLAY_COPY)
    temp = short_tmp
    env = {**os.environ, "TMPDIR": str(temp), "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "('engines', True) [('engines', True), ('engines', True)]"
    assert list(temp.iterdir()) == []
