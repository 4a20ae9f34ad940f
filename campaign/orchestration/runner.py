"""Run a campaign: every status point of a matrix, in parallel, resumable."""

from __future__ import annotations

import platform
import shutil
import time
from concurrent.futures import BrokenExecutor, as_completed
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Iterator

import cloudpickle
import numpy as np
from tqdm import tqdm

from campaign.simulation.engine import FlightConfig, TrimError, fly
from campaign.errors import UserError
from campaign.simulation.matrix import Matrix, StatusPoint
from infra.provenance import NAME, tool
from campaign.orchestration.store import (
    MANIFEST,
    clean_temporaries,
    failed_record,
    log_name,
    read_manifest,
    readable_log,
    write_json,
    write_log,
)


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for pkg in ("jsbsim", "numpy", "pandas", "pyarrow", NAME):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def settings(matrix: Matrix, config: FlightConfig) -> dict:
    """What makes two campaigns the same campaign (compared on resume)."""
    fx = config.aircraft.effects
    return {
        "matrix": matrix.path,
        "matrix_sha256": matrix.sha256,
        "aircraft": config.aircraft.folder,
        "aircraft_sha256": config.aircraft.sha256,
        "effects": fx.path,
        "effects_sha256": fx.sha256,
        "seed": config.seed,
        "instruments": config.instruments.name,
        "instruments_sha256": config.instruments.sha256,
    }


def excursions(log) -> dict[str, float]:
    """Largest departures from the first sample of a gear transition."""
    first = log.iloc[0]
    return {f"{c}_max_dev": float(np.abs(log[c] - first[c]).max()) for c in ("alpha_deg", "mach", "alt_ft")}


def fly_logs(point: StatusPoint, config: FlightConfig) -> tuple[dict, list[tuple[str, object, dict]]]:
    """Fly every manoeuvre of one point.

    Returns
    -------
    record : dict
        ``{"id", "status", "reason", "files", "seeds", "excursions"}``.
    logs : list of (file name, DataFrame, metadata)
        What was flown (up to the manoeuvre that failed to trim, if one did).
    """
    logs, seeds, exc = [], {}, {}
    status, reason = "ok", ""
    for name in point.maneuvers:
        try:
            flight = fly(point, name, config)
        except TrimError as err:
            status, reason = "failed", f"{name}: {err}"
            break
        fname = log_name(point.id, name)
        logs.append((fname, flight.log, flight.meta))
        seeds[fname] = flight.meta["seed"]
        if name.startswith("gear_"):
            exc[name] = excursions(flight.log)
    return (
        {
            "id": point.id,
            "status": status,
            "reason": reason,
            "files": [f for f, _, _ in logs],
            "seeds": seeds,
            "excursions": exc,
        },
        logs,
    )


#: While points fly the manifest is written again once this many times as long as its last writing
#: took has passed: after every point in a campaign of hundreds, about once a second for 9,700 points,
#: where rewriting it after each point took longer than flying them. A point flown but not yet in it
#: flies again on resume, to the same bytes.
MANIFEST_SHARE = 10.0


def store(record: dict, logs: list, out: Path) -> dict:
    """Write a point's logs into ``out`` (atomically, one by one) and return its record."""
    for fname, log, meta in logs:
        write_log(Path(out) / fname, log, meta)
    return record


def fly_point(point: StatusPoint, config: FlightConfig, out: Path, overwrite: bool = True, flyer=None) -> dict:
    """Fly every manoeuvre of one point and write its logs.

    Parameters
    ----------
    point : StatusPoint
    config : FlightConfig
    out : Path
        Campaign folder.
    overwrite : bool
        If False, refuse to replace an existing log (``campaign fly``).
    flyer : callable, optional
        ``flyer(point, config) -> (record, logs)``; :func:`fly_logs` by default.

    Returns
    -------
    dict
        ``{"id", "status", "reason", "files", "seeds", "excursions"}``.
    """
    if not overwrite:
        for name in point.maneuvers:
            path = Path(out) / log_name(point.id, name)
            if path.exists():
                raise UserError(f"{path}: exists; will not overwrite (choose another --out)")
    return store(*(flyer or fly_logs)(point, config), out)


