"""``campaign diagnose``: show the discrepancy, name the cause, extend the model, measure the gain.

The diagnosis (:mod:`diagnose`) works on the training logs; this module reads the data,
splits it, runs the diagnosis, writes the extension into a copy of the model, flies the
held-out manoeuvres on both aircraft (same trimmed start, recorded inputs) and hands them to
:mod:`diagnose.gain`, and draws the plots on the workers.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from campaign.diagnosis.bands import replay_bands
from campaign.diagnosis.floor import FLOOR, replay_floor
from campaign.diagnosis.refine import REFINE, refine_extension
from campaign.errors import UserError
from campaign.orchestration.cluster import connect, pack, unpack_source
from campaign.orchestration.store import atomic_write
from campaign.simulation.aircraft import AircraftSource, check_aircraft_folder, load_effects
from campaign.simulation.replay_log import Inputs, ReplayError, Start, estimate_start, fly_log, measured_inputs
from diagnose.config import DiagnosisSettings
from diagnose.diagnosis import STAGES, diagnose
from diagnose.evaluate import ModelEvaluator
from diagnose.extension import write_extension
from diagnose.gain import exercised, largest, measure_gain, replay_lines, replay_table, window_table
from diagnose.report import document, summary
from diagnose.residuals import residual_data
from diagnose.result import Diagnosis
from identify.export import merge_into_aircraft
from identify.kinematics import measured_wind
from identify.logs import Log, LogError, read_campaign, read_csv, read_parquet
from identify.models import lowpass
from infra.pool import Ahead, local_workers, on_cluster, pmap, results, submit, trim_memory

G0 = 32.174049


def load_data(path: Path) -> list[Log]:
    """Measured logs: a campaign folder, a folder of CSV/Parquet logs, or one file."""
    path = Path(path)
    try:
        if path.is_dir():
            return read_campaign(path)
        if path.suffix == ".csv":
            return [read_csv(path)]
        if path.suffix == ".parquet":
            return [read_parquet(path)]
    except LogError as exc:
        raise UserError(str(exc)) from None
    raise UserError(f"{path}: not a campaign folder, a CSV or a Parquet log")


def split(
    logs: list[Log], every: int = 3, first: list[Log] | None = None, source: str = ""
) -> tuple[list[Log], list[Log]]:
    """Hold out about every ``every``-th flight condition (all its manoeuvres) of ``first`` (default: of
    ``logs``), chosen so that the fit keeps what was flown (:func:`_taken`): first every altitude, Mach
    number and flap angle outside the fitted range, and every gear state; then every Mach number and flap
    angle inside it, no Mach number flown at one flap angle only that the data fly at another, and every
    held-out trim angle of attack within what the fitted logs fly. Where no choice of that many keeps all
    of it, fewer are held out if that keeps it all (at least one); if nothing does, the choice of that
    many taking least.
    Logs added later (flights ``campaign plan`` designed) are fitted on, unless they sit at a held-out
    condition, so that adding them moves no condition out of the fit. ``source`` names the data in the
    error raised when ``first`` holds one flight condition only."""
    first = first or logs
    conds = sorted({log.condition for log in first})
    if len(_distinct(conds)) < 2 and len(first) >= 2:
        return split_by_flight(logs, every, first)
    if len(conds) < 2:
        found = ", ".join(f"{c[0]:g} ft, Mach {c[1]:g}, flap {c[2]:g}" for c in conds) or "none"
        raise UserError(
            f"--data{' ' + source if source else ''}: needs logs from at least two flight conditions "
            f"or two flights at one (one is held out), found {len(first)} log(s) at {len(conds)} "
            f"condition(s) ({found})"
        )
    states = {c: set() for c in conds}
    alpha = {c: [] for c in conds}
    for lg in first:
        states[lg.condition].add(_gear_state(lg))
        frame = getattr(lg, "data", None)
        if frame is not None and "alpha_deg" in frame:
            alpha[lg.condition].append(frame["alpha_deg"].to_numpy())
    spans = {c: _span(a) for c, a in alpha.items()}
    start = sorted({c for i, c in enumerate(conds) if i % every == every - 1} or {conds[-1]})
    held = _least_taken(set(start), conds, states, spans)
    for k in range(len(start) - 1, 0, -1):
        if not any(_taken(held, conds, states, spans)):
            break
        fewer = _least_taken(set(start[:k]), conds, states, spans)
        if not any(_taken(fewer, conds, states, spans)):
            held = fewer
    return [lg for lg in logs if lg.condition not in held], [lg for lg in logs if lg.condition in held]


#: How a held-out split the user gave is said in ``diagnosis.json`` (``data.split``).
AS_GIVEN = "as given (--held-out)"


def _split(logs: list[Log], first: list[Log], source: str, held_out: list[str] | None) -> tuple:
    """``(fitted, held out, split by flight)``: as given (``held_out``), or :func:`split` of ``first``."""
    if held_out:
        return (*held_out_as_given(logs, held_out), False)
    train, held = split(logs, first=first, source=source)
    return train, held, len(_distinct(sorted({lg.condition for lg in first}))) < 2


def held_out_as_given(logs: list[Log], names: list[str]) -> tuple[list[Log], list[Log]]:
    """The fitted and the held-out logs, those held out named by file name or stem.

    Raises
    ------
    UserError
        If a name matches no log, or every log would be held out.
    """
    files = [Path(lg.path) for lg in logs]
    held = set()
    for name in names:
        match = {str(f) for f in files if name in (f.name, f.stem)}
        if not match:
            shown = ", ".join(f.name for f in files[:6]) + (f" and {len(files) - 6} more" if len(files) > 6 else "")
            raise UserError(f"--held-out {name}: no log of that name in --data (the logs: {shown})")
        held |= match
    train = [lg for lg in logs if str(Path(lg.path)) not in held]
    if not train:
        raise UserError("--held-out: every log would be held out; at least one must be fitted")
    return train, [lg for lg in logs if str(Path(lg.path)) in held]


#: How a split by flight is said in ``diagnosis.json`` (``data.split``) and ``diagnosis.txt``.
BY_FLIGHT = (
    "by flight: the data hold one flight condition, so every {every}rd flight in file order is held out "
    "(the last at least)"
)


#: Conditions closer than this (altitude [ft], Mach, flap [deg]) are one for the held-out split: imported records
#: of one test point differ in the last digits of their averaged condition.
SAME_CONDITION = (500.0, 0.01, 0.1)


def _distinct(conds: list[tuple]) -> list[tuple]:
    """``conds`` with those within :data:`SAME_CONDITION` of an earlier one left out."""
    out = []
    for c in conds:
        if not any(all(abs(a - b) < tol for a, b, tol in zip(c, o, SAME_CONDITION)) for o in out):
            out.append(c)
    return out


def split_by_flight(logs: list[Log], every: int = 3, first: list[Log] | None = None) -> tuple[list[Log], list[Log]]:
    """The held-out split of data that hold one flight condition (:func:`split` cannot hold a condition out):
    every ``every``-th flight of ``first`` (default ``logs``) in file order, the last at least; logs added
    later are fitted on."""
    first = first or logs
    order = sorted(first, key=lambda lg: lg.path)
    held = {lg.path for i, lg in enumerate(order) if i % every == every - 1} or {order[-1].path}
    return [lg for lg in logs if lg.path not in held], [lg for lg in logs if lg.path in held]


def _least_taken(held: set, conds: list, states: dict, spans: dict) -> set:
    """``held`` with one condition at a time swapped for one in the fit while that takes less (:func:`_taken`)."""
    best = _taken(held, conds, states, spans)
    while any(best):
        score, h, c = min(
            (
                (_taken((held - {h}) | {c}, conds, states, spans), h, c)
                for h in sorted(held)
                for c in conds
                if c not in held
            ),
            key=lambda s: s[0],
        )
        if not score < best:
            break
        held, best = (held - {h}) | {c}, score
    return held


def _gear_state(log: Log) -> str:
    try:
        return "transition" if log.transition else "down" if log.gear_down else "up"
    except (AttributeError, KeyError, TypeError):
        return "up"


def _span(alpha: list) -> tuple[float, float, float] | None:
    """(1st percentile, median, 99th percentile) [deg] of a condition's angle of attack over its logs."""
    a = np.concatenate(alpha) if alpha else np.empty(0)
    a = a[np.isfinite(a)]
    return tuple(np.percentile(a, [1, 50, 99])) if a.size else None


