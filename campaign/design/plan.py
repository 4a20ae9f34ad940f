"""Design the next flight: the status points and manoeuvres that best separate a diagnosis's rivals.

``campaign plan --diagnosis DIR`` reads the rival explanations the diagnosis could not tell apart
(:mod:`diagnose.separation`: a cause against an instrument error or another term, separated by
fewer than 5 standard errors), flies every candidate flight on the model under test (noise-free:
the expected data), and predicts how far each flight would separate each pair, with the cause's
and the rival's fits to the old data taken in turn as the truth (T-optimal discrimination). Flights
are chosen greedily by separation gained per flight minute until every pair is predicted beyond
:data:`PLAN_SE` or the budget is spent. Writes ``plan.toml`` (a matrix ``campaign run`` flies),
``plan.json`` and ``plan.txt``.

Candidates: the ``--matrix`` given (its points, each with its own manoeuvres), or,
by default, one factor at a time away from every condition of the old data: 6,000 ft above and below,
Mach 0.1 either side, Mach 0.1 either side at the same dynamic pressure (:func:`same_lift_alt_ft`: about the
same alpha, which tells a term in Mach, or in alpha and Mach, from one in alpha alone), and the aircraft's
lowest, middle and highest flap angle; each gear up (2-3-1-1,
multisine) and gear down (2-3-1-1, multisine, gear extension, gear retraction); and, when a rival
is an airspeed error the data compatibility could not measure (it needs a heading change) and the
logs hold an inertial velocity, a full-circle level turn gear up at each condition. A flight already
in the old data is not a candidate.

A turn's worth to an airspeed rival is the data compatibility's measurement of the error: a steady
wind is told from an error along the track over the circle, to within the mean along-track gust
over the turn, ``sigma sqrt(2 L / (V T))`` (Dryden's scale length ``L``, the turbulence ``sigma`` the
diagnosis reconstructed, the turn's speed ``V`` and duration ``T``).
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from campaign.diagnosis.run import SAME_CONDITION, load_data
from campaign.errors import UserError
from campaign.orchestration.store import read_manifest
from campaign.simulation.aircraft import (
    AircraftSource,
    check_aircraft_folder,
    load_effects,
)
from campaign.simulation.engine import FlightConfig, check_flaps
from campaign.simulation.matrix import Matrix, StatusPoint, load_matrix
from diagnose import separation as sep
from diagnose.config import recorded
from identify.logs import Log
from infra.provenance import tool

#: Flights are added until every rival is predicted this far from its cause [standard errors]: the
#: measured separation scatters about the prediction by about one, and must clear the diagnosis's
#: ``settled_se`` (:class:`diagnose.config.DiagnosisSettings`).
PLAN_SE = 7.0
#: Default budget: this share of the old data's flight time.
BUDGET_SHARE = 0.25
#: Candidate manoeuvres by gear.
GEAR_UP = ("doublet", "multisine")
GEAR_DOWN = ("doublet", "multisine", "gear_extension", "gear_retraction")
#: Highest candidate altitude (the matrix's own bound) [ft].
MAX_ALT_FT = 45000.0
#: Excitation inputs: one per point (identification pairs one eq. (3) fit per gear).
EXCITATION = ("doublet", "multisine")
#: The greedy choice is also started from this many of the flights that gain most alone.
SEEDED = 8
#: Channels a turn needs to measure an airspeed error: an inertial velocity and heading.
TURN_NEEDS = ("psi_deg", "vn_fps", "ve_fps", "vd_fps")


def read_diagnosis(folder: Path) -> dict:
    """``diagnosis.json`` of a diagnosis folder, with one-line errors."""
    path = Path(folder) / "diagnosis.json"
    if not path.is_file():
        raise UserError(f"{path}: not found (--diagnosis takes the folder `campaign diagnose --out` wrote)")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise UserError(f"{path}: does not read as JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise UserError(f"{path}: not a diagnosis (a JSON object is expected)")
    if "rivals" not in doc:
        raise UserError(f"{path}: rivals: missing (written before rivals were measured); diagnose again")
    if not isinstance(doc["rivals"], list) or not all(
        isinstance(r, dict) and isinstance(r.get("separation_se"), (int, float)) for r in doc["rivals"]
    ):
        raise UserError(f"{path}: rivals: expected a list of rivals, each with its separation_se")
    for key in ("model", "data"):
        if key not in doc:
            raise UserError(f"{path}: {key}: missing; diagnose again")
    return doc


def open_rivals(doc: dict, where: Path) -> list[dict]:
    """The rivals not yet separated (below the ``settled_se`` the diagnosis was made with); a one-line
    error if there is nothing to separate."""
    rivals = doc["rivals"]
    if not rivals:
        raise UserError(f"{where}: rivals: nothing to separate (the diagnosis names no rival explanation)")
    settled_se = recorded(doc).settled_se
    left = [r for r in rivals if r["separation_se"] < settled_se]
    if not left:
        done = "; ".join(f"{r['rival']} at {r['separation_se']:.1f}" for r in rivals)
        raise UserError(
            f"{where}: rivals: nothing to separate (these data already reject every rival at "
            f"{settled_se:g} standard errors or more: {done})"
        )
    return left


def data_paths(doc: dict) -> list[Path]:
    d = doc["data"]
    return [Path(p) for p in d.get("paths", [d["path"]])]


def minutes(log: Log) -> float:
    t = log.data["t_s"].to_numpy()
    return float(t[-1] - t[0]) / 60.0


def _old_matrix(paths: list[Path]) -> Matrix | None:
    """The matrix the old campaign flew, if its manifest names one that still reads."""
    for p in paths:
        m = read_manifest(p) if p.is_dir() else None
        f = (m or {}).get("settings", {}).get("matrix")
        if f and Path(f).is_file():
            try:
                return load_matrix(f)
            except UserError:
                return None
    return None


def other_flaps(source: AircraftSource, like: Matrix | None, have: set[float]) -> list[float]:
    """Up to three flap angles not in ``have``: the aircraft's lowest, middle and highest, each snapped
    to the nearest angle of ``like``'s CLmax table in range (the stall margin is known there)."""
    from campaign.simulation.engine import flap_schedule

    s = flap_schedule(source)
    if not s.moves:
        return []
    lo, hi = s.range
    known = [f for f, _ in (like.clmax_by_flap if like else ()) if lo - 1e-6 <= f <= hi + 1e-6]
    out = []
    for f in (lo, 0.5 * (lo + hi), hi):
        f = min(known, key=lambda k: abs(k - f)) if known else round(f, 1)
        if f not in have and f not in out:
            out.append(float(f))
    return out


