"""A campaign on a Dask cluster (a LocalCluster on 127.0.0.1): the same logs as a local run, bit for bit;
a point whose worker dies fails alone; a scheduler that does not answer is one line."""

import json
import os

import dask
import pytest
from distributed import LocalCluster

from campaign.cli import main
from campaign.orchestration.runner import fly_logs, run_campaign
from campaign.validation.support import matrix_toml, one_line_error


@pytest.fixture(scope="module")
def cluster():
    # one task per worker thread, and a worker's death fails its task at once
    with dask.config.set({"distributed.scheduler.worker-saturation": 1.0, "distributed.scheduler.allowed-failures": 0}):
        with LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            silence_logs=50,
        ) as c:
            yield c


def _matrix(tmp_path):
    m = tmp_path / "m.toml"
    m.write_text(matrix_toml([(g, 0, [0.3, 0.5], 2000) for g in ("up", "down")]))
    return m


def test_cluster_logs_equal_a_local_runs_bit_for_bit(tmp_path, cluster):
    m = _matrix(tmp_path)
    common = ["--matrix", str(m), "--noise", "flight-test", "--seed", "3", "--no-identify", "--quiet"]
    assert main(["run", "--out", str(tmp_path / "local"), "--jobs", "2"] + common) == 0
    assert main(["run", "--out", str(tmp_path / "dask"), "--cluster", cluster.scheduler_address] + common) == 0
    local = {p.name: p.read_bytes() for p in (tmp_path / "local").glob("*.parquet")}
    dask_ = {p.name: p.read_bytes() for p in (tmp_path / "dask").glob("*.parquet")}
    assert len(local) == 6 and dask_ == local
    a, b = (json.loads((tmp_path / f / "manifest.json").read_text()) for f in ("local", "dask"))
    assert a["points"] == b["points"] and b["complete"]


def test_a_point_that_kills_its_worker_fails_alone(tmp_path, cluster):
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, AircraftSource, load_effects
    from campaign.simulation.engine import FlightConfig
    from campaign.simulation.instruments import load_profile
    from campaign.simulation.matrix import load_matrix

    matrix = load_matrix(str(_matrix(tmp_path)))
    config = FlightConfig(
        AircraftSource(str(DEFAULT_AIRCRAFT), load_effects("none")),
        0,
        load_profile("none"),
        matrix.maneuver_params,
        matrix.clmax_by_flap,
    )
    doomed = matrix.points[1].id

    def killer(point, cfg):  # pickled by value: the worker aborts on one point, as a segfault would
        if point.id == doomed:
            os.abort()
        return fly_logs(point, cfg)

    out = tmp_path / "c"
    summary = run_campaign(matrix, config, out, progress=False, cluster=cluster.scheduler_address, flyer=killer)
    assert [pid for pid, _ in summary.failed] == [doomed], summary.failed
    assert "worker died" in summary.failed[0][1]
    man = json.loads((out / "manifest.json").read_text())
    ok = [r for r in man["points"] if r["status"] == "ok"]
    assert len(ok) == 3 and man["complete"]
    assert sorted(f for r in ok for f in r["files"]) == sorted(p.name for p in out.glob("*.parquet"))
    # the resume flies the failed point again, on a sound worker this time
    summary = run_campaign(matrix, config, out, progress=False, cluster=cluster.scheduler_address)
    man = json.loads((out / "manifest.json").read_text())
    assert not summary.failed and len(list(out.glob("*.parquet"))) == sum(len(r["files"]) for r in man["points"]) == 6


def test_a_scheduler_that_does_not_answer_is_one_line_and_writes_nothing(tmp_path, capsys):
    argv = ["run", "--matrix", str(_matrix(tmp_path)), "--out", str(tmp_path / "c"), "--no-identify"]
    one_line_error(capsys, argv + ["--cluster", "tcp://127.0.0.1:9"], "--cluster", "no Dask scheduler")
    one_line_error(capsys, argv + ["--cluster", "nonsense"], "--cluster", "tcp://HOST:PORT")
    assert not (tmp_path / "c").exists()  # not even the folder, nor its lock
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT

    out = tmp_path.parent / f"{tmp_path.name}-d"  # not inside --data
    diag = ["diagnose", "--data", str(tmp_path), "--model", str(DEFAULT_AIRCRAFT), "--out", str(out)]
    one_line_error(capsys, diag + ["--cluster", "nonsense"], "--cluster", "tcp://HOST:PORT")
    assert not out.exists()


