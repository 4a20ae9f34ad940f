"""``campaign model``: a whole JSBSim aircraft folder from an identification folder.

The identification's point models (``identification.json``), its gear model (``gear_surfaces.json``,
if any) and the metadata of the logs it was made from (mass, inertia, geometry, CG, thrust line)
become an aircraft (:mod:`identify.aircraft`). It is written into a staging folder, loaded by
JSBSim and trimmed at the start of each identified record (:mod:`campaign.modelling.trim`), then
moved into place: a refused or failed build leaves nothing behind.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from campaign.errors import UserError
from identify.aircraft import (
    NOMINAL_ASPECT_RATIO,
    NOMINAL_GEAR_TRAVEL_S,
    NOMINAL_INERTIA,
    Airframe,
    GearTravel,
    IdentificationError,
    PointModel,
    aircraft_xml,
    point_models,
)
from identify.logs import Log, LogError, campaign_files, read_csv, read_head, read_parquet
from identify.models import GearSurface
from infra.model import load_fdm
from infra.provenance import tool

#: slug -> lbf, as JSBSim converts its weights to mass.
SLUG_LB = 32.174049
#: The logged channels whose range a point model's description gives.
FLOWN = ("alpha_deg", "elevator_deg", "stabilizer_deg", "mach", "tas_kt")
#: The start of a record a trim is compared with [s].
HEAD_S = 1.0
#: The gear positions at equal fractions of its travel written into the aircraft.
GEAR_NODES = 11
#: What the aircraft folder holds beside its XML: what was built, from what, and its trims.
MODEL_JSON = "model.json"


@dataclass
class ModelBuild:
    """What ``campaign model`` built.

    Attributes
    ----------
    folder : Path
        The aircraft folder (``<name>.xml`` and ``model.json`` inside).
    name : str
    notes : list of str
        What the aircraft is made of and how it interpolates (as its XML says).
    trims : list of dict
        Per identified record: the steady flight at its first second and the logged values beside it.
    """

    folder: Path
    name: str
    notes: list[str]
    trims: list[dict]

    def lines(self) -> list[str]:
        """What the command prints."""
        out = [f"aircraft {self.name} in {self.folder}"] + [f"  {n}" for n in self.notes]
        for t in self.trims:
            if "error" in t:
                out.append(f"  trim at {t['point']}'s start: {t['error']}")
                continue
            pitch = t["pitch_control"]
            out.append(
                f"  trim at {t['point']}'s start ({t['alt_ft']:.0f} ft, {t['tas_kt']:.1f} kt, flight path "
                f"{t['gamma_deg']:+.2f} deg, {pitch} trims): alpha {t['alpha_deg']:.2f} deg "
                f"(logged {t['logged']['alpha_deg']:.2f}), {pitch} {t[pitch + '_deg']:.2f} deg "
                f"(logged {t['logged'][pitch + '_deg']:.2f}), thrust {t['thrust_lbf']:.0f} lbf "
                f"(logged {t['logged']['thrust_lbf']:.0f})"
            )
        return out


def _doc(folder: Path) -> tuple[Path, dict]:
    path = folder / "identification.json"
    if not folder.is_dir():
        raise UserError(f"{folder}: not a folder (an identification folder holds identification.json)")
    if not path.is_file():
        raise UserError(f"{path}: missing (no identification here: run campaign identify first)")
    try:
        return path, json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: not valid JSON ({getattr(exc, 'msg', exc)})") from None


def _read(path: Path) -> Log:
    return read_csv(path) if path.suffix == ".csv" else read_parquet(path)


def _logs(folder: Path, where: Path, doc: dict, points: list[PointModel]) -> dict[str, Log]:
    """Each point's log: where ``identification.json`` says, else among the logs of the folder above it."""
    out, nearby = {}, None
    for p in points:
        rel = doc["points"][p.point].get("log")
        path = (folder / rel) if isinstance(rel, str) else None
        if path is None or not path.is_file():
            if nearby is None:
                try:
                    nearby = {read_head(f).point: f for f in campaign_files(folder.parent)}
                except LogError:
                    nearby = {}
            path = nearby.get(p.point)
        if path is None:
            looked = f"{folder / rel} and " if isinstance(rel, str) else ""
            raise UserError(
                f"{where}: points.{p.point}.log: the log it was identified from is not found (looked in "
                f"{looked}{folder.parent}); its mass, inertia and geometry make the aircraft"
            )
        try:
            out[p.point] = _read(Path(path))
        except LogError as exc:
            raise UserError(str(exc)) from None
    return out