def _flyable_flap(source: AircraftSource, flap_deg: float) -> float:
    """A measured flap angle snapped into what the aircraft can fly (0 without flaps, else clipped
    to its range): imported data log the mean of a measured flap channel."""
    from campaign.simulation.engine import flap_schedule

    s = flap_schedule(source)
    if not s.moves:
        return 0.0
    lo, hi = s.range
    return float(min(max(round(flap_deg, 1), lo), hi))


def same_lift_alt_ft(alt_ft: float, mach: float, to_mach: float) -> float:
    """The pressure altitude [ft] at which ``to_mach`` has the dynamic pressure ``mach`` has at ``alt_ft``
    (the standard atmosphere of :func:`campaign.importing.importer.isa`; ``q = 0.7 p M^2``), rounded to 100 ft: at
    one weight the same lift coefficient, so about the same alpha at another Mach number (compressibility
    moves it a little). NaN outside 0-80,000 ft."""
    from scipy.optimize import brentq

    from campaign.importing.importer import isa

    target = float(isa(alt_ft)[0][0]) * (mach / to_mach) ** 2
    lo, hi = 0.0, 80000.0
    if not float(isa(hi)[0][0]) <= target <= float(isa(lo)[0][0]):
        return float("nan")
    alt = brentq(lambda h: float(isa(h)[0][0]) - target, lo, hi, xtol=1.0)
    return float(round(alt / 100.0) * 100.0)