def test_a_service_that_is_not_a_scheduler_is_one_line_and_writes_nothing(tmp_path, capsys):
    """A port where an SSH server listens: it sends its banner before the client speaks, which Dask's client
    would read as a message length (a memory error, and a traceback)."""
    import contextlib
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def banner():
        with server:
            while True:
                try:
                    conn, _ = server.accept()
                except OSError:
                    return
                with conn, contextlib.suppress(OSError):  # the client hangs up when it likes
                    conn.sendall(b"SSH-2.0-OpenSSH_9.2p1\r\n")
                    conn.recv(64)

    threading.Thread(target=banner, daemon=True).start()
    argv = ["run", "--matrix", str(_matrix(tmp_path)), "--out", str(tmp_path / "c"), "--no-identify"]
    try:
        one_line_error(
            capsys, argv + ["--cluster", f"tcp://127.0.0.1:{port}"], "--cluster", "not a Dask scheduler", "SSH-2.0"
        )
    finally:
        server.close()
    assert not (tmp_path / "c").exists()


def test_replays_on_the_cluster_equal_local_replays_bit_for_bit(tmp_path, cluster):
    import shutil

    m = tmp_path / "m.toml"
    m.write_text(
        matrix_toml(
            [(g, 5, 0.3, 2000) for g in ("up", "down")],
            "r",
            "[maneuvers.doublet]\ntail_s = 2.0\n[maneuvers.gear_extension]\npost_s = 5.0\n",
        )
    )
    local = tmp_path / "local"
    assert main(["run", "--matrix", str(m), "--out", str(local), "--no-replay", "--quiet"]) == 0
    shutil.copytree(local, tmp_path / "dask")
    assert main(["replay", str(local), "--case", "landing-135kt", "--jobs", "2"]) == 0
    assert (
        main(["replay", str(tmp_path / "dask"), "--case", "landing-135kt", "--cluster", cluster.scheduler_address]) == 0
    )
    a, b = (
        {p.name: p.read_bytes() for p in (tmp_path / f / "replays").rglob("*") if p.is_file()}
        for f in ("local", "dask")
    )
    assert len([k for k in a if k.endswith(".parquet")]) == 6 and a == b


def test_diagnosis_on_the_cluster_equals_a_local_one_bit_for_bit(tmp_path, cluster):
    """The residuals, sensitivities, noise realizations and replays on the cluster's two workers (the
    model and the extended aircraft shipped with the tasks): diagnosis.json is a local run's, to the
    bit, with one local job as with two."""
    from campaign.simulation.aircraft import DEFAULT_AIRCRAFT, DEFAULT_EFFECTS
    from campaign.validation.hidden import DIAG_MATRIX
    from campaign.validation.support import run_matrix

    data = run_matrix(tmp_path, DIAG_MATRIX, str(DEFAULT_AIRCRAFT), str(DEFAULT_EFFECTS), noise="flight-test", seed=5)
    common = ["diagnose", "--data", str(data), "--model", str(DEFAULT_AIRCRAFT), "--no-plots", "--quiet"]
    runs = {"one": ["--jobs", "1"], "two": ["--jobs", "2"], "dask": ["--cluster", cluster.scheduler_address]}
    docs = {}
    for name, extra in runs.items():
        before = _tasks(cluster)
        assert main(common + ["--out", str(tmp_path / name)] + extra) == 0
        docs[name] = (tmp_path / name / "diagnosis.json").read_text().replace(str(tmp_path / name), "OUT")
        assert (_tasks(cluster) >= before + 10) == (name == "dask"), name  # the work went where it was sent
    assert json.loads(docs["one"])["causes"] and json.loads(docs["one"])["gain"]["replay_per_log"]
    assert docs["dask"] == docs["one"] == docs["two"]


def _tasks(cluster) -> int:
    """Tasks of infra.pool.submit the cluster's scheduler has seen finish."""
    prefix = cluster.scheduler.task_prefixes.get("on_cluster_worker")  # the key's prefix, its "_" dropped
    return prefix.state_counts["memory"] if prefix is not None else 0