def _airframe(logs: list[Log]) -> Airframe:
    """Mass, inertia and geometry from the logs' metadata (the first log's; the weights of all)."""
    meta = logs[0].meta
    g, inertia = meta["geometry"], dict(meta["inertia_slugft2"])
    where = logs[0].path
    for key in ("S_ft2", "cbar_ft"):
        if not isinstance(g.get(key), (int, float)) or not g[key] > 0:
            raise UserError(f"{where}: metadata geometry.{key}: missing or not positive")
    if not inertia.get("iyy", 0.0) > 0:
        raise UserError(f"{where}: metadata inertia_slugft2.iyy: missing or not positive")
    nominal = []
    for k, share in NOMINAL_INERTIA.items():
        if not inertia.get(k, 0.0) > 0:
            inertia[k] = share * inertia["iyy"]
            nominal.append(f"{k} = {share:g} Iyy")
    inertia = {k: float(inertia.get(k, 0.0)) for k in ("ixx", "iyy", "izz", "ixz")}
    span = float(g.get("b_ft") or 0.0)
    if not span > 0:
        span = math.sqrt(NOMINAL_ASPECT_RATIO * g["S_ft2"])
        nominal.append(f"span (aspect ratio {NOMINAL_ASPECT_RATIO:g})")
    if "cg_x_in" in g:
        cg = (float(g["cg_x_in"]), float(g.get("cg_z_in", 0.0)))
    elif "xcg_in" in logs[0].data:
        cg = (float(np.mean([lg.data["xcg_in"].mean() for lg in logs])), 0.0)
    else:
        cg = (0.0, 0.0)
        nominal.append("CG station (the structural origin)")
    weights = [float(lg.data["mass_slug"].mean()) * SLUG_LB for lg in logs]
    return Airframe(
        float(g["S_ft2"]),
        float(g["cbar_ft"]),
        span,
        float(np.mean(weights)),
        min(weights),
        inertia,
        cg,
        float(g.get("thrust_z_arm_ft", 0.0)),
        tuple(nominal),
    )


def _gear_model(folder: Path) -> tuple[GearSurface | None, str | None]:
    """The identification's nonlinear gear model, else its linear one, else none."""
    path = folder / "gear_surfaces.json"
    if not path.is_file():
        return None, None
    try:
        doc = json.loads(path.read_text())
        for kind in ("nonlinear", "linear"):
            if kind in doc:
                return GearSurface.from_arrays(doc[kind]), kind
    except (ValueError, KeyError, TypeError) as exc:
        raise UserError(f"{path}: not a gear model this tool wrote ({type(exc).__name__}: {exc})") from None
    return None, None


def gear_travel(logs: list[Log]) -> GearTravel:
    """The gear's travel from the logged transitions (time and shape, averaged), or nominal."""
    times, shapes = [], []
    u = np.linspace(0.0, 1.0, GEAR_NODES)
    for lg in logs:
        t, g = lg.data["t_s"].to_numpy(), lg.data["gear_norm"].to_numpy()
        moving = np.flatnonzero(np.abs(g - g[0]) > 1e-6)
        if not moving.size or abs(abs(g[-1] - g[0]) - 1.0) > 1e-3:
            continue
        start = max(int(moving[0]) - 1, 0)
        end = start + int(np.flatnonzero(np.abs(g[start:] - g[-1]) < 1e-6)[0])
        times.append(t[end] - t[start])
        f, seg = (t[start : end + 1] - t[start]) / times[-1], g[start : end + 1]
        # the travel runs 0 -> 1 extending and 1 -> 0 retracting, the position a function of it
        shapes.append(np.interp(u, f, seg) if g[-1] > g[0] else np.interp(1.0 - u, f, seg))
    if not times:
        return GearTravel(NOMINAL_GEAR_TRAVEL_S)
    shape = np.maximum.accumulate(np.clip(np.mean(shapes, axis=0), 0.0, 1.0))
    shape[0], shape[-1] = 0.0, 1.0
    return GearTravel(float(np.mean(times)), tuple(map(float, shape)), f"from {len(times)} logged gear transition(s)")


def _transitions(logs: list[Log], limit: int = 8) -> list[Log]:
    """Up to ``limit`` gear-transition logs beside the identified ones."""
    try:
        heads = [read_head(f) for f in campaign_files(Path(logs[0].path).parent)]
    except LogError:
        return []
    return [h.read() for h in heads if h.transition][:limit]