#: A candidate at the dynamic pressure of another condition this close to a condition of the data at its Mach
#: number and flap angle is that condition [ft] (there and back, the 100 ft rounding can miss it by 100 ft).
SNAP_FT = 250.0


def _snapped(alt_ft: float, mach: float, flap_deg: float, known: set[tuple]) -> float:
    """``alt_ft``, or the altitude [ft] of a condition in ``known`` (alt, Mach, flap) at this Mach number
    and flap angle within :data:`SNAP_FT` of it."""
    near = [a for a, m, f in known if round(m, 4) == round(mach, 4) and f == flap_deg and abs(a - alt_ft) <= SNAP_FT]
    return min(near, key=lambda a: abs(a - alt_ft)) if near else alt_ft


def _condition(alt: float, mach: float, flap: float) -> tuple:
    return round(alt, 1), round(mach, 4), round(flap, 1)


def candidates(
    logs: list[Log],
    source: AircraftSource,
    like: Matrix | None,
    given: Matrix | None,
    held: set | None = None,
    turns: bool = False,
) -> list[StatusPoint]:
    """Candidate points, each with its candidate manoeuvres (see the module's docstring): one factor
    at a time away from each condition of the old data, at its weight, with a level turn gear up
    if ``turns``. None at a condition the diagnosis holds out (``held``): a flight there would be
    held out too."""
    held = {_condition(*c) for c in (held or ())}
    if given is not None:
        return [p for p in given.points if _condition(p.alt_ft, p.mach, p.flap_deg) not in held]
    weights = {}
    for lg in logs:
        weights.setdefault(lg.condition, lg.meta["status_point"].get("weight_lb"))
    conditions = sorted(weights)
    flaps = other_flaps(source, like, {_flyable_flap(source, f) for _, _, f in conditions})
    known = {(a, m, _flyable_flap(source, f)) for a, m, f in conditions}
    seen, out = set(), []
    for alt, mach, measured_flap in conditions:
        weight, flap = weights[(alt, mach, measured_flap)], _flyable_flap(source, measured_flap)
        variants = [
            (alt, mach, flap),
            (alt + 6000.0, mach, flap),
            (max(alt - 6000.0, 1500.0), mach, flap),
            (alt, round(mach - 0.1, 4), flap),
            (alt, round(mach + 0.1, 4), flap),
        ]
        variants += [
            (a, m, flap)
            for m in (round(mach - 0.1, 4), round(mach + 0.1, 4))
            if m > 0
            for a in [_snapped(same_lift_alt_ft(alt, mach, m), m, flap, known)]
            if a >= 1500.0
        ]
        variants += [(alt, mach, f) for f in flaps]
        for a, m, f in variants:
            if not (0.15 <= m <= 0.85 and a <= MAX_ALT_FT) or _condition(a, m, f) in held:
                continue
            for down in (False, True):
                if (a, m, f, down) not in seen:
                    seen.add((a, m, f, down))
                    up = GEAR_UP + (("level_turn",) if turns and f == flap else ())
                    out.append(StatusPoint(a, m, f, down, weight, GEAR_DOWN if down else up, "candidates"))
    return out


def _matrix(name: str, points: list[StatusPoint], like: Matrix | None) -> Matrix:
    return Matrix(
        name, name, tuple(points), like.maneuver_params if like else (), like.clmax_by_flap if like else (), ""
    )


def fly_candidates(
    points: list[StatusPoint],
    like: Matrix | None,
    model: Path,
    out: Path,
    jobs: int,
    progress: bool,
    rate_hz: float | None = None,
) -> list[Log]:
    """Fly the candidates on the model, noise-free, recorded at ``rate_hz`` (the old data's: the
    residuals are thinned per second, and the weights count rows), into ``out``; the logs flown."""
    from campaign.orchestration.runner import run_campaign
    from campaign.simulation.instruments import load_profile
    from identify.logs import read_campaign

    profile = "none"
    if rate_hz is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out.parent / "candidates.toml").write_text(f'extends = "none"\nrate_hz = {rate_hz!r}\n')
        profile = load_profile(str(out.parent / "candidates.toml"))
    cfg = FlightConfig(
        AircraftSource(str(model), load_effects(None)),
        0,
        profile,
        like.maneuver_params if like else (),
        like.clmax_by_flap if like else (),
    )
    run_campaign(_matrix("candidates", points, like), cfg, out, jobs=jobs, progress=progress)
    return read_campaign(out)


