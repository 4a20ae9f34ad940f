"""The flight-test matrix (TOML) and its status points."""

from __future__ import annotations

import hashlib
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from campaign.errors import UserError
from maneuvers.library import MANEUVERS, maneuver_parameters

DEFAULT_MATRIX = Path(__file__).resolve().parent / "matrices" / "cai2024.toml"

TOP_KEYS = {"name", "description", "defaults", "maneuvers", "stall", "points"}
DEFAULT_KEYS = {"weight_lb", "maneuvers_gear_up", "maneuvers_gear_down"}
POINT_KEYS = {"gear", "flap_deg", "mach", "alt_ft", "weight_lb", "maneuvers"}
STALL_KEYS = {"clmax_by_flap"}


def flap_label(flap_deg: float) -> str:
    """A flap angle as point ids write it: ``05`` for 5 deg, ``2.5`` for 2.5 deg."""
    return f"{int(flap_deg):02d}" if float(flap_deg).is_integer() else f"{flap_deg:g}"


@dataclass(frozen=True, order=True)
class StatusPoint:
    """One status point of the matrix.

    Attributes
    ----------
    alt_ft : float
        Pressure altitude [ft].
    mach : float
        Mach number [-].
    flap_deg : float
        The aircraft's own flap angle, ``fcs/flap-pos-deg`` [deg].
    gear_down : bool
        Gear configuration of the point.
    weight_lb : float or None
        Gross weight [lb]; None keeps the aircraft's own.
    maneuvers : tuple of str
        Manoeuvres flown at this point, by name.
    entry : str
        The matrix entry it comes from, e.g. ``points[3]`` (for messages).
    """

    alt_ft: float
    mach: float
    flap_deg: float
    gear_down: bool
    weight_lb: float | None = None
    maneuvers: tuple[str, ...] = field(default=(), compare=False)
    entry: str = field(default="", compare=False)

    @property
    def id(self) -> str:
        """Stable readable id, e.g. ``h02000_m0.30_f05_gdn``."""
        pid = (
            f"h{int(round(self.alt_ft)):05d}_m{self.mach:.2f}_f{flap_label(self.flap_deg)}"
            f"_g{'dn' if self.gear_down else 'up'}"
        )
        if self.weight_lb is not None:
            pid += f"_w{int(round(self.weight_lb)):06d}"
        return pid


@dataclass(frozen=True)
class Matrix:
    """A parsed matrix: its points, manoeuvre parameters and stall data."""

    path: str
    name: str
    points: tuple[StatusPoint, ...]
    maneuver_params: tuple[tuple[str, tuple[tuple[str, float], ...]], ...]
    clmax_by_flap: tuple[tuple[float, float], ...]
    sha256: str

    def point(self, point_id: str) -> StatusPoint:
        for p in self.points:
            if p.id == point_id:
                return p
        raise UserError(f"{self.path}: point {point_id!r} is not in the matrix (see 'campaign points')")

    def params_for(self, maneuver: str) -> dict[str, float]:
        return dict(dict(self.maneuver_params).get(maneuver, ()))

    def clmax(self, flap_deg: float) -> float | None:
        return dict(self.clmax_by_flap).get(flap_deg)

    def to_json(self) -> dict:
        return {
            "path": self.path,
            "name": self.name,
            "sha256": self.sha256,
            "points": [p.id for p in self.points],
            "maneuvers": {m: dict(p) for m, p in self.maneuver_params},
            "clmax_by_flap": {f"{f:g}": c for f, c in self.clmax_by_flap},
        }


#: Manoeuvre parameters for which 0 means "leave it out" (no stabilizer 2-3-1-1). A level turn's
#: ``turn_s`` is left out of the matrix to take it from the trim; given, it is a time at full bank.
MAY_BE_ZERO = ("stabilizer_amplitude_deg",)
#: Manoeuvre parameters whose sign means something (a level turn's bank: negative turns left); the
#: manoeuvre checks their size.
SIGNED = ("bank_deg",)


#: The longest a manoeuvre's time parameter (``*_s``) may be [s].
MAX_DURATION_S = 600.0
#: Gross weights a point may ask for [lb].
WEIGHT_RANGE_LB = (100.0, 2.0e6)