def _fly_marked(point: StatusPoint, config: FlightConfig, out: Path, flyer: bytes | None, marks: Path) -> dict:
    """In a local worker: leave a mark that ``point`` started, then fly it (the mark names the
    suspect if the worker dies). ``flyer`` comes cloudpickled (a caller's local function may fly)."""
    (marks / point.id).touch()
    return fly_point(point, config, out, True, cloudpickle.loads(flyer) if flyer else None)


def fly_local(points: list[StatusPoint], config: FlightConfig, out: Path, jobs: int, flyer=None) -> Iterator[dict]:
    """Fly ``points`` into ``out`` on ``jobs`` local worker processes (forks of the warm server,
    :mod:`infra.pool`), yielding each record as it finishes.

    A worker that dies (abort, segfault, out of memory) breaks the pool: the points
    finished so far are kept, those that had not started go on in a new pool, and
    those the dead workers had started are flown again at the end, each alone in a
    process of its own. A point whose lone worker dies comes back failed with the
    reason (transient: a resume flies it again). The others are unaffected.
    """
    if jobs == 1:  # in this process, as before: nothing to isolate
        for p in points:
            yield fly_point(p, config, out, True, flyer)
        return
    from infra.pool import WorkerDied, alone, owned_tmpdir, submit

    marks = owned_tmpdir("started")
    blob = cloudpickle.dumps(flyer) if flyer is not None else None
    futures: dict = {}
    try:
        queue, suspects = list(points), []
        while queue:
            broke = None
            futures = dict(zip(submit(_fly_marked, [(p, config, out, blob, marks) for p in queue], jobs), queue))
            for fut in as_completed(futures):
                if isinstance(fut.exception(), BrokenExecutor):
                    broke = fut.exception()
                    break
                yield fut.result()
                del futures[fut]
            for fut in futures:  # a broken pool fails them all: wait for that before sorting them
                fut.exception()
            queue = []
            if broke is None:
                break
            for fut, p in futures.items():
                if fut.done() and fut.exception() is None:
                    yield fut.result()
                elif (marks / p.id).exists():
                    suspects.append(p)
                else:
                    queue.append(p)
        for p in suspects:
            try:
                yield alone(_fly_marked, (p, config, out, blob, marks))
            except WorkerDied as exc:
                yield failed_record(p, f"its worker died while flying it, alone ({exc})", transient=True)
    finally:
        for fut in futures:  # the caller stopped early: what has not started is not flown
            fut.cancel()
        shutil.rmtree(marks, ignore_errors=True)


@dataclass
class Summary:
    """What a campaign run did."""

    flown: int
    skipped: int
    failed: list[tuple[str, str]]
    wall_s: float
    total: int
    worst: dict[str, float]

    @property
    def all_failed(self) -> bool:
        return self.total > 0 and len(self.failed) == self.total

    def text(self) -> str:
        lines = [
            f"{self.total - len(self.failed)} of {self.total} points ok "
            f"({self.flown} flown now, {self.skipped} already done), "
            f"{len(self.failed)} failed, flying took {self.wall_s:.1f} s"
        ]
        for pid, reason in self.failed:
            lines.append(f"  failed {pid}: {reason}")
        if self.worst:
            lines.append(
                "  gear transitions, worst excursion: "
                f"alpha {self.worst['alpha_deg_max_dev']:.3f} deg, "
                f"Mach {self.worst['mach_max_dev']:.5f}, "
                f"altitude {self.worst['alt_ft_max_dev']:.2f} ft"
            )
        return "\n".join(lines)