def _taken(held: set, conds: list, states: dict, spans: dict) -> tuple[int, int]:
    """What holding out ``held`` takes from the fit, as (what it loses, what it blurs).

    Lost: values of altitude, Mach or flap that no fitted condition has and that lie outside the fitted
    range, and gear states. Blurred: Mach numbers and flap angles no fitted condition has inside its
    range (interpolated: a Mach bump at 0.4 is seen in held-out data only when both conditions at Mach
    0.4 are held out); each Mach number and flap angle the fit would fly at the same conditions only
    while the data fly them apart (the A320's Mach 0.3 flown clean and with flap 15, the clean one held
    out: a Mach step fits as one in the flap angle); and each held-out condition whose median angle of
    attack lies outside what the fitted logs fly (``spans``, from :func:`_span`; our 737's Mach 0.3 at
    10,000 ft trims at 9.5 deg where the rest fly up to 9.3: a Cm rise above 9 deg is hardly in the
    fit). Altitude enters the aerodynamics through Mach and the trim alone, and an inner one is
    not counted. With four conditions, one of them flap 15 and one the only Mach 0.4, every choice
    blurs or loses, and the first stays."""
    train = [c for c in conds if c not in held]
    lost = inner = 0
    for j in range(3):
        have = {c[j] for c in train}
        gone = {c[j] for c in held} - have
        outside = sum(not min(have) < v < max(have) for v in gone)
        lost += outside
        inner += (len(gone) - outside) if j else 0
    fitted = set().union(*(states[c] for c in train))
    lost += len(set().union(*(states[c] for c in held)) - fitted)
    flown = [spans[c] for c in train if spans.get(c)]
    alpha_out = 0
    if flown:
        lo, hi = min(f[0] for f in flown), max(f[2] for f in flown)
        alpha_out = sum(not lo <= spans[c][1] <= hi for c in held if spans.get(c))
    return lost, inner + _confounded(train, conds) + alpha_out


