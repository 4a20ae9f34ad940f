"""Replays: fly each case on the reference and on the identified models.

Each case starts from quasi-steady flight (each aircraft trimmed at the case's
altitude, airspeed, flap and weight) and runs a gear transition, open loop
(controls frozen: Part 60's uncontrolled free response) and closed loop (the
altitude/speed hold engaged).
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from pathlib import Path

from campaign.simulation.aircraft import AircraftSource, check_aircraft_folder, load_effects
from campaign.simulation.engine import FlightConfig, TrimError, check_flaps, fly, new_fdm
from campaign.errors import UserError
from campaign.simulation.matrix import StatusPoint
from campaign.orchestration.store import atomic_write, clean_temporaries, read_meta, write_log
from infra import pool

DEFAULT_CASES = Path(__file__).resolve().parent / "cases" / "replays.toml"
CASE_KEYS = {"name", "alt_ft", "ias_kt", "flap_deg", "gear", "weight_lb", "pre_s", "post_s"}
MODELS = ("reference", "linear", "nonlinear")
LOOPS = ("open", "closed")


@dataclass(frozen=True)
class ReplayCase:
    """One replay case.

    Attributes
    ----------
    name : str
    alt_ft : float
        Pressure altitude [ft].
    ias_kt : float
        Indicated (calibrated) airspeed [kt].
    flap_deg : float
        The aircraft's own flap angle [deg].
    gear : str
        ``"retract"`` or ``"extend"``.
    weight_lb : float or None
    pre_s, post_s : float
        Trimmed flight before the gear command, flight after the travel [s].
    """

    name: str
    alt_ft: float
    ias_kt: float
    flap_deg: float
    gear: str
    weight_lb: float | None = None
    pre_s: float = 5.0
    post_s: float = 15.0

    @property
    def maneuver(self) -> str:
        return "gear_extension" if self.gear == "extend" else "gear_retraction"


def load_cases(path: str | Path | None = None) -> list[ReplayCase]:
    """Read a cases file; bad input raises UserError naming file and field."""
    p = Path(path) if path else DEFAULT_CASES
    try:
        doc = tomllib.loads(p.read_text())
    except FileNotFoundError:
        raise UserError(f"{p}: cases file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{p}: TOML does not parse: {exc}") from None
    cases = []
    for i, c in enumerate(doc.get("case", [])):
        extra = sorted(set(c) - CASE_KEYS)
        if extra:
            raise UserError(f"{p}: case[{i}].{extra[0]}: unknown key")
        for k in ("name", "alt_ft", "ias_kt", "flap_deg", "gear"):
            if k not in c:
                raise UserError(f"{p}: case[{i}].{k}: missing")
        if c["gear"] not in ("retract", "extend"):
            raise UserError(f'{p}: case[{i}].gear: expected "retract" or "extend"')
        if isinstance(c["flap_deg"], bool) or not isinstance(c["flap_deg"], (int, float)):
            raise UserError(f"{p}: case[{i}].flap_deg: expected a number")
        if not c["ias_kt"] > 0:
            raise UserError(f"{p}: case[{i}].ias_kt: must be > 0")
        if c.get("pre_s", 5.0) < 5.0 or c.get("post_s", 15.0) < 15.0:
            raise UserError(f"{p}: case[{i}]: pre_s must be >= 5 and post_s >= 15 (FAA Part 60)")
        cases.append(ReplayCase(**c))
    if not cases:
        raise UserError(f"{p}: case: no [[case]] tables")
    return cases


def select(cases: list[ReplayCase], names: list[str] | None) -> list[ReplayCase]:
    """Cases whose name contains any of ``names`` (all if none given)."""
    if not names:
        return cases
    chosen = [c for c in cases if any(n in c.name for n in names)]
    if not chosen:
        raise UserError(f"--case: no case matches {', '.join(names)} (cases: {', '.join(c.name for c in cases)})")
    return chosen


def mach_for(source: AircraftSource, alt_ft: float, ias_kt: float) -> float:
    """Mach of a calibrated airspeed at a pressure altitude (JSBSim's atmosphere)."""
    fdm = new_fdm(source)
    fdm["ic/h-sl-ft"] = alt_ft
    fdm["ic/vc-kts"] = ias_kt
    return float(fdm["ic/mach"])


def aircraft_for(results: Path) -> dict[str, AircraftSource]:
    """The reference aircraft (the campaign's) and the two identified models."""
    man = json.loads((results / "manifest.json").read_text())
    st = man["settings"]
    ident = results / "identification"
    name = Path(st["aircraft"]).name
    out = {"reference": AircraftSource(st["aircraft"], load_effects(st["effects"]))}
    for kind in ("linear", "nonlinear"):
        folder = ident / f"aircraft_{kind}" / name
        if not folder.is_dir():
            raise UserError(f"{folder}: identified aircraft missing; run 'campaign identify {results}' first")
        out[kind] = AircraftSource(str(check_aircraft_folder(folder)), load_effects(None))
    return out


def fly_case(case: ReplayCase, source: AircraftSource, loop: str):
    """Fly one case on one aircraft, open or closed loop."""
    point = StatusPoint(
        case.alt_ft,
        mach_for(source, case.alt_ft, case.ias_kt),
        case.flap_deg,
        case.gear == "retract",
        case.weight_lb,
        (case.maneuver,),
    )
    params = ((case.maneuver, (("hold", loop == "closed"), ("post_s", case.post_s), ("pre_s", case.pre_s))),)
    flight = fly(point, case.maneuver, FlightConfig(source, maneuver_params=params))
    flight.meta.update({"case": case.name, "loop": loop, "ias_kt_target": case.ias_kt})
    return flight


def fly_one(case: ReplayCase, model: str, source: AircraftSource, loop: str) -> tuple[object, dict, str]:
    """``(log, meta, "")`` of one replay flight, or ``(None, {}, why)`` if it did not trim."""
    try:
        flight = fly_case(case, source, loop)
    except TrimError as exc:
        return None, {}, f"{case.name} on {model}: {exc}"
    flight.meta["model"] = model
    return flight.log, flight.meta, ""


def _fly_shipped(case: ReplayCase, model: str, shipment, effects, loop: str):
    """On a cluster worker: :func:`fly_one` on this machine's copy of the shipped aircraft."""
    from campaign.orchestration.cluster import unpack_source

    return fly_one(case, model, unpack_source(shipment, effects), loop)


def _log_name(case: ReplayCase, model: str, loop: str) -> str:
    return f"{case.name}__{model}__{loop}.parquet"


def _stamps(sources: dict[str, AircraftSource]) -> dict[str, dict]:
    """Per model, what its replays depend on besides the case and the loop: the aircraft's bytes."""
    return {m: {"aircraft_sha256": s.sha256, "effects_sha256": s.effects.sha256} for m, s in sources.items()}


def _stamp(case: ReplayCase, model: str, loop: str, stamps: dict[str, dict]) -> dict:
    """What one replay log was flown from, as its metadata records it (``replay_of``)."""
    return {"case": vars(case), "model": model, "loop": loop, **stamps[model]}


def replayed_already(results: Path, cases: list[ReplayCase]) -> set[tuple[str, str, str]]:
    """The (case, model, loop) flights of ``cases`` whose logs in ``results/replays`` are complete and
    were flown from this case on these aircraft as they are now (each log's ``replay_of``): a resumed
    run need not fly them again."""
    rep = Path(results) / "replays"
    if not rep.is_dir():
        return set()
    stamps = _stamps(aircraft_for(Path(results)))
    return {
        (c.name, m, lp)
        for c in cases
        for m in MODELS
        for lp in LOOPS
        if (read_meta(rep / _log_name(c, m, lp)) or {}).get("replay_of") == _stamp(c, m, lp, stamps)
    }


def run_replays(
    results: Path,
    cases: list[ReplayCase],
    jobs: int = 1,
    cases_file: str | Path | None = None,
    cluster: str | None = None,
    kept: set[tuple[str, str, str]] = frozenset(),
) -> list[str]:
    """Fly every case x model x loop into ``results/replays``; return failures.

    ``jobs`` local processes, or the Dask cluster whose scheduler is at ``cluster``
    (the aircraft travel as data; the logs come back and are written here).
    ``cases_file`` names the cases in error messages. The flights in ``kept``, (case name, model,
    loop), are not flown again (:func:`replayed_already`).
    """
    results = Path(results)
    sources = aircraft_for(results)
    where = Path(cases_file) if cases_file else DEFAULT_CASES
    check_flaps(sources["reference"], [(f"{where}: case {c.name}.flap_deg", c.flap_deg) for c in cases])
    client = None
    if cluster:  # before anything is written
        from campaign.orchestration.cluster import connect

        client = connect(cluster)
    out = results / "replays"
    out.mkdir(parents=True, exist_ok=True)
    clean_temporaries(out)
    text = json.dumps([vars(c) for c in cases], indent=1) + "\n"
    atomic_write(out / "cases.json", lambda tmp: Path(tmp).write_text(text))
    flights = [(c, m, lp) for c in cases for m in MODELS for lp in LOOPS if (c.name, m, lp) not in kept]
    stamps = _stamps(sources)
    if client is None:
        calls = [(c, m, sources[m], lp) for c, m, lp in flights]
        res = pool.results(pool.submit(fly_one, calls, jobs)) if jobs > 1 else (fly_one(*a) for a in calls)
    else:
        res = _on_cluster(client, flights, sources)
    failures = []
    for (c, m, lp), (log, meta, why) in zip(flights, res):
        if why:
            failures.append(why)
        else:
            write_log(out / _log_name(c, m, lp), log, {**meta, "replay_of": _stamp(c, m, lp, stamps)})
    return failures


def _on_cluster(client, flights: list, sources: dict[str, AircraftSource]):
    """Each flight's ``(log, meta, why)`` from the cluster, in order; a worker's death or error
    fails that flight only."""
    from campaign.orchestration.cluster import pack

    try:
        ships = {m: pack(s) for m, s in sources.items()}
        futures = [
            client.submit(_fly_shipped, c, m, ships[m], sources[m].effects, lp, pure=False) for c, m, lp in flights
        ]
        for (c, m, _), fut in zip(flights, futures):
            try:
                yield fut.result()
            except UserError:
                raise
            except Exception as exc:  # noqa: BLE001 - a worker's death or error fails its flight only
                first = (str(exc).splitlines() or [""])[0]
                yield None, {}, f"{c.name} on {m}: on the cluster ({type(exc).__name__}: {first})"
    finally:
        client.close()
