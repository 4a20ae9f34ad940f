"""``campaign import``: measured data as flight-test departments deliver it, into the log schema.

A map (TOML) says where each schema channel is in the source file and in which
unit; units are parsed and converted by pint. Channels the source lacks are
given as constants or derived: Mach, calibrated airspeed and dynamic pressure
from true airspeed and pressure altitude through the standard atmosphere
(ambiance, ISA 1993); the pitch acceleration is left to the identification,
which derives it from q. Every file is read and checked before anything is
written; the logs are Parquet in the schema with their metadata, and an import
report names what was mapped, set and derived.
"""

from __future__ import annotations

import hashlib
import json
import re
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from campaign.simulation.catalog import LOG_COLUMNS
from campaign.errors import UserError
from campaign.importing.atmosphere import air_data, isa  # noqa: F401 (isa: the plan's)
from campaign.importing.declared import check_gravity, normal_gravity_fps2, parse_accuracy, parse_records, windows
from campaign.importing.guard import MAX_POSITION_FT, bounded, check_columns, check_log, check_rate, check_text, shown
from campaign.simulation.instruments import POSITIONED
from infra.provenance import tool

FORMATS = {
    ".csv": "csv",
    ".txt": "whitespace",
    ".dat": "whitespace",
    ".asc": "whitespace",
    ".mat": "mat",
    ".parquet": "parquet",
}
SECTIONS = {
    "source": {"format", "columns", "variable", "skip_rows", "encoding"},
    "time": {"column", "unit"},
    "channels": None,
    "constants": None,
    "positions": None,
    "accuracy": None,
    "records": None,
    "aircraft": {
        "mass",
        "ixx",
        "iyy",
        "izz",
        "ixz",
        "S",
        "cbar",
        "b",
        "thrust_z_arm",
        "cg_x",
        "cg_z",
        "aerorp_x",
        "aerorp_z",
        "latitude",
        "gravity",
    },
}
#: Our channel-name suffixes and the unit each stands for (pint spells them; pint converts).
SUFFIX_UNITS = (
    ("_dps2", "degree / second ** 2"),
    ("_dps", "degree / second"),
    ("_fps2", "foot / second ** 2"),
    ("_fps", "foot / second"),
    ("_deg", "degree"),
    ("_kt", "knot"),
    ("_ft", "foot"),
    ("_psf", "force_pound / foot ** 2"),
    ("_lbf", "force_pound"),
    ("_slug", "slug"),
    ("_in", "inch"),
    ("_norm", "dimensionless"),
    ("_s", "second"),
)
AIRCRAFT_UNITS = {
    "mass": "slug",
    "ixx": "slug * foot ** 2",
    "iyy": "slug * foot ** 2",
    "izz": "slug * foot ** 2",
    "ixz": "slug * foot ** 2",
    "S": "foot ** 2",
    "cbar": "foot",
    "b": "foot",
    "thrust_z_arm": "foot",
    "cg_x": "inch",
    "cg_z": "inch",
    "aerorp_x": "inch",
    "aerorp_z": "inch",
    "latitude": "degree",
    "gravity": "foot / second ** 2",
}
#: Schema channels eq. (1) and the states need; Mach and the dynamic pressure can be derived.
NEEDED = (
    "alt_ft",
    "tas_kt",
    "alpha_deg",
    "theta_deg",
    "p_dps",
    "q_dps",
    "r_dps",
    "ax_fps2",
    "az_fps2",
    "thrust_lbf",
    "elevator_deg",
    "stabilizer_deg",
    "flap_deg",
    "gear_norm",
)
DERIVABLE = ("mach", "qbar_psf", "ias_kt")
#: Sampling-interval jitter (share of the median interval) above which the log is put on a uniform grid,
#: and gaps (in intervals) that are refused.
JITTER, GAP = 0.01, 2.5
#: Status points of imported logs: conditions this close are one condition (gear up/down pairs).
ALT_GRID_FT, MACH_GRID = 500.0, 0.01


_UREG = None


def ureg():
    """The shared pint registry."""
    global _UREG
    if _UREG is None:
        import pint

        _UREG = pint.UnitRegistry()
    return _UREG