def _confounded(train: list, conds: list) -> int:
    """How many (Mach number, flap angle) pairs the conditions ``train`` fly at exactly the same conditions
    while ``conds`` do not."""

    def at(cs, j, v):
        return frozenset(c for c in cs if c[j] == v)

    return sum(
        at(train, 1, m) == at(train, 2, f) and at(conds, 1, m) != at(conds, 2, f)
        for m in {c[1] for c in train}
        for f in {c[2] for c in train}
    )


#: Below this RMS [ft/s] the wind measured in a log is taken as still air (noise-free campaigns).
STILL_AIR_FPS = 0.05
#: The measured wind is low-passed here [Hz]: turbulence lies far below, the vanes' noise above.
WIND_CUTOFF_HZ = 2.0


def log_wind(log: Log) -> np.ndarray | None:
    """The wind measured in a log (:func:`identify.kinematics.measured_wind`), low-passed at
    :data:`WIND_CUTOFF_HZ`, shape (N, 3) [ft/s]; None in still air or without inertial velocities.

    The whole wind, steady part included: the replay trims in its first sample, so that its
    inertial path (altitude) follows the data's. A steady error the data compatibility left in
    the air data (an alpha bias) is then flown as a steady wind."""
    w = measured_wind(log.data)
    if w is None:
        return None
    t = log.data.t_s.to_numpy()
    w = lowpass(w, float(np.median(np.diff(t))), WIND_CUTOFF_HZ)
    return w if float(np.sqrt(np.mean(w**2))) > STILL_AIR_FPS else None


def wind_note(log: Log) -> dict:
    """What a held-out log's replays flew in: the measured wind's RMS per axis, or why still air."""
    if measured_wind(log.data) is None:
        return {"replayed_in": "still air", "why": "no inertial velocity logged (vn_fps, ve_fps, vd_fps)"}
    w = log_wind(log)
    if w is None:
        return {"replayed_in": "still air", "why": f"measured wind below {STILL_AIR_FPS} ft/s RMS"}
    rms = np.sqrt(np.mean((w - w.mean(axis=0)) ** 2, axis=0))
    return {"replayed_in": "measured wind", "rms_fps": dict(zip(("north", "east", "down"), map(float, rms)))}