def _number(path: str, where: str, value, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"{path}: {where}: expected a number, found {value!r}")
    if not math.isfinite(value):
        raise UserError(f"{path}: {where}: expected a finite number, found {value!r}")
    if positive and value <= 0:
        raise UserError(f"{path}: {where}: must be > 0, found {value!r}")
    return float(value)


def _weight(path: str, where: str, value) -> float:
    w = _number(path, where, value, positive=True)
    lo, hi = WEIGHT_RANGE_LB
    if not lo <= w <= hi:
        raise UserError(f"{path}: {where}: {w:g} lb is outside {lo:g}..{hi:g} lb")
    return w


def _values(path: str, where: str, value) -> list:
    """A number or a non-empty list of them, as a list."""
    if isinstance(value, list):
        if not value:
            raise UserError(f"{path}: {where}: an empty list (give at least one value)")
        return value
    return [value]


def _unknown(path: str, where: str, keys, allowed) -> None:
    extra = sorted(set(keys) - set(allowed))
    if extra:
        raise UserError(f"{path}: {where}{extra[0]}: unknown key (allowed: {', '.join(sorted(allowed))})")


def _maneuver_list(path: str, where: str, value) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise UserError(f"{path}: {where}: expected a list of manoeuvre names")
    if not value:
        raise UserError(f"{path}: {where}: an empty list (a point flies at least one manoeuvre)")
    dup = next((v for v in value if value.count(v) > 1), None)
    if dup:
        raise UserError(f"{path}: {where}: {dup!r} appears twice")
    for name in value:
        if name not in MANEUVERS:
            raise UserError(f"{path}: {where}: unknown manoeuvre {name!r} (known: {', '.join(MANEUVERS)})")
    if {"doublet", "multisine"} <= set(value):
        raise UserError(
            f"{path}: {where}: doublet and multisine both fit eq. (3) at the point; fly one of them "
            f"per point (identification pairs one fit per gear)"
        )
    return tuple(value)