def schema_unit(column: str) -> str:
    """The unit a schema column's name carries."""
    if column == "mach":
        return "dimensionless"
    for suffix, unit in SUFFIX_UNITS:
        if column.endswith(suffix):
            return unit
    return "dimensionless"


def factor(path: str, where: str, unit: str, target: str) -> float:
    """Multiplier from ``unit`` to ``target`` (pint), or a one-line error naming the key."""
    import pint

    u = ureg()
    if not unit:
        if u.Quantity(1.0, target).dimensionless and target == "dimensionless":
            return 1.0
        raise UserError(f"{path}: {where}: needs a unit (the schema column is in {target})")
    try:
        q = u.Quantity(1.0, unit)
    except (
        pint.errors.UndefinedUnitError,
        pint.errors.DefinitionSyntaxError,
        AttributeError,
        TypeError,
        ValueError,
        AssertionError,
    ) as exc:
        raise UserError(f"{path}: {where}: unit {unit!r} does not parse ({type(exc).__name__})") from None
    try:
        return float(q.to(target).magnitude)
    except pint.errors.DimensionalityError:
        raise UserError(
            f"{path}: {where}: unit {unit!r} is {q.dimensionality}, not {u.Quantity(1.0, target).dimensionality} "
            f"as {target}"
        ) from None
    except pint.errors.OffsetUnitCalculusError:
        raise UserError(f"{path}: {where}: unit {unit!r} has an offset; give it in an absolute unit") from None


def _split(text: str) -> tuple[str, str]:
    """``"NAME unit..."`` -> (name, unit); the unit may hold spaces."""
    parts = text.strip().split(None, 1)
    return (parts[0], parts[1].strip()) if len(parts) == 2 else (parts[0] if parts else "", "")


def _quantity(path: str, where: str, value, target: str) -> float:
    """A constant: a number (in the target's unit) or ``"number unit"``."""
    if isinstance(value, bool):
        raise UserError(f'{path}: {where}: expected a number or "number unit", found {value!r}')
    if isinstance(value, (int, float)):
        if not np.isfinite(value):
            raise UserError(f"{path}: {where}: {value!r} is not a finite number")
        return float(value)
    if not isinstance(value, str):
        raise UserError(f'{path}: {where}: expected a number or "number unit", found {value!r}')
    num, unit = _split(value)
    try:
        x = float(num)
    except ValueError:
        raise UserError(f"{path}: {where}: {shown(value)} does not start with a number") from None
    x = x * factor(path, where, unit, target) if unit else x
    if not np.isfinite(x):
        raise UserError(f"{path}: {where}: {shown(value)} is not a finite number")
    return x


@dataclass(frozen=True)
class ImportMap:
    """A parsed, checked import map.

    Attributes
    ----------
    channels : tuple of (schema column, source column, factor to the schema unit)
    constants : tuple of (schema column, value in the schema unit)
    aircraft : tuple of (key, value in slug, ft, slug ft^2, in, deg)
    """

    path: str
    sha256: str
    format: str | None = None
    columns: tuple[str, ...] = ()
    variable: str | None = None
    time_column: str = ""
    time_factor: float = 1.0
    channels: tuple[tuple[str, str, float], ...] = ()
    constants: tuple[tuple[str, float], ...] = ()
    aircraft: tuple[tuple[str, float], ...] = ()
    positions: tuple[tuple[str, tuple[float, float, float]], ...] = ()  # documented sensor positions [ft]
    units: dict = field(default_factory=dict, compare=False, hash=False)  # schema column -> source unit text
    accuracy: dict = field(default_factory=dict, compare=False, hash=False)  # channel -> declared accuracy
    records: tuple[float, ...] = ()  # times [s] one file is cut at into records
    skip_rows: int = 0  # text files: lines before the header row (or the data, with ``columns``)
    encoding: str = "utf-8"  # text files: the characters' encoding