def recorded(log: Log, wind: bool = True) -> tuple[Start, Inputs]:
    """Where a replay of the log starts and what it flies (:mod:`campaign.simulation.replay_log`): the start
    estimated from the log's first seconds, the recorded surfaces and the measured thrust, and with ``wind``
    the wind measured in the log (:func:`log_wind`): a replay of turbulent data meets the gusts the
    aeroplane met."""
    w = log_wind(log) if wind else None
    start = estimate_start(log.data, w)
    return start, measured_inputs(log.data, start, w)


def replay_why(log: Log, source: AircraftSource, wind: bool = True) -> pd.DataFrame | str:
    """Fly the log's recorded inputs and measured thrust on an aircraft from the start estimated from the log,
    in the wind measured in the log (``wind``; still air when it has none): the flight, or why it could not
    be flown."""
    start, inputs = recorded(log, wind=wind)
    try:
        return fly_log(source, start, inputs)
    except ReplayError as exc:
        return str(exc)


def replay(log: Log, source: AircraftSource, wind: bool = True) -> pd.DataFrame | None:
    """:func:`replay_why`'s flight, or None if it could not be flown."""
    out = replay_why(log, source, wind)
    return None if isinstance(out, str) else out


#: The niceness of the process that flies the model's replays ahead (:class:`infra.pool.Ahead`): the lowest
#: priority, so that it takes a core only when the diagnosis leaves one idle.
AHEAD_NICE = 19


#: Which held-out logs get plots of their own: ``key`` those where the first aerodynamic cause acts
#: (without one, those with the largest residual of each coefficient), ``all`` every one.
PLOTS = ("key", "all", "none")


def replay_shipped(log: Log, shipment, effects) -> pd.DataFrame | str:
    """On a cluster worker: :func:`replay_why` on this machine's copy of the shipped aircraft."""
    return replay_why(log, unpack_source(shipment, effects))


def floor_shipped(log: Log, shipment, effects, seed: int) -> dict:
    """On a cluster worker: :func:`campaign.diagnosis.floor.replay_floor` on the shipped aircraft."""
    return replay_floor(log, unpack_source(shipment, effects), seed)


#: How a set of logs given in memory (not read from a path) is named in ``diagnosis.json``.
IN_MEMORY = "logs given in memory"


def _data_sets(data_path) -> list[tuple[object, list[Log]]]:
    """``(where, logs)`` of each set of measured logs: a path read (:func:`load_data`), or a list of
    :class:`identify.logs.Log` given in memory (named :data:`IN_MEMORY`)."""
    items = list(data_path) if isinstance(data_path, (list, tuple)) else [data_path]
    if not items:
        raise UserError("data: no logs given")
    if all(isinstance(x, Log) for x in items):
        items = [items]
    sets = []
    for x in items:
        if isinstance(x, (list, tuple)):
            if not x or not all(isinstance(lg, Log) for lg in x):
                raise UserError("data: a list of logs must hold identify.logs.Log objects only, and one at least")
            sets.append((IN_MEMORY if len(items) == 1 else f"{IN_MEMORY} ({len(sets) + 1})", list(x)))
        else:
            p = Path(x).resolve()
            sets.append((p, load_data(p)))
    return sets


def _paths(data_path) -> list[Path]:
    """The folders and files among the data given (logs given in memory are neither)."""
    given = data_path if isinstance(data_path, (list, tuple)) else [data_path]
    return [Path(p) for p in given if isinstance(p, (str, Path))]


def _within(out: Path, folder: Path) -> bool:
    """Whether ``out`` is ``folder`` or below it (links resolved)."""
    o, f = out.resolve(), folder.resolve()
    return o == f or f in o.parents