def flight_sums(
    logs: list[Log],
    rivals: list[dict],
    noise: dict,
    model: Path,
    jobs: int,
    turbulence_fps: float = 0.0,
    *,
    settled_se: float,
) -> list[list[list[dict]]]:
    """Per log, per rival: the sums each way (:func:`diagnose.separation.predicted`), and a level
    turn's measurement of an airspeed rival (:func:`with_turn`); ``settled_se``: the diagnosis's
    (:func:`to_measure`)."""
    from diagnose.evaluate import ModelEvaluator
    from diagnose.noise_floor import NoiseFloor
    from diagnose.residuals import residual_data

    evaluator = ModelEvaluator(model, jobs=jobs)
    try:
        frame = residual_data(logs, evaluator)
        keys = sorted({(h["channel"], h["error"]) for r in rivals for h in r["hypotheses"] if h["kind"] == "sensor"})
        sig = {}
        if keys:
            floor = NoiseFloor(logs, evaluator, {k: float(v) for k, v in noise.items()}, realizations=0, jobs=jobs)
            sig = sep.signatures(floor, keys)
    finally:
        evaluator.close()
    ids = frame["log"].to_numpy()
    out = []
    for i in range(len(logs)):
        rows = np.flatnonzero(ids == i)
        part = frame.iloc[rows].reset_index(drop=True)
        s = {k: v[:, rows] for k, v in sig.items()}
        per = []
        for r in rivals:
            context = {c: [sep.unclipped(sep.term_from_dict(t)) for t in ts] for c, ts in r.get("context", {}).items()}
            if to_measure(r, settled_se):
                turn = logs[i].maneuver == "level_turn" and airspeed_rival(r)
                per.append(measurement(measured_se(r, logs[i], turbulence_fps) if turn else 0.0))
                continue
            sums = sep.predicted(sep.Stack(part, r["weights"], s, context), r)
            if logs[i].maneuver == "level_turn" and airspeed_rival(r):
                sums = with_turn(sums, r, logs[i], turbulence_fps)
            per.append(sums)
        out.append(per)
    return out


def airspeed_rival(r: dict) -> bool:
    """Whether a rival is an airspeed error (what a turn measures)."""
    return r["kind"] == "sensor" and r["hypotheses"][1].get("channel") == "tas_kt"


def unmeasured(r: dict) -> bool:
    """Whether a rival is an instrument error the data compatibility could not measure."""
    return r["kind"] == "sensor" and r["hypotheses"][1].get("prior") is None


def turn_se(log: Log, turbulence_fps: float) -> float:
    """What the data compatibility will measure of the airspeed error along the track from this
    turn, one standard error [kt] (see the module's docstring)."""
    from identify.compat.result import DRYDEN_LENGTH_FT, FT_PER_KT, GUST_PRIOR_FLOOR_FPS

    t = log.data["t_s"].to_numpy(float)
    speed = float(np.median(log.data["tas_kt"])) * FT_PER_KT
    sigma = max(float(turbulence_fps), GUST_PRIOR_FLOOR_FPS)
    return sigma * np.sqrt(2.0 * DRYDEN_LENGTH_FT / speed / (t[-1] - t[0])) / FT_PER_KT


def to_measure(r: dict, settled_se: float) -> bool:
    """A rival the residuals already prefer to the cause (by ``settled_se``, the diagnosis's, or more),
    an instrument error the data compatibility could not measure: what settles it is a measurement of
    the error, nothing the residuals can add."""
    return unmeasured(r) and r["separation_se"] <= -settled_se