def run_campaign(
    matrix: Matrix,
    config: FlightConfig,
    out: Path,
    jobs: int = 1,
    progress: bool = True,
    points: list[StatusPoint] | None = None,
    cluster: str | None = None,
    flyer=None,
) -> Summary:
    """Fly the matrix into ``out``; resume if ``out`` holds the same campaign.

    ``jobs`` local worker processes (:func:`fly_local`), or the Dask cluster whose
    scheduler is at ``cluster`` (``tcp://HOST:PORT``; :mod:`campaign.orchestration.cluster`).
    ``flyer(point, config) -> (record, logs)`` flies one point (default :func:`fly_logs`).

    Raises
    ------
    UserError
        If ``out`` holds a campaign with other settings (nothing is overwritten).
    """
    if jobs < 1:
        raise UserError("--jobs: must be at least 1")
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    want = settings(matrix, config)
    old = read_manifest(out)
    if old is None and any(out.glob("*.parquet")):
        raise UserError(f"{out}: holds logs but no {MANIFEST}; will not overwrite (choose another --out)")
    done: dict[str, dict] = {}
    if old is not None:
        prev = old.get("settings", {})
        diff = [k for k in want if prev.get(k) != want[k]]
        if diff:
            raise UserError(
                f"{out / MANIFEST}: settings.{diff[0]}: {prev.get(diff[0])!r} differs from "
                f"this run's {want[diff[0]]!r}; will not overwrite (choose another --out)"
            )
        for rec in old.get("points", []):  # a missing or unreadable log, or a worker's death, flies again
            if (rec["status"] != "ok" and not rec.get("transient")) or (
                rec["status"] == "ok" and all(readable_log(out / f) for f in rec["files"])
            ):
                done[rec["id"]] = rec
    client = None
    if cluster:  # before anything is written: a scheduler that does not answer changes nothing
        from campaign.orchestration.cluster import connect, fly_on_cluster

        client = connect(cluster)
    clean_temporaries(out)
    todo = [p for p in (points or matrix.points) if p.id not in done]
    order = {p.id: i for i, p in enumerate(matrix.points)}

    def manifest(complete: bool) -> dict:
        recs = sorted(done.values(), key=lambda r: order[r["id"]])
        return {
            "campaign": matrix.name,
            "tool": tool(),
            "settings": want,
            "matrix": matrix.to_json(),
            "versions": _versions(),
            "hashes": {
                "matrix": matrix.sha256,
                "aircraft": want["aircraft_sha256"],
                "effects": want["effects_sha256"],
                "instruments": want["instruments_sha256"],
            },
            "instruments": config.instruments.to_json(),
            "seeds": {"campaign": config.seed, "logs": {f: s for r in recs for f, s in r.get("seeds", {}).items()}},
            "points": recs,
            "complete": complete,
        }

    write_json(out / MANIFEST, manifest(False))
    skipped = len(done)
    if client is not None:
        results = (store(rec, logs, out) for rec, logs in fly_on_cluster(client, todo, config, flyer or fly_logs))
    else:
        results = fly_local(todo, config, out, jobs, flyer)
    bar = tqdm(results, total=len(todo), desc="status points", unit="pt", disable=not progress)
    written, cost = time.perf_counter(), 0.0
    for rec in bar:
        done[rec["id"]] = rec
        if time.perf_counter() - written >= MANIFEST_SHARE * cost:
            t = time.perf_counter()
            write_json(out / MANIFEST, manifest(False))
            written = time.perf_counter()
            cost = written - t
    clean_temporaries(out)  # a worker the pool terminated (another's death broke it) may have been writing
    write_json(out / MANIFEST, manifest(len(done) == len(matrix.points)))
    failed = [
        (r["id"], r["reason"]) for r in sorted(done.values(), key=lambda r: order[r["id"]]) if r["status"] != "ok"
    ]
    worst: dict[str, float] = {}
    for r in done.values():
        for e in r.get("excursions", {}).values():
            for k, v in e.items():
                worst[k] = max(worst.get(k, 0.0), v)
    return Summary(len(todo), skipped, failed, time.perf_counter() - t0, len(done), worst)