def load_matrix(path: str | Path | None = None) -> Matrix:  # noqa: C901
    """Read and validate a matrix file.

    Raises
    ------
    UserError
        Unparseable TOML, unknown keys, Mach <= 0, flaps off the detents...,
        with the file and the field named.
    """
    p = Path(path) if path else DEFAULT_MATRIX
    if not p.is_file():
        raise UserError(f"{p}: matrix file not found")
    raw = p.read_bytes()
    try:
        doc = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{p}: TOML does not parse: {exc}") from None
    ps = str(p)
    _unknown(ps, "", doc.keys(), TOP_KEYS)
    for key in ("defaults", "maneuvers", "stall"):
        if not isinstance(doc.get(key, {}), dict):
            raise UserError(f"{ps}: {key}: expected a table [{key}]")
    title = doc.get("name", p.stem)
    if not isinstance(title, str) or not re.fullmatch(r"[^./\\\x00-\x1f][^/\\\x00-\x1f]{0,99}", title):
        raise UserError(
            f"{ps}: name: {str(title)[:40]!r} is not a folder name (the default results folder is "
            f"results/<name>: no '/', no leading '.', at most 100 characters)"
        )
    defaults = doc.get("defaults", {})
    _unknown(ps, "defaults.", defaults.keys(), DEFAULT_KEYS)
    man_up = _maneuver_list(ps, "defaults.maneuvers_gear_up", defaults.get("maneuvers_gear_up", ["doublet"]))
    man_dn = _maneuver_list(
        ps, "defaults.maneuvers_gear_down", defaults.get("maneuvers_gear_down", ["doublet", "gear_extension"])
    )
    weight0 = defaults.get("weight_lb")
    if weight0 is not None:
        weight0 = _weight(ps, "defaults.weight_lb", weight0)

    params = []
    for name, table in doc.get("maneuvers", {}).items():
        if name not in MANEUVERS:
            raise UserError(f"{ps}: maneuvers.{name}: unknown manoeuvre (known: {', '.join(MANEUVERS)})")
        if not isinstance(table, dict):
            raise UserError(f"{ps}: maneuvers.{name}: expected a table")
        allowed = maneuver_parameters(name)
        _unknown(ps, f"maneuvers.{name}.", table.keys(), allowed)
        items = []
        for k, v in sorted(table.items()):
            if k == "hold":
                if not isinstance(v, bool):
                    raise UserError(f"{ps}: maneuvers.{name}.hold: expected true or false")
                items.append((k, v))
            else:
                x = _number(ps, f"maneuvers.{name}.{k}", v, positive=k not in MAY_BE_ZERO + SIGNED)
                if x < 0 and k not in SIGNED:
                    raise UserError(f"{ps}: maneuvers.{name}.{k}: must be >= 0, found {v!r}")
                if k.endswith("_s") and x > MAX_DURATION_S:
                    raise UserError(
                        f"{ps}: maneuvers.{name}.{k}: {x:g} s is longer than a manoeuvre's {MAX_DURATION_S:g} s"
                    )
                items.append((k, x))
        try:
            from maneuvers.library import make_maneuver

            make_maneuver(name, **dict(items))
        except ValueError as exc:
            raise UserError(f"{ps}: maneuvers.{name}: {exc}") from None
        params.append((name, tuple(items)))

    stall = doc.get("stall", {})
    _unknown(ps, "stall.", stall.keys(), STALL_KEYS)
    clmax = []
    if not isinstance(stall.get("clmax_by_flap", {}), dict):
        raise UserError(f"{ps}: stall.clmax_by_flap: expected a table of flap angle = CLmax")
    for k, v in stall.get("clmax_by_flap", {}).items():
        try:
            flap = float(k)
        except ValueError:
            raise UserError(f"{ps}: stall.clmax_by_flap.{k}: key must be a flap angle [deg]") from None
        if not math.isfinite(flap):
            raise UserError(f"{ps}: stall.clmax_by_flap.{k}: key must be a flap angle [deg]")
        c = _number(ps, f"stall.clmax_by_flap.{k}", v, positive=True)
        if c > 5.0:
            raise UserError(f"{ps}: stall.clmax_by_flap.{k}: CLmax {c:g} is beyond any wing's (at most 5)")
        clmax.append((flap, c))

    entries = doc.get("points", [])
    if not isinstance(entries, list) or not entries:
        raise UserError(f"{ps}: points: expected at least one [[points]] table")
    points: list[StatusPoint] = []
    for i, e in enumerate(entries):
        where = f"points[{i}]"
        if not isinstance(e, dict):
            raise UserError(f"{ps}: {where}: expected a table")
        _unknown(ps, f"{where}.", e.keys(), POINT_KEYS)
        for key in ("gear", "flap_deg", "mach", "alt_ft"):
            if key not in e:
                raise UserError(f"{ps}: {where}.{key}: missing")
        gear = e["gear"]
        if gear not in ("up", "down"):
            raise UserError(f'{ps}: {where}.gear: expected "up" or "down", found {gear!r}')
        flap = _number(ps, f"{where}.flap_deg", e["flap_deg"])
        if not -90.0 <= flap <= 90.0:
            raise UserError(f"{ps}: {where}.flap_deg: {flap:g} is not a flap angle in degrees")
        machs = _values(ps, f"{where}.mach", e["mach"])
        alts = _values(ps, f"{where}.alt_ft", e["alt_ft"])
        machs = [_number(ps, f"{where}.mach", m, positive=True) for m in machs]
        for m in machs:
            if m >= 1.0:
                raise UserError(f"{ps}: {where}.mach: {m} is not subsonic")
        alts = [_number(ps, f"{where}.alt_ft", a) for a in alts]
        for a in alts:
            if not -1000 <= a <= 45000:
                raise UserError(f"{ps}: {where}.alt_ft: {a} outside -1000..45000 ft")
        weight = e.get("weight_lb", weight0)
        if weight is not None:
            weight = _weight(ps, f"{where}.weight_lb", weight)
        mans = (
            _maneuver_list(ps, f"{where}.maneuvers", e["maneuvers"])
            if "maneuvers" in e
            else (man_dn if gear == "down" else man_up)
        )
        for m in machs:
            for a in alts:
                points.append(StatusPoint(a, m, flap, gear == "down", weight, mans, where))
    ids = [p.id for p in points]
    dup = sorted({x for x in ids if ids.count(x) > 1})
    if dup:
        raise UserError(f"{ps}: points: status point {dup[0]} appears twice")
    return Matrix(
        str(p.resolve()), title, tuple(points), tuple(params), tuple(sorted(clmax)), hashlib.sha256(raw).hexdigest()
    )