def run_diagnosis(
    data_path: Path,
    model_dir: Path,
    out: Path,
    plots: str | bool = "key",
    jobs: int = 1,
    progress: bool = False,
    cluster: str | None = None,
    refine: str | None = None,
    bands: int = 0,
    settings: DiagnosisSettings | None = None,
    held_out: list[str] | None = None,
) -> dict:
    """The whole diagnosis; returns what ``diagnosis.json`` holds.

    Parameters
    ----------
    data_path : Path, list of Path, or list of Log
        Measured logs (:func:`load_data`), several read together (a campaign and the flights
        ``campaign plan`` designed); a list of :class:`identify.logs.Log` is one set given in memory
        (a list of such lists, several).
    model_dir, out : Path
        The model aircraft folder, a new report folder.
    plots : {"key", "all", "none"} or bool
        Which plots to draw (:data:`PLOTS`; True is ``key``, False ``none``). The overview of
        the residuals against each cause is always drawn unless ``none``.
    jobs : int
        Worker processes for the noise floor, the replays and the plots.
    progress : bool
        A progress bar of the stages on stderr.
    cluster : str, optional
        ``tcp://HOST:PORT`` of a Dask scheduler: the residuals, sensitivities, noise realizations
        and replays run on its workers (the model and aircraft folders shipped with the tasks), the
        plots on ``jobs`` local workers. ``diagnosis.json`` is the same as a local run's, to the bit.
    refine : {"oe"}, optional
        Refine the extension's terms by output error through replays of the fitted logs
        (:mod:`campaign.diagnosis.refine`, on the local workers) and report its gain beside the
        equation-error extension's (``refine`` in ``diagnosis.json``).
    bands : int
        Monte Carlo draws of the extension for bands on the held-out replays where the cause
        acts, and their Part 60 pass probability (:mod:`campaign.diagnosis.bands`; 0: none).
    settings : DiagnosisSettings, optional
        Every decision threshold, handed to :func:`diagnose.diagnosis.diagnose` (None: its defaults);
        ``diagnosis.json`` records them (``settings``).
    held_out : list of str, optional
        The logs to hold out, by file name (``fAttasElv1.parquet``) or stem, instead of the split by
        flight condition (:func:`held_out_as_given`).

    Raises
    ------
    TypeError
        If ``settings`` is not a :class:`diagnose.config.DiagnosisSettings` (before anything is read).
    """
    if settings is not None and not isinstance(settings, DiagnosisSettings):
        raise TypeError(f"settings: a diagnose.config.DiagnosisSettings, not {type(settings).__name__}")
    plots = {True: "key", False: "none"}.get(plots, plots)
    if plots not in PLOTS:
        raise UserError(f"plots: {plots!r} is not one of {', '.join(PLOTS)}")
    if refine is not None and refine not in REFINE:
        raise UserError(f"refine: {refine!r} is not one of {', '.join(REFINE)}")
    if bands < 0 or 0 < bands < 20:
        raise UserError(f"--bands: {bands} draws; a band needs 20 or more (50 is usual), or 0 for none")
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: is a file, not a folder (--out names a new folder for the report)")
    if out.exists() and any(out.iterdir()):
        raise UserError(f"{out}: exists and is not empty; will not overwrite (choose another --out)")
    for flag, given in [("--data", p) for p in _paths(data_path)] + [("--model", Path(model_dir))]:
        if _within(out, given):
            raise UserError(
                f"{out}: inside {flag} {given}; the report goes in a folder of its own (choose another --out)"
            )
    model = check_aircraft_folder(model_dir)
    client = connect(cluster) if cluster else None  # before anything is read or written
    try:
        paths, sets = map(list, zip(*_data_sets(data_path)))
        logs = [lg for s in sets for lg in s]
        where = {}
        for p, s in zip(paths, sets):
            for lg in s:
                name = Path(lg.path).name
                if name in where:
                    raise UserError(
                        f"--data: log {name} is in {where[name]} and in {p} (the report names logs by "
                        f"file: each --data must hold other flights)"
                    )
                where[name] = p
        train, held, by_flight = _split(logs, sets[0], str(paths[0]), held_out)
    except UserError:
        if client is not None:
            client.close()
        raise
    fresh = not out.exists()
    try:
        with on_cluster(client):
            return _diagnosis(
                paths,
                model,
                out,
                plots,
                jobs,
                progress,
                logs,
                train,
                held,
                client,
                refine,
                bands,
                settings,
                by_flight,
                bool(held_out),
            )
    except BaseException:  # interrupted or failed: no half report, and the same command runs again
        if fresh:
            shutil.rmtree(out, ignore_errors=True)
        elif out.is_dir():
            for p in out.iterdir():
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    p.unlink()
        raise
    finally:
        if client is not None:
            client.close()


