"""Measured files and maps from outside, read as untrusted: bounded lines and fields, physical
aircraft data, and each log checked as identify and diagnose will read it before anything is written.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from campaign.errors import UserError

#: The longest line a text file may have [bytes], and the most fields a line may hold: a flight-test
#: export of a few thousand channels is well inside both; a file past them is not a table.
MAX_LINE_BYTES = 1 << 20
MAX_FIELDS = 20_000
#: Sampling rates a measured log may have [Hz]: outside, the map's time unit is wrong.
RATE_RANGE_HZ = (1.0, 10_000.0)
#: Aircraft data of a map, in the units of :data:`campaign.importing.importer.AIRCRAFT_UNITS`: (lowest, highest),
#: the lowest excluded where it is 0 (a mass, an area, a length).
AIRCRAFT_BOUNDS = {
    "mass": (0.0, 1e5),
    "ixx": (0.0, 1e9),
    "iyy": (0.0, 1e9),
    "izz": (0.0, 1e9),
    "ixz": (-1e9, 1e9),
    "S": (0.0, 1e5),
    "cbar": (0.0, 1000.0),
    "b": (0.0, 1000.0),
    "thrust_z_arm": (-100.0, 100.0),
    "cg_x": (-12000.0, 12000.0),
    "cg_z": (-12000.0, 12000.0),
    "aerorp_x": (-12000.0, 12000.0),
    "aerorp_z": (-12000.0, 12000.0),
    "latitude": (-90.0, 90.0),
}
#: A documented sensor position's largest distance from the CG along an axis [ft].
MAX_POSITION_FT = 500.0
CHUNK = 1 << 20


def shown(value, n: int = 40) -> str:
    """``repr`` of a value from a file, cut to ``n`` characters (a cell can be megabytes)."""
    text = repr(value)
    return text if len(text) <= n else text[:n] + "..."


def bounded(path: str, where: str, key: str, value: float, unit: str) -> float:
    """An aircraft value of a map within :data:`AIRCRAFT_BOUNDS`, or a one-line error."""
    lo, hi = AIRCRAFT_BOUNDS[key]
    if not math.isfinite(value):
        raise UserError(f"{path}: {where}: not a finite number")
    if (value <= lo if lo == 0.0 else value < lo) or value > hi:
        rng = f"more than 0 and at most {hi:g}" if lo == 0.0 else f"within {lo:g}..{hi:g}"
        raise UserError(f"{path}: {where}: {value:g} {unit} is not physical (must be {rng} {unit})")
    return value


def check_text(path: Path, fmt: str) -> None:
    """Refuse a text file with a line longer than :data:`MAX_LINE_BYTES` or more than
    :data:`MAX_FIELDS` fields on a line, before a parser reads it."""
    sep = re.compile(rb"," if fmt == "csv" else rb"\s+")
    row, carry = 0, b""
    with open(path, "rb") as f:
        while True:
            chunk = f.read(CHUNK)
            lines = (carry + chunk).split(b"\n")
            carry = lines.pop() if chunk else b""
            for line in lines:
                row += 1
                _line(path, row, line, sep, fmt)
            if len(carry) > MAX_LINE_BYTES:
                raise UserError(
                    f"{path}: row {row + 1}: a line longer than {MAX_LINE_BYTES:,} bytes (not a table of samples)"
                )
            if not chunk:
                return


def _line(path: Path, row: int, line: bytes, sep, fmt: str) -> None:
    if len(line) > MAX_LINE_BYTES:
        raise UserError(f"{path}: row {row}: a line longer than {MAX_LINE_BYTES:,} bytes (not a table of samples)")
    if len(line) > 2 * MAX_FIELDS:  # shorter lines cannot hold more fields
        n = len(sep.findall(line.strip())) + 1
        if n > MAX_FIELDS:
            raise UserError(
                f"{path}: row {row}: {n:,} fields, more than {MAX_FIELDS:,} (not a table of samples as {fmt})"
            )


def check_columns(path: Path, n: int) -> None:
    """Refuse a table (Parquet, .mat) of more than :data:`MAX_FIELDS` columns."""
    if n > MAX_FIELDS:
        raise UserError(f"{path}: {n:,} columns, more than {MAX_FIELDS:,}")


def check_rate(path: Path, step_s: float, m) -> None:
    """Refuse samples whose spacing says the map's time unit is wrong."""
    lo, hi = RATE_RANGE_HZ
    rate = 1.0 / step_s
    if not lo <= rate <= hi:
        raise UserError(
            f"{path}: samples {step_s:g} s apart ({rate:g} Hz), outside {lo:g}..{hi:g} Hz: is the time in "
            f"{m.units.get('t_s') or 's'}? (time.unit of {Path(m.path).name})"
        )


def where_in_map(m, column: str) -> str:
    """The map's key that gives a log column: ``channels.<col> ("SRC unit")``, ``constants.<col>``,
    ``aircraft.mass`` or ``derived``."""
    for col, src, _ in m.channels:
        if col == column:
            unit = m.units.get(col, "")
            return f'channels.{col} ("{src}{" " + unit if unit else ""}")'
    if column in dict(m.constants):
        return f"constants.{column}"
    if column == "mass_slug":
        return "aircraft.mass"
    return f"{column} (derived from tas_kt and alt_ft)"


def check_log(source: Path, m, log, meta) -> None:
    """A converted log checked as identify and diagnose will read it
    (:func:`identify.logs.checked`); the error names the source file and the map's key."""
    from identify.logs import LogError, checked

    try:
        checked(str(source), log, meta)
    except LogError as exc:
        text = str(exc)[len(str(source)) + 2 :]
        hit = re.match(r"column '([^']+)', (.*)", text)
        if hit:
            raise UserError(
                f"{source}: {where_in_map(m, hit.group(1))} of {Path(m.path).name}: {hit.group(2)}"
            ) from None
        raise UserError(f"{source}: {text}") from None