def _trim_row(fdm, p: PointModel, log: Log, pitch: str) -> dict:
    from campaign.modelling.trim import ModelTrimError, trim_model

    d = log.data
    head = d[d["t_s"] < d["t_s"].iloc[0] + HEAD_S].mean()
    gamma = float(head.theta_deg - head.alpha_deg)
    logged = {
        "alpha_deg": float(head.alpha_deg),
        "elevator_deg": float(head.elevator_deg),
        "stabilizer_deg": float(head.stabilizer_deg),
        "thrust_lbf": float(head.thrust_lbf),
    }
    row = {
        "point": p.point,
        "alt_ft": float(head.alt_ft),
        "tas_kt": float(head.tas_kt),
        "gamma_deg": gamma,
        "flap_deg": float(head.flap_deg),
        "gear_norm": float(head.gear_norm),
        "logged": logged,
    }
    try:
        t = trim_model(
            fdm,
            row["alt_ft"],
            row["tas_kt"],
            gamma,
            row["flap_deg"],
            row["gear_norm"],
            logged["elevator_deg"],
            logged["stabilizer_deg"],
            logged["thrust_lbf"],
            logged["alpha_deg"],
            float(head.mass_slug) * SLUG_LB,
            pitch,
        )
    except ModelTrimError as exc:
        return {**row, "error": str(exc)}
    return {**row, **{k: v for k, v in vars(t).items() if k != "residual"}, "residual": list(t.residual)}


def pitch_control(points: list[PointModel]) -> str:
    """The surface that trims: the elevator where its Cm effect was identified, else the stabilizer."""
    if any("delevator_rad" in p.params["Cm"] for p in points) or not any(
        "dstabilizer_rad" in p.params["Cm"] for p in points
    ):
        return "elevator"
    return "stabilizer"


def build_model(identification: str | Path, out: str | Path, name: str | None = None, say=None) -> ModelBuild:
    """Write a JSBSim aircraft folder from an identification folder (``campaign model``).

    Parameters
    ----------
    identification : str or Path
        A folder ``campaign identify`` wrote (``identification.json``; the logs it names must be readable).
    out : str or Path
        The new aircraft folder; refused if it exists and holds anything.
    name : str, optional
        The aircraft's name, which JSBSim finds as ``<name>/<name>.xml``: the folder's name (default).
    say : callable, optional
        Called with each line of what was built.

    Returns
    -------
    ModelBuild

    Raises
    ------
    UserError
        One line naming the file and the field: no identification, no point fits, a point without
        parameters, its log not found, the log's metadata short of a mass or geometry; an ``out`` that
        holds something, a ``name`` that is not ``out``'s.
    """
    folder, out = Path(identification), Path(out)
    name = name or out.name
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
        raise UserError(f"--name {name!r}: letters, digits, '_', '.' and '-' only (it names the aircraft's files)")
    if name != out.name:
        raise UserError(
            f"--name {name}: JSBSim finds aircraft {name} in a folder of that name; --out is "
            f"{out.name} (give --out .../{name})"
        )
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UserError(f"{out}: exists; will not overwrite (choose another --out)")
    where, doc = _doc(folder)
    try:
        points = point_models(doc, str(where))
    except IdentificationError as exc:
        raise UserError(str(exc)) from None
    logs = _logs(folder, where, doc, points)
    points = [
        replace(
            p,
            condition=p.condition or logs[p.point].condition,
            flown={c: (float(logs[p.point].data[c].min()), float(logs[p.point].data[c].max())) for c in FLOWN},
        )
        for p in points
    ]
    airframe = _airframe(list(logs.values()))
    surface, kind = _gear_model(folder)
    gear = gear_travel(_transitions(list(logs.values())))
    tree, notes = aircraft_xml(name, points, airframe, surface, kind, gear, source=str(folder))
    stage = out.parent / f".{out.name}.partial"
    shutil.rmtree(stage, ignore_errors=True)
    try:
        (stage / "aircraft" / name).mkdir(parents=True)
        xml = stage / "aircraft" / name / f"{name}.xml"
        tree.write(xml, xml_declaration=True, encoding="unicode")
        try:
            fdm = load_fdm(stage, name)
        except ValueError as exc:  # a bug here, not bad input: say what JSBSim said
            raise RuntimeError(f"{xml}: JSBSim does not load the aircraft written ({exc})") from None
        pitch = pitch_control(points)
        trims = [_trim_row(fdm, p, logs[p.point], pitch) for p in points]
        del fdm
        (xml.parent / MODEL_JSON).write_text(
            json.dumps(
                {"tool": tool(), "name": name, "identification": str(folder.resolve()), "notes": notes, "trims": trims},
                indent=1,
            )
            + "\n"
        )
        out.parent.mkdir(parents=True, exist_ok=True)
        if out.exists():
            out.rmdir()  # empty (checked above)
        shutil.move(str(xml.parent), str(out))
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    result = ModelBuild(out, name, notes, trims)
    for line in result.lines() if say else ():
        say(line)
    return result