def measurement(z: float) -> list[dict]:
    """The sums each way of a measurement that finds the rival's error at ``z`` standard errors
    (:func:`diagnose.separation.left` gives ``z``; they add in squares over flights)."""
    st = {"G": np.ones((1, 1)), "b": np.zeros(1), "c": float(z) ** 2, "H": np.zeros((1, 1)), "C": np.zeros((1, 1))}
    return [st, dict(st)]


def error_se(r: dict, log: Log, turbulence_fps: float) -> float:
    """One standard error of the turn ``log``'s measurement of the airspeed rival's error, in its
    units (scale [-], bias [kt])."""
    se_kt = turn_se(log, turbulence_fps)
    return se_kt / float(np.median(log.data["tas_kt"])) if r["hypotheses"][1]["error"] == "scale" else se_kt


def measured_se(r: dict, log: Log, turbulence_fps: float) -> float:
    """How far the turn ``log`` will find the airspeed rival's error from 0 [standard errors]."""
    return abs(float(r["theta"][1][-1])) / error_se(r, log, turbulence_fps)


def with_turn(sums: list[dict], r: dict, log: Log, turbulence_fps: float) -> list[dict]:
    """A rival's sums each way (:func:`flight_sums`) plus the data compatibility's measurement of
    its airspeed error from the turn ``log``: a row on the sensor's own column (the last), which the
    cause's fit cannot follow; the cause taken as the truth makes it measure 0."""
    w = 1.0 / error_se(r, log, turbulence_fps)
    out = [{k: (np.array(v, float) if isinstance(v, np.ndarray) else v) for k, v in st.items()} for st in sums]
    out[0]["G"][-1, -1] += w * w  # the cause as the truth: the rival's error is measured at 0
    theta = float(r["theta"][1][-1])  # the rival as the truth: its error is measured
    out[1]["H"][-1, -1] += w * w
    out[1]["c"] = float(out[1]["c"]) + (w * theta) ** 2
    return out


def planned(sums: list[dict], base: tuple[float, float]) -> float:
    """The separation a rival will show: what the data in hand show (``base[0]``, signed) plus what
    the new flights add to the prediction (``base[1]``: the prediction for the data in hand)."""
    now, before = base
    lam = np.sign(now) * now**2 + sep.separation(sums) ** 2 - before**2
    return float(np.sign(lam) * np.sqrt(abs(lam)))


def choose(
    old: list[list[dict]], flights: list[dict], budget: float, base: list[tuple[float, float]]
) -> tuple[list[int], list[list[dict]]]:
    """Greedy choice: the flight that gains most :func:`planned` separation (capped at
    :data:`PLAN_SE` per rival, squared) per minute, until every rival reaches it or the budget is spent.
    Greedy by the minute can spend the budget on cheap flights and leave no room for the one long
    flight a rival needs (a turn), so it is also started from each of the :data:`SEEDED` flights that
    gain most alone, and the best end (most capped separation, then fewest minutes) is kept.

    ``flights``: ``{"minutes", "sums" (per rival), "point", "maneuver"}``; returns the chosen
    indices in order and the sums they reach."""

    def score(sums):
        return sum(min(max(planned(s, b), 0.0), PLAN_SE) ** 2 for s, b in zip(sums, base))

    def trial(now, j):
        return [sep.add(a, b) for a, b in zip(now, flights[j]["sums"])]

    def greedy(first: int | None):
        now, chosen, spent = old, [], 0.0
        if first is not None:
            now, chosen, spent = trial(old, first), [first], flights[first]["minutes"]
        while min(planned(s, b) for s, b in zip(now, base)) < PLAN_SE:
            excited = {flights[j]["point"] for j in chosen if flights[j]["maneuver"] in EXCITATION}
            current, best = score(now), None
            for j, f in enumerate(flights):
                if (
                    j in chosen
                    or spent + f["minutes"] > budget
                    or (f["maneuver"] in EXCITATION and f["point"] in excited)
                ):
                    continue
                t = trial(now, j)
                gain = (score(t) - current) / max(f["minutes"], 1e-6)
                if gain > 0 and (best is None or gain > best[0]):
                    best = (gain, j, t)
            if best is None:
                break
            chosen.append(best[1])
            now = best[2]
            spent += flights[best[1]]["minutes"]
        return score(now), -spent, chosen, now

    start = score(old)
    alone = sorted(
        (j for j, f in enumerate(flights) if f["minutes"] <= budget), key=lambda j: -(score(trial(old, j)) - start)
    )[:SEEDED]
    ends = [greedy(None)] + [greedy(j) for j in alone if score(trial(old, j)) > start]
    _, _, chosen, now = max(ends, key=lambda e: (round(e[0], 9), e[1]))
    return chosen, now


