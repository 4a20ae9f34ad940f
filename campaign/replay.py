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

from joblib import Parallel, delayed

from campaign.aircraft import AircraftSource, check_aircraft_folder, load_effects
from campaign.engine import FlightConfig, TrimError, check_flaps, fly, new_fdm
from campaign.errors import UserError
from campaign.matrix import StatusPoint
from campaign.store import write_log

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
            raise UserError(f"{p}: case[{i}].gear: expected \"retract\" or \"extend\"")
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
    point = StatusPoint(case.alt_ft, mach_for(source, case.alt_ft, case.ias_kt), case.flap_deg,
                        case.gear == "retract", case.weight_lb, (case.maneuver,))
    params = ((case.maneuver, (("hold", loop == "closed"), ("post_s", case.post_s), ("pre_s", case.pre_s))),)
    flight = fly(point, case.maneuver, FlightConfig(source, maneuver_params=params))
    flight.meta.update({"case": case.name, "loop": loop, "ias_kt_target": case.ias_kt})
    return flight


def _fly_one(case: ReplayCase, model: str, source: AircraftSource, loop: str, out: Path) -> tuple[str, str]:
    path = out / f"{case.name}__{model}__{loop}.parquet"
    try:
        flight = fly_case(case, source, loop)
    except TrimError as exc:
        return str(path), f"{case.name} on {model}: {exc}"
    flight.meta["model"] = model
    write_log(path, flight.log, flight.meta)
    return str(path), ""


def run_replays(results: Path, cases: list[ReplayCase], jobs: int = 1) -> list[str]:
    """Fly every case x model x loop into ``results/replays``; return failures."""
    results = Path(results)
    sources = aircraft_for(results)
    check_flaps(sources["reference"], [(f"case {c.name}.flap_deg", c.flap_deg) for c in cases])
    out = results / "replays"
    out.mkdir(parents=True, exist_ok=True)
    (out / "cases.json").write_text(json.dumps([vars(c) for c in cases], indent=1) + "\n")
    jobs_list = [(c, m, sources[m], lp) for c in cases for m in MODELS for lp in LOOPS]
    res = Parallel(n_jobs=jobs)(delayed(_fly_one)(c, m, s, lp, out) for c, m, s, lp in jobs_list)
    return [why for _, why in res if why]