def _diagnosis(  # noqa: PLR0913
    data_path: list[Path],
    model: Path,
    out: Path,
    plots: str,
    jobs: int,
    progress: bool,
    logs: list[Log],
    train: list[Log],
    held: list[Log],
    client,
    refine: str | None = None,
    bands: int = 0,
    settings: DiagnosisSettings | None = None,
    by_flight: bool = False,
    as_given: bool = False,
) -> dict:
    """:func:`run_diagnosis` once its inputs are read (within :func:`infra.pool.on_cluster`)."""
    fan = max(jobs, sum(client.nthreads().values())) if client is not None else jobs  # tasks at once
    try:
        evaluator = ModelEvaluator(model)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    bar = tqdm(
        total=len(STAGES), unit="stage", disable=not progress, bar_format="{l_bar}{bar}| {n}/{total} stages [{elapsed}]"
    )
    src_model = AircraftSource(str(model), load_effects(None))

    def stage(name: str) -> None:
        trim_memory()
        bar.n = STAGES.index(name)
        bar.set_description(name)

    # a process of its own flies the model's replays at the lowest priority until they are wanted: on the
    # core the serial work leaves (the data compatibility, the search, the verdict), hardly beside the workers
    with Ahead(replay_why, [(lg, src_model) for lg in held], jobs if client is None else 1, nice=AHEAD_NICE) as ahead:
        try:
            diag = diagnose(train, evaluator, held, jobs=fan, progress=stage, settings=settings)
        except ValueError as exc:  # logs the model cannot be set to (a flap angle it does not have)
            evaluator.close()
            bar.close()
            raise UserError(str(exc)) from None
        out.mkdir(parents=True, exist_ok=True)
        doc = document(
            diag,
            {
                "path": " + ".join(map(str, data_path)),
                "paths": [str(p) for p in data_path],
                "logs": len(logs),
                "train": [lg.path for lg in train],
                "held_out": [lg.path for lg in held],
                "split": AS_GIVEN if as_given else BY_FLIGHT.format(every=3) if by_flight else "by flight condition",
            },
            str(model),
        )
        before = diag.held
        raw_held, held = held, diag.held_logs  # as corrected for instrument errors
        extended_eval = src_ext = after = None
        if diag.aero_causes:
            stage("extension")
            xml = write_extension(diag, out / "extension.xml")
            folder = merge_into_aircraft(model, xml, out / "extended_aircraft", replace_gear=False)
            doc["extension"], doc["extension_xml"] = str(folder), str(xml)
            extended_eval = ModelEvaluator(folder, jobs=fan)
            after = residual_data(held, extended_eval, wait=False)  # the workers go on to the replays
            src_ext = AircraftSource(str(folder), load_effects(None))
        stage("replays")
        early = {i: fb for i, fb in ahead.finished(cancel=True).items() if recorded(held[i]) == recorded(raw_held[i])}
    sources = (src_model,) if src_ext is None else (src_model, src_ext)
    calls = [(i, src) for i in range(len(held)) for src in sources if src is src_ext or i not in early]
    seeds = [_floor_seed(lg) for lg in held]
    if client is None:
        flown_now = dict(zip(calls, pmap(replay_why, [(held[i], src) for i, src in calls], jobs)))
        floors = pmap(replay_floor, [(lg, src_model, sd) for lg, sd in zip(held, seeds)], jobs)
    else:  # the aircraft travel with the tasks
        shipped = {id(s): pack(s) for s in sources}
        flown_now = dict(
            zip(calls, pmap(replay_shipped, [(held[i], shipped[id(src)], src.effects) for i, src in calls], fan))
        )
        floors = pmap(
            floor_shipped, [(lg, shipped[id(src_model)], src_model.effects, sd) for lg, sd in zip(held, seeds)], fan
        )
    after = after() if callable(after) else after
    raw = {
        lg.path: (
            early[i] if i in early else flown_now[i, src_model],
            flown_now[i, src_ext] if src_ext is not None else None,
        )
        for i, lg in enumerate(held)
    }
    flown = {k: tuple(None if isinstance(f, str) else f for f in v) for k, v in raw.items()}
    floors = {Path(lg.path).name: f for lg, f in zip(held, floors)}
    doc["replays"] = replay_table(held, flown, extended=src_ext is not None, floors=floors)
    doc["replay_windows"] = window_table(held)
    doc["replay_floor"] = {
        "method": FLOOR,
        "per_log": {
            k: {"draws": f.get("draws"), "drawn": f.get("drawn"), "note": f.get("note")} for k, f in floors.items()
        },
    }
    doc["replay_starts"] = {Path(lg.path).name: _start_note(lg, raw[lg.path]) for lg in held}
    doc["wind"] = {Path(lg.path).name: wind_note(lg) for lg in held}
    if diag.aero_causes:
        doc["gain"] = measure_gain(diag, held, before, after, flown)
        if refine:
            stage("refine")
            with local_workers():
                doc["refine"] = refine_extension(
                    diag, model, out, held, before, {k: v[0] for k, v in flown.items()}, replay, jobs
                )
    band_arrays = {}
    if bands and diag.aero_causes:
        stage("bands")
        acting = exercised(before, diag.aero_causes[0].variables, diag.settings.min_std)
        with local_workers():
            doc["bands"], band_arrays = replay_bands(diag, model, out, [held[i] for i in acting], bands, replay, jobs)
    if plots != "none":
        stage("plots")
        which = (
            exercised(before, diag.aero_causes[0].variables, diag.settings.min_std)
            if diag.aero_causes
            else largest(before)
        )
        doc["plotted_logs"] = _plots(
            diag, held, before, after, flown, out, jobs, None if plots == "all" else which, band_arrays
        )
    bar.update(len(STAGES) - bar.n)
    bar.close()
    doc["summary"] = summary(diag, doc)
    lines = replay_lines(doc)
    unflown = {k: v["why"] for k, v in doc["replay_starts"].items() if v.get("why")}
    if lines or unflown:
        doc["summary"] += (
            "\nHeld-out replays judged over "
            + ("their Part 60 or manoeuvre windows; the floor: " + FLOOR + "\n" + "\n".join(lines) if lines else "")
            + "".join(f"\n  {k}: not flown: {w}" for k, w in unflown.items())
            + (f"\n  held-out split {doc['data']['split']}" if by_flight else "")
            + "\n"
        )
    text = json.dumps(doc, indent=1, default=float) + "\n"
    atomic_write(out / "diagnosis.txt", lambda tmp: Path(tmp).write_text(doc["summary"]))
    atomic_write(out / "diagnosis.json", lambda tmp: Path(tmp).write_text(text))  # last: the diagnosis is whole
    evaluator.close()
    if extended_eval:
        extended_eval.close()
    return doc