def load_map(path: str | Path) -> ImportMap:  # noqa: C901
    """Parse and check an import map.

    Raises
    ------
    UserError
        One line naming the file and the key: unknown sections, keys or schema
        columns, units that do not parse or have the wrong dimension, a missing
        time column, a needed channel neither mapped nor constant.
    """
    p = Path(path)
    ps = str(p)
    if not p.is_file():
        raise UserError(f"{ps}: import map not found")
    raw = p.read_bytes()
    try:
        doc = tomllib.loads(raw.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"{ps}: TOML does not parse: {exc}") from None
    for sec, v in doc.items():
        if sec not in SECTIONS:
            raise UserError(f"{ps}: [{sec}]: unknown section (allowed: {', '.join(SECTIONS)})")
        if not isinstance(v, dict):
            raise UserError(f"{ps}: {sec}: expected a table [{sec}]")
        allowed = SECTIONS[sec]
        if allowed is not None and set(v) - allowed:
            raise UserError(
                f"{ps}: {sec}.{sorted(set(v) - allowed)[0]}: unknown key (allowed: {', '.join(sorted(allowed))})"
            )
    src, tim = doc.get("source", {}), doc.get("time", {})
    fmt = src.get("format")
    if fmt is not None and fmt not in set(FORMATS.values()):
        raise UserError(f"{ps}: source.format: {fmt!r} is not one of csv, whitespace, mat, parquet")
    cols = src.get("columns", [])
    if not isinstance(cols, list) or not all(isinstance(c, str) and c for c in cols):
        raise UserError(f"{ps}: source.columns: expected a list of column names")
    if len(set(cols)) != len(cols):
        raise UserError(f"{ps}: source.columns: {next(c for c in cols if cols.count(c) > 1)!r} appears twice")
    var = src.get("variable")
    if var is not None and not isinstance(var, str):
        raise UserError(f"{ps}: source.variable: expected the name of a variable in the .mat file")
    skip, encoding = _text_options(ps, src)
    if not isinstance(tim.get("column"), str) or not tim.get("column"):
        raise UserError(f"{ps}: time.column: missing (the source column holding time)")
    t_factor = factor(ps, "time.unit", str(tim.get("unit", "s")), "second")
    channels, units = [], {"t_s": str(tim.get("unit", "s"))}
    for col, spec in doc.get("channels", {}).items():
        where = f"channels.{col}"
        if col not in LOG_COLUMNS or col == "t_s":
            raise UserError(f"{ps}: {where}: {col!r} is not a log-schema column")
        if not isinstance(spec, str) or not spec.strip():
            raise UserError(f'{ps}: {where}: expected "SOURCE_COLUMN unit"')
        name, unit = _split(spec)
        channels.append((col, name, factor(ps, where, unit, schema_unit(col))))
        units[col] = unit
    constants = []
    for col, value in doc.get("constants", {}).items():
        where = f"constants.{col}"
        if col not in LOG_COLUMNS or col == "t_s":
            raise UserError(f"{ps}: {where}: {col!r} is not a log-schema column")
        if col in dict((c, 0) for c, *_ in channels):
            raise UserError(f"{ps}: {where}: {col!r} is mapped in [channels] too")
        constants.append((col, _quantity(ps, where, value, schema_unit(col))))
    aircraft = []
    for key, value in doc.get("aircraft", {}).items():
        unit, where = AIRCRAFT_UNITS[key], f"aircraft.{key}"
        x = _quantity(ps, where, value, unit)
        aircraft.append(
            (key, check_gravity(ps, where, x, value) if key == "gravity" else bounded(ps, where, key, x, unit))
        )
    accuracy = parse_accuracy(ps, doc.get("accuracy", {}), _quantity, schema_unit)
    records = parse_records(ps, doc["records"]) if "records" in doc else ()
    positions = []
    for col, value in doc.get("positions", {}).items():
        where = f"positions.{col}"
        if col not in POSITIONED:
            raise UserError(f"{ps}: {where}: a documented position applies only to {', '.join(POSITIONED)}")
        if not isinstance(value, list) or len(value) != 3:
            raise UserError(
                f'{ps}: {where}: expected [x, y, z] from the CG, body axes (numbers in ft, or "number unit" strings)'
            )
        xyz = tuple(_quantity(ps, where, v, "foot") for v in value)
        if max(abs(x) for x in xyz) > MAX_POSITION_FT:
            raise UserError(
                f"{ps}: {where}: {max(abs(x) for x in xyz):g} ft from the CG; a sensor is within {MAX_POSITION_FT:g} ft"
            )
        positions.append((col, xyz))
    have = {c for c, *_ in channels} | {c for c, _ in constants}
    if "mass_slug" not in have and "mass" not in dict(aircraft):
        raise UserError(f"{ps}: aircraft.mass: missing (or map mass_slug)")
    for col in NEEDED:
        if col not in have:
            hint = (
                " (a missing stabilizer, flap or gear must be given as a constant)"
                if col in ("stabilizer_deg", "flap_deg", "gear_norm")
                else ""
            )
            raise UserError(f"{ps}: {col}: neither mapped in [channels] nor given in [constants]{hint}")
    for ref in ("S", "cbar"):
        if ref not in dict(aircraft):
            raise UserError(f"{ps}: aircraft.{ref}: missing (eq. 1 needs the reference area and chord)")
    return ImportMap(
        ps,
        hashlib.sha256(raw).hexdigest(),
        fmt,
        tuple(cols),
        var,
        tim["column"],
        t_factor,
        tuple(channels),
        tuple(constants),
        tuple(aircraft),
        tuple(positions),
        units,
        accuracy,
        records,
        skip,
        encoding,
    )