def plan(
    diagnosis: Path,
    out: Path | None = None,
    budget_min: float | None = None,
    matrix: str | None = None,
    jobs: int = 1,
    progress: bool = False,
) -> dict:
    """The whole plan; returns what ``plan.json`` holds (see the module's docstring)."""
    import shutil

    diagnosis = Path(diagnosis)
    doc = read_diagnosis(diagnosis)  # the arguments in the order a user gives them, before the rivals
    where = diagnosis / "diagnosis.json"
    settled_se = recorded(doc).settled_se
    if budget_min is not None and not 0 < budget_min < float("inf"):
        raise UserError(f"--budget-min: {budget_min:g} minutes; the plan needs a finite budget of more than 0")
    given = load_matrix(matrix) if matrix else None
    out = Path(out) if out else diagnosis / "plan"
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: is a file, not a folder (--out names a new folder for the plan)")
    if out.exists() and any(out.iterdir()):
        raise UserError(f"{out}: exists and is not empty; will not overwrite (choose another --out)")
    rivals = open_rivals(doc, where)
    model = check_aircraft_folder(Path(doc["model"]))
    paths = data_paths(doc)
    logs = []
    for i, p in enumerate(paths):
        try:
            logs += load_data(p)
        except UserError as exc:
            raise UserError(f"{where}: data.paths[{i}]: the logs diagnosed do not read any more ({exc})") from None
    held_paths = set(doc["data"].get("held_out", []))
    held = {lg.condition for lg in logs if lg.path in held_paths}
    old_minutes = sum(minutes(lg) for lg in logs)
    budget = BUDGET_SHARE * old_minutes if budget_min is None else float(budget_min)
    like = _old_matrix(paths)
    source = AircraftSource(str(model), load_effects(None))
    turns = any(airspeed_rival(r) for r in rivals) and all(c in lg.columns for lg in logs for c in TURN_NEEDS)
    points = candidates(logs, source, like, given, held, turns)
    if given is not None:
        check_flaps(source, [(f"{given.path}: {p.entry}.flap_deg", p.flap_deg) for p in points])
    flown_before = {(lg.point, lg.maneuver) for lg in logs}
    points = [replace(p, maneuvers=tuple(m for m in p.maneuvers if (p.id, m) not in flown_before)) for p in points]
    points = [p for p in points if p.maneuvers]
    if not points:
        raise UserError(
            f"{given.path if given else where}: points: no candidate flight left (each is flown "
            f"already or at a condition the diagnosis holds out)"
        )
    like = given or like
    rates = [1.0 / float(lg.meta["dt_s"]) for lg in logs if float(lg.meta.get("dt_s") or 0) > 0]
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        flown = fly_candidates(
            points, like, model, out / "candidates", jobs, progress, float(np.median(rates)) if rates else None
        )
        if not flown:
            raise UserError(
                f"{given.path if given else where}: points: the aircraft trims at none of the candidate points"
            )
        sums = flight_sums(
            flown,
            rivals,
            doc.get("noise_estimated", {}),
            model,
            jobs,
            (doc.get("data_compatibility") or {}).get("vertical_gust_rms_fps") or 0.0,
            settled_se=settled_se,
        )
    except BaseException:
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    old = [
        measurement(0.0)
        if to_measure(r, settled_se)
        else [{k: np.asarray(v, float) if k != "c" else float(v) for k, v in s.items()} for s in r["stats"]]
        for r in rivals
    ]
    base = [
        (0.0 if to_measure(r, settled_se) else float(r["separation_se"]), sep.separation(o))
        for r, o in zip(rivals, old)
    ]
    flights = [
        {"point": lg.point, "maneuver": lg.maneuver, "minutes": minutes(lg), "sums": s} for lg, s in zip(flown, sums)
    ]
    chosen, reached = choose(old, flights, budget, base)
    result = {
        "tool": tool(),
        "diagnosis": str(diagnosis),
        "model": str(model),
        "budget_min": budget,
        "old_minutes": old_minutes,
        "planned_minutes": sum(flights[j]["minutes"] for j in chosen),
        "target_se": PLAN_SE,
        "settled_se": settled_se,
        "candidates": len(flights),
        "rivals": [
            {
                "cause": r["cause"],
                "rival": r["rival"],
                "kind": r["kind"],
                "now_se": b[0],
                "predicted_now_se": b[1],
                "planned_se": planned(n, b),
                "to_measure": to_measure(r, settled_se),
                "residuals_se": float(r["separation_se"]),
            }
            for r, b, n in zip(rivals, base, reached)
        ],
        "flights": [
            {
                "point": flights[j]["point"],
                "maneuver": flights[j]["maneuver"],
                "minutes": flights[j]["minutes"],
                "alone_se": [planned(sep.add(o, s), b) for o, s, b in zip(old, flights[j]["sums"], base)],
                "extrapolated": extrapolation(
                    next(p for p in points if p.id == flights[j]["point"]), identified_at(model)
                ),
            }
            for j in chosen
        ],
    }
    result["matrix"] = None
    if chosen:
        chosen_points = {}
        by_id = {p.id: p for p in points}
        for j in chosen:
            p = by_id[flights[j]["point"]]
            chosen_points.setdefault(p.id, (p, []))[1].append(flights[j]["maneuver"])
        toml = out / "plan.toml"
        toml.write_text(matrix_toml(diagnosis.name, [(p, ms) for p, ms in chosen_points.values()], like))
        load_matrix(toml)  # what `campaign run` will read
        result["matrix"] = str(toml)
    text = report(result)
    (out / "plan.json").write_text(json.dumps(result, indent=1) + "\n")
    (out / "plan.txt").write_text(text)
    result["text"] = text
    return result