def _floor_seed(log: Log) -> int:
    """The floor's noise seed of a log: from its file name (the same on every run and machine)."""
    import zlib

    return zlib.crc32(Path(log.path).name.encode())


def _start_note(log: Log, flights: tuple) -> dict:
    """Where a held-out log's replays started, the offsets they flew, and why a replay was not flown."""
    start, _ = recorded(log)
    out = {"start": start.to_dict()}
    for kind, f in zip(("model", "extended"), flights):
        if isinstance(f, str):
            out.setdefault("why", {})[kind] = f
        elif f is not None:
            out[kind] = {"trim": f.attrs.get("trim"), "offsets": f.attrs.get("offsets")}
    return out


def _plots(
    diag: Diagnosis,
    held: list[Log],
    before: pd.DataFrame,
    after: pd.DataFrame | None,
    flown: dict,
    out: Path,
    jobs: int = 1,
    which: list[int] | None = None,
    bands: dict | None = None,
) -> list[str]:
    """The overview, and the residual history and response of the held-out logs ``which`` (None: all),
    drawn on the local workers (they write into ``out``); returns the names of the logs plotted."""
    from diagnose.plots import (  # matplotlib: only when plots are drawn
        save_log_plots,
        save_overview,
    )

    (out / "plots").mkdir(exist_ok=True)
    which = range(len(held)) if which is None else which
    calls = [
        (
            Path(held[i].path).stem,
            held[i].data,
            before[before.log == i],
            after[after.log == i] if after is not None else None,
            *flown.get(held[i].path, (None, None)),
            out / "plots",
            (bands or {}).get(held[i].path),
        )
        for i in which
    ]
    if jobs > 1:  # the overview too: the workers have matplotlib loaded, and this process waits anyway
        slim = replace(diag, held=None, logs=[], held_logs=[])  # what the overview draws, without the logs
        with local_workers():
            list(results(submit(save_overview, [(slim, out / "plots")], jobs) + submit(save_log_plots, calls, jobs)))
    else:
        save_overview(diag, out / "plots")
        for args in calls:
            save_log_plots(*args)
    return [Path(held[i].path).name for i in which]