#: The most lines ``source.skip_rows`` skips (a preamble, not a file).
MAX_SKIP_ROWS = 10_000


def _text_options(ps: str, src: dict) -> tuple[int, str]:
    """``source.skip_rows`` and ``source.encoding``, checked."""
    import codecs

    skip, encoding = src.get("skip_rows", 0), src.get("encoding", "utf-8")
    if isinstance(skip, bool) or not isinstance(skip, int) or not 0 <= skip <= MAX_SKIP_ROWS:
        raise UserError(
            f"{ps}: source.skip_rows: {shown(skip)} is not a whole number of lines from 0 to {MAX_SKIP_ROWS:,}"
        )
    try:
        if not isinstance(encoding, str):
            raise LookupError
        codecs.lookup(encoding)
    except LookupError:
        raise UserError(f"{ps}: source.encoding: {shown(encoding)} is not a text encoding Python knows") from None
    return skip, encoding


# ----------------------------------------------------------------------------- reading


def _mat(path: Path, m: ImportMap) -> pd.DataFrame:
    from scipy.io import loadmat

    try:
        doc = loadmat(path, squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises several types for a bad file
        raise UserError(f"{path}: not a readable .mat file ({type(exc).__name__}: {exc})") from None
    names = [k for k in doc if not k.startswith("__")]
    if m.variable is not None:
        if m.variable not in doc:
            raise UserError(f"{path}: source.variable: {m.variable!r} is not in the file ({', '.join(names)})")
        obj = doc[m.variable]
        if hasattr(obj, "_fieldnames"):
            return pd.DataFrame({f: np.ravel(getattr(obj, f)) for f in obj._fieldnames})
        arr = np.atleast_2d(np.asarray(obj, dtype=float))
        if arr.shape[0] == len(m.columns) and arr.shape[1] != len(m.columns):
            arr = arr.T
        if arr.shape[1] != len(m.columns):
            raise UserError(
                f"{path}: source.columns: {m.variable!r} has {arr.shape[1]} columns, the map names {len(m.columns)}"
            )
        return pd.DataFrame(arr, columns=list(m.columns))
    vectors = {k: np.ravel(doc[k]) for k in names if np.ndim(doc[k]) == 1 and np.size(doc[k]) > 1}
    arrays = [k for k in names if np.ndim(doc[k]) == 2 and np.asarray(doc[k]).dtype.kind in "fiu"]
    if not vectors and len(arrays) == 1 and m.columns:  # one record per file, each named after its file
        return _mat(path, replace(m, variable=arrays[0]))
    if not vectors:
        raise UserError(f"{path}: source.variable: no vectors at the top of the file; name the array or struct")
    return pd.DataFrame(vectors)


def _format_hint(path: Path, m: ImportMap) -> str:
    """Where the map's ``source.format`` differs from what the file's suffix says: both (else nothing)."""
    by_suffix = FORMATS.get(path.suffix.lower())
    if m.format and by_suffix and by_suffix != m.format:
        return f'; source.format in {m.path} reads it as "{m.format}", its suffix {path.suffix} says "{by_suffix}"'
    return ""


def read_source(path: str | Path, m: ImportMap) -> pd.DataFrame:
    """The source file as a table of named columns (one line naming the file on failure)."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: file not found")
    fmt = m.format or FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise UserError(f"{path}: cannot tell the format from {path.suffix!r}; set source.format in {m.path}")
    names = list(m.columns) or None
    if fmt in ("csv", "whitespace"):
        check_text(path, fmt)
    elif fmt == "parquet":
        try:
            check_columns(path, len(pq.read_schema(path).names))
        except (OSError, ValueError) as exc:
            raise UserError(
                f"{path}: not readable as parquet ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})"
            ) from None
    try:
        text = {"skiprows": m.skip_rows, "encoding": m.encoding, "header": None if names else "infer", "names": names}
        if fmt == "csv":
            df = pd.read_csv(path, skipinitialspace=True, **text)
        elif fmt == "whitespace":
            df = pd.read_csv(path, sep=r"\s+", comment="#", **text)
        elif fmt == "parquet":
            df = pd.read_parquet(path)
        else:
            df = _mat(path, m)
    except UserError as exc:
        raise UserError(f"{exc}{_format_hint(path, m)}") from None
    except UnicodeDecodeError as exc:
        raise UserError(
            f"{path}: not readable as {m.encoding} text (it holds the byte {exc.object[exc.start]:#04x}): "
            f'set source.encoding in {m.path} (a German or French record is often "latin-1")'
        ) from None
    except (ValueError, OSError, pd.errors.ParserError) as exc:
        raise UserError(
            f"{path}: not readable as {fmt} ({type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:120]})"
            + _format_hint(path, m)
        ) from None
    if names and fmt in ("parquet",):
        missing = [c for c in names if c not in df.columns]
        if missing:
            raise UserError(f"{path}: source.columns: {missing[0]!r} is not a column of the file")
    df.columns = [str(c).strip() for c in df.columns]
    return df


def _numeric(path: Path, df: pd.DataFrame, col: str, where: str) -> np.ndarray:
    if col not in df.columns:
        raise UserError(
            f"{path}: {where}: source column {shown(col)} not in the file (it has "
            f"{', '.join(shown(str(c), 24) for c in df.columns[:12])}{'...' if len(df.columns) > 12 else ''})"
        )
    values = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise UserError(
            f"{path}: column {shown(col)}, row {bad[0] + 1}: not a finite number ({shown(df[col].iloc[bad[0]])})"
        )
    return values


# ----------------------------------------------------------------------------- conversion


@dataclass
class Imported:
    """One converted file: the log, its metadata and its report entry."""

    source: str
    name: str
    log: pd.DataFrame
    meta: dict
    report: dict


def _time(path: Path, df: pd.DataFrame, m: ImportMap) -> np.ndarray:
    t = _numeric(path, df, m.time_column, "time.column") * m.time_factor
    dt = np.diff(t)
    bad = np.flatnonzero(dt <= 0)
    if bad.size:
        i = bad[0] + 1
        raise UserError(
            f"{path}: time column {m.time_column!r}, row {i + 1}: time does not increase "
            f"({t[i]:g} s after {t[i - 1]:g} s)"
        )
    if len(t) < 10:
        raise UserError(f"{path}: only {len(t)} rows")
    step = float(np.median(dt))
    t0 = t - t[0]
    # a gap the map cuts the file at ends one record and starts the next
    at_cut = np.zeros(len(dt), dtype=bool)
    at_cut[np.clip(np.searchsorted(t0, m.records, side="left") - 1, 0, len(dt) - 1)] = True
    gaps = np.flatnonzero((dt > GAP * step) & ~at_cut)
    if gaps.size:
        cuts = ", ".join(f"{c:.12g}" for c in sorted({*m.records, float(t0[gaps[0]] + dt[gaps[0]] / 2)}))
        raise UserError(
            f"{path}: time column {m.time_column!r}, row {gaps[0] + 2}: a gap of {dt[gaps[0]]:g} s "
            f"in {step:g} s samples (cut the file there: [records] split_s = [{cuts}])"
        )
    return t


def _maneuver(gear: np.ndarray) -> str:
    if gear[0] <= 0.05 and gear[-1] >= 0.95:
        return "gear_extension"
    if gear[0] >= 0.95 and gear[-1] <= 0.05:
        return "gear_retraction"
    return "excitation"


def schema_log(
    name: str,
    t_s: np.ndarray,
    cols: dict[str, np.ndarray],
    air: dict[str, float],
    positions=(),
    step: float | None = None,
    extra: dict | None = None,
) -> tuple[pd.DataFrame, dict]:
    """A log in the schema and its metadata, from channels in the schema's units.

    What the channels lack is filled in: ``mass_slug`` from ``air["mass"]``; Mach, calibrated
    airspeed and dynamic pressure from true airspeed and pressure altitude (:func:`air_data`); the
    pitch acceleration is left to the identification. The status point is the first second's mean
    (altitude snapped to :data:`ALT_GRID_FT`, Mach to :data:`MACH_GRID`; gear from the first
    sample), the manoeuvre a gear extension or retraction if the gear moves from one end to the
    other, else an excitation.

    Parameters
    ----------
    name : str
        The log's name (its status point's id and its file's stem).
    t_s : ndarray
        Time from the start [s].
    cols : dict of str to ndarray
        Schema columns (``t_s`` excluded), units as in their names.
    air : dict
        ``mass`` [slug], ``ixx``, ``iyy``, ``izz``, ``ixz`` [slug ft^2], ``S`` [ft^2], ``cbar``, ``b``,
        ``thrust_z_arm`` [ft], ``cg_x``, ``cg_z``, ``aerorp_x``, ``aerorp_z`` [in], ``latitude`` [deg];
        ``S`` and ``cbar`` are needed, the inertias 0 and the arms 0 when absent, the positions absent.
    positions : iterable of (channel, (x, y, z))
        Documented sensor positions from the CG [ft].
    step : float, optional
        Sampling interval [s] (default: the median of ``t_s``'s).
    extra : dict, optional
        More metadata (where the log came from).
    """
    cols = dict(cols)
    n = len(t_s)
    if "mass_slug" not in cols:
        cols["mass_slug"] = np.full(n, air["mass"])
    derived = {}
    need = [c for c in DERIVABLE if c not in cols]
    if need:
        ad = air_data(cols["alt_ft"], cols["tas_kt"])
        for c in need:
            cols[c] = ad[c]
            derived[c] = "from tas_kt and alt_ft (pressure altitude) through the ISA standard atmosphere"
    if "qdot_dps2" not in cols:
        derived["qdot_dps2"] = (
            "not written: the identification derives it from q_dps (quintic spline "
            "derivative, low-passed at 3 Hz with the coefficients)"
        )
    order = [c for c in LOG_COLUMNS if c in cols]
    log = pd.DataFrame({"t_s": t_s, **{c: cols[c] for c in order if c != "t_s"}})
    head = log[log.t_s < 1.0]
    gear0 = float(log.gear_norm.iloc[0])
    alt = round(float(head.alt_ft.mean()) / ALT_GRID_FT) * ALT_GRID_FT
    mach = round(float(head.mach.mean()) / MACH_GRID) * MACH_GRID
    meta = {
        "point": name,
        "maneuver": _maneuver(log.gear_norm.to_numpy()),
        "status_point": {
            "id": name,
            "alt_ft": alt,
            "mach": round(mach, 4),
            "flap_deg": float(head.flap_deg.mean()),
            "gear": "down" if gear0 >= 0.5 else "up",
        },
        "inertia_slugft2": {k: air.get(k, 0.0) for k in ("ixx", "iyy", "izz", "ixz")},
        "geometry": {
            "S_ft2": air["S"],
            "cbar_ft": air["cbar"],
            "b_ft": air.get("b", 0.0),
            "thrust_z_arm_ft": air.get("thrust_z_arm", 0.0),
            **{f"{k}_in": air[k] for k in ("cg_x", "cg_z", "aerorp_x", "aerorp_z") if k in air},
        },
        "dt_s": float(np.median(np.diff(t_s))) if step is None else step,
        "sensor_positions_ft": {c: list(r) for c, r in positions},
        "derived_channels": derived,
        **(extra or {}),
        **({"latitude_deg": air["latitude"]} if "latitude" in air else {}),
    }
    if "gravity" in air or "latitude" in air:
        meta["gravity_fps2"] = (
            air["gravity"] if "gravity" in air else normal_gravity_fps2(air["latitude"], float(log.alt_ft.mean()))
        )
    return log, meta


def convert(path: str | Path, m: ImportMap) -> list[Imported]:
    """One source file in the log schema, with its metadata and report entry: one log, or one per record
    where the map cuts the file (``[records] split_s``), each named ``<file stem>_<k>``."""
    path = Path(path)
    df = read_source(path, m)
    t = _time(path, df, m)
    cols, report = {}, {"mapped": {}, "constants": {}, "derived": {}, "source": str(path)}
    for col, src, k in m.channels:  # "A+B": the sum of source columns (two engines' thrust)
        cols[col] = sum(_numeric(path, df, s, f"channels.{col}") for s in src.split("+")) * k
        report["mapped"][col] = f"{src} [{m.units.get(col) or '-'}]"
    step = float(np.median(np.diff(t)))
    check_rate(path, step, m)
    t0 = t - t[0]
    for col, v in m.constants:
        cols[col] = np.full(len(t0), v)
        report["constants"][col] = v
    air = dict(m.aircraft)
    if "mass_slug" not in cols:
        report["constants"]["mass_slug"] = air["mass"]
    stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", path.stem)
    parts = windows(path, t0, m.records) if m.records else [np.arange(len(t0))]
    out = []
    for k, rows in enumerate(parts, 1):
        name = f"{stem}_{k}" if m.records else stem
        t_rec, rec = t0[rows], {c: x[rows] for c, x in cols.items()}
        jitter = float(np.max(np.abs(np.diff(t_rec) - step)) / step)
        resampled = None
        if jitter > JITTER:
            grid = np.arange(t_rec[0], t_rec[-1] + 0.5 * step, step)
            rec = {c: np.interp(grid, t_rec, x) for c, x in rec.items()}
            resampled = f"onto a uniform {1 / step:.4g} Hz grid (interval jitter {jitter:.1%})"
            t_rec = grid
        where = {
            "source": path.name,
            "map": Path(m.path).name,
            "map_sha256": m.sha256,
            "constants": sorted(c for c, _ in m.constants),
            **({"record": k, "from_s": float(t_rec[0])} if m.records else {}),
        }
        log, meta = schema_log(
            name,
            t_rec - t_rec[0],
            rec,
            air,
            m.positions,
            step,
            {"imported": where, **({"instrument_accuracy": m.accuracy} if m.accuracy else {})},
        )
        rep = {
            **report,
            "derived": meta["derived_channels"],
            "log": f"{name}.parquet",
            **({"resampled": resampled} if resampled else {}),
            "rows": len(t_rec),
            "rate_hz": round(1.0 / step, 4),
            "duration_s": round(float(log.t_s.iloc[-1]), 3),
            "maneuver": meta["maneuver"],
            "status_point": meta["status_point"],
        }
        if m.records:
            rep["record"] = f"{k} of {len(parts)}, from {where['from_s']:g} s of the file"
        if "gravity_fps2" in meta:
            rep["gravity_fps2"] = meta["gravity_fps2"]
        out.append(Imported(str(path), name, log, meta, rep))
    return out


def import_files(files: list[str | Path], map_path: str | Path, out: str | Path) -> dict:
    """Convert every file, check them all, then write the logs and the report into ``out``.

    Nothing is written if any file or the map is bad (each log is checked as identify and diagnose
    will read it first), no existing log is overwritten, and a write that fails half way takes back
    what it wrote: the mended command then runs as if the first had not.
    """
    from campaign.orchestration.store import atomic_write, write_json, write_log
    from identify.logs import LogError, read_parquet

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UserError(f"{out}: is a file, not a folder (--out names the folder for the logs)")
    m = load_map(map_path)
    if not files:
        raise UserError("campaign import: no input files")
    done = [x for f in files for x in convert(f, m)]
    names = [d.name for d in done]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup:
        raise UserError(f"{done[names.index(dup)].source}: two input files make the log {dup}.parquet")
    for d in done:
        check_log(Path(d.source), m, d.log, d.meta)
    clash = [out / f"{n}.parquet" for n in names if (out / f"{n}.parquet").exists()]
    if clash or (out / "manifest.json").exists():
        raise UserError(
            f"{clash[0] if clash else out / 'manifest.json'}: exists; will not overwrite (choose another --out)"
        )
    for d in done:
        d.report["map"] = m.path
    report = {"maps": {m.path: m.sha256}, "logs": [d.report for d in done]}
    previous = out / "import.json"
    whole = json.loads(previous.read_text()) if previous.exists() else {"maps": {}, "logs": []}
    whole = {"tool": tool(), "maps": {**whole["maps"], **report["maps"]}, "logs": whole["logs"] + report["logs"]}
    created = not out.exists()
    kept = {f: (out / f).read_bytes() for f in ("import.json", "import.txt") if (out / f).exists()}
    written: list[Path] = []
    try:
        out.mkdir(parents=True, exist_ok=True)
        for d in done:
            written.append(out / f"{d.name}.parquet")
            write_log(written[-1], d.log, d.meta)
            read_parquet(written[-1])  # what identify and diagnose will read
        write_json(out / "import.json", whole)  # several imports into one folder: one report
        text = report_text(whole)
        atomic_write(out / "import.txt", lambda tmp: Path(tmp).write_text(text))
    except BaseException as exc:
        _take_back(out, created, written, kept)
        if isinstance(exc, LogError):
            raise UserError(str(exc)) from None
        raise
    return report


def _take_back(out: Path, created: bool, written: list[Path], kept: dict[str, bytes]) -> None:
    """Undo a half-done import: the logs it wrote, its reports, the folder if it made it."""
    import shutil

    if created:
        shutil.rmtree(out, ignore_errors=True)
        return
    for f in written:
        f.unlink(missing_ok=True)
    for name in ("import.json", "import.txt"):
        if name in kept:
            (out / name).write_bytes(kept[name])
        else:
            (out / name).unlink(missing_ok=True)


def report_text(report: dict) -> str:
    lines = [f"Import with {', '.join(report['maps'])}", ""]
    for r in report["logs"]:
        lines.append(
            f"{r['source']} -> {r['log']}: {r['rows']} rows at {r['rate_hz']:g} Hz, {r['duration_s']:g} s, "
            f"{r['maneuver']}, condition {r['status_point']['alt_ft']:g} ft / M{r['status_point']['mach']:g} / "
            f"flap {r['status_point']['flap_deg']:g} / gear {r['status_point']['gear']}"
        )
        lines.append("  mapped: " + ", ".join(f"{k} <- {v}" for k, v in r["mapped"].items()))
        if r["constants"]:
            lines.append("  constants: " + ", ".join(f"{k} = {v:g}" for k, v in r["constants"].items()))
        for k, v in r["derived"].items():
            lines.append(f"  derived: {k}: {v}")
        if "resampled" in r:
            lines.append(f"  resampled {r['resampled']}")
        if "record" in r:
            lines.append(f"  record {r['record']}")
        if "gravity_fps2" in r:
            lines.append(f"  local gravity {r['gravity_fps2']:.5g} ft/s^2 ({r['gravity_fps2'] * 0.3048:.5g} m/s^2)")
    return "\n".join(lines) + "\n"