def identified_at(model: Path) -> dict | None:
    """The conditions a ``campaign model`` aircraft was identified at (its ``model.json``'s record starts):
    ``{"alt_ft": (lowest, highest), "mach": (lowest, highest)}``; None for another aircraft."""
    from campaign.importing.atmosphere import air_data

    try:
        trims = json.loads((Path(model) / "model.json").read_text()).get("trims") or []
        alt = np.array([float(t["alt_ft"]) for t in trims])
        mach = air_data(alt, np.array([float(t["tas_kt"]) for t in trims]))["mach"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    if not len(alt):
        return None
    return {"alt_ft": (float(alt.min()), float(alt.max())), "mach": (float(mach.min()), float(mach.max()))}


def extrapolation(point: StatusPoint, at: dict | None) -> str | None:
    """What a candidate ``point`` flies of a ``campaign model`` aircraft identified ``at``
    (:func:`identified_at`) beyond its records (their conditions widened by the held-out split's
    :data:`campaign.diagnosis.run.SAME_CONDITION`); None within them or for another aircraft."""
    if at is None:
        return None
    (a0, a1), (m0, m1) = at["alt_ft"], at["mach"]
    d_alt, d_mach = SAME_CONDITION[0], SAME_CONDITION[1]
    if a0 - d_alt <= point.alt_ft <= a1 + d_alt and m0 - d_mach <= point.mach <= m1 + d_mach:
        return None

    def span(lo: float, hi: float, form: str) -> str:
        return form.format(lo) if form.format(lo) == form.format(hi) else f"{form.format(lo)}-{form.format(hi)}"

    return (
        f"the model was identified at {span(a0, a1, '{:,.0f}')} ft, Mach {span(m0, m1, '{:.2f}')} (its model.json): "
        f"at {point.alt_ft:,.0f} ft, Mach {point.mach:.2f} it flies its extrapolation, and so does the prediction"
    )


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    return repr(float(v)) if isinstance(v, float) else str(v)


def matrix_toml(name: str, points: list[tuple[StatusPoint, list[str]]], like: Matrix | None) -> str:
    """A matrix file of the chosen flights (each point with its own manoeuvres), readable by
    :func:`campaign.simulation.matrix.load_matrix`."""
    lines = [
        f"# Flights planned by `campaign plan` to separate the rivals of diagnosis {name}.",
        f"name = {_value('plan-' + name)}",
        'description = "flights that separate a diagnosis\'s rivals"',
        "",
    ]
    for m, params in like.maneuver_params if like else ():
        lines.append(f"[maneuvers.{m}]")
        lines += [f"{k} = {_value(v)}" for k, v in params]
        lines.append("")
    if like and like.clmax_by_flap:
        lines.append("[stall.clmax_by_flap]")
        lines += [f"{_value(f'{f:g}')} = {_value(c)}" for f, c in like.clmax_by_flap]
        lines.append("")
    for p, ms in points:
        lines += [
            "[[points]]",
            f"gear = {_value('down' if p.gear_down else 'up')}",
            f"flap_deg = {_value(p.flap_deg)}",
            f"mach = {_value(p.mach)}",
            f"alt_ft = {_value(p.alt_ft)}",
            f"maneuvers = {_value(ms)}",
        ]
        if p.weight_lb is not None:
            lines.append(f"weight_lb = {_value(p.weight_lb)}")
        lines.append("")
    return "\n".join(lines)


def report(r: dict) -> str:
    """``plan.txt``."""
    lines = [
        "Flight plan",
        "===========",
        "",
        f"diagnosis: {r['diagnosis']}",
        f"model: {r['model']}",
        (
            f"budget: {r['budget_min']:.1f} min ({100 * r['budget_min'] / max(r['old_minutes'], 1e-9):.0f} % of the "
            f"{r['old_minutes']:.1f} min already flown); {r['candidates']} candidate flights flown on the model"
        ),
        "",
        (f"Rivals (separation in standard errors; settled at {r['settled_se']:g}, planned to {r['target_se']:g}):"),
    ]
    for x in r["rivals"]:
        if x.get("to_measure"):
            lines.append(
                f"  {x['cause']}  against  {x['rival']}: the residuals prefer the instrument error "
                f"({x['residuals_se']:+.1f}), which the data compatibility could not measure; the plan "
                f"measures it to {x['planned_se']:.1f} standard errors of its size"
            )
            continue
        lines.append(
            f"  {x['cause']}  against  {x['rival']}: {x['now_se']:+.1f} now, {x['planned_se']:+.1f} "
            f"predicted with the plan (now, plus what the plan adds to the {x['predicted_now_se']:.1f} "
            f"the fits expect of the data in hand)"
        )
    lines.append("")
    if not r["flights"]:
        lines.append(
            "No candidate flight separates them within the budget: raise --budget-min or give --matrix other points."
        )
    else:
        lines.append(
            f"Flights, in the order chosen ({r['planned_minutes']:.1f} min, "
            f"{100 * r['planned_minutes'] / max(r['old_minutes'], 1e-9):.0f} % more flight time):"
        )
        for f in r["flights"]:
            alone = ", ".join(f"{s:.1f}" for s in f["alone_se"])
            lines.append(f"  {f['point']} {f['maneuver']} ({f['minutes']:.2f} min): alone with the old data {alone}")
            if f.get("extrapolated"):
                lines.append(f"    {f['extrapolated']}")
        short = [x for x in r["rivals"] if x["planned_se"] < r["settled_se"]]
        if short:
            lines.append("Within the budget the plan does not settle: " + "; ".join(x["rival"] for x in short))
        lines += [
            "",
            f"Fly it:        campaign run --matrix {r['matrix']} --aircraft AIRCRAFT --out NEW",
            f"Then diagnose: campaign diagnose --data OLD --data NEW --model {r['model']} --out DIR",
        ]
    return "\n".join(lines) + "\n"
