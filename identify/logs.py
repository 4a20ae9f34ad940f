"""Reading measured logs: a campaign folder (Parquet + manifest) or CSV files.

This module knows the log schema only; it never imports the flying code.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

REQUIRED_COLUMNS: tuple[str, ...] = (
    "t_s",
    "alt_ft",
    "tas_kt",
    "mach",
    "alpha_deg",
    "theta_deg",
    "p_dps",
    "q_dps",
    "r_dps",
    "ax_fps2",
    "az_fps2",
    "qbar_psf",
    "thrust_lbf",
    "elevator_deg",
    "stabilizer_deg",
    "flap_deg",
    "gear_norm",
    "mass_slug",
)
#: Channels a log may lack; what takes their place.
DERIVED = {
    "qdot_dps2": "derivative of the quintic spline through q_dps, half a JSBSim frame ahead, "
    "low-passed at 3 Hz with the coefficients"
}
TRANSITIONS = ("gear_extension", "gear_retraction")
#: Manoeuvres flown for the data compatibility (air-data calibration), not for eq. (3) fits.
CALIBRATION = ("level_turn",)
REQUIRED_META = ("point", "maneuver", "status_point", "inertia_slugft2", "geometry")
#: Physically plausible ranges; a value outside is a unit or sign mistake.
PLAUSIBLE = {
    "alpha_deg": (-30.0, 60.0),
    "mach": (0.0, 3.0),
    "tas_kt": (0.0, 2000.0),
    "qbar_psf": (0.0, 3000.0),
    "gear_norm": (-0.01, 1.01),
    "flap_deg": (-1.0, 60.0),
    "mass_slug": (1.0, 1e5),
    "theta_deg": (-90.0, 90.0),
    "elevator_deg": (-45.0, 45.0),
    "stabilizer_deg": (-30.0, 30.0),
}


class LogError(ValueError):
    """A bad measured log; the message names the file, and the column and row."""


class _Described:
    """What a log's metadata says of it (``self.meta``)."""

    meta: dict

    @property
    def point(self) -> str:
        return self.meta["point"]

    @property
    def maneuver(self) -> str:
        return self.meta["maneuver"]

    @property
    def condition(self) -> tuple[float, float, int]:
        """(altitude [ft], Mach, flap [deg]) of the status point."""
        sp = self.meta["status_point"]
        return (float(sp["alt_ft"]), float(sp["mach"]), float(sp["flap_deg"]))

    @property
    def gear_down(self) -> bool:
        return self.meta["status_point"]["gear"] == "down"

    @property
    def transition(self) -> bool:
        """A gear extension or retraction."""
        return self.maneuver in TRANSITIONS

    @property
    def excitation(self) -> bool:
        """An input for eq. (3) (a 2-3-1-1, a multisine): neither a gear transition nor a
        calibration manoeuvre (a level turn)."""
        return self.maneuver not in TRANSITIONS + CALIBRATION


@dataclass
class Log(_Described):
    """One measured manoeuvre.

    Attributes
    ----------
    path : str
    data : pandas.DataFrame
        Columns of the log schema, units in the names.
    meta : dict
        Status point, manoeuvre, inertia, geometry...
    """

    path: str
    data: pd.DataFrame
    meta: dict

    @property
    def columns(self) -> pd.Index:
        return self.data.columns

    def read(self) -> "Log":
        """Itself (a :class:`LogHead` reads its file)."""
        return self


#: The metadata a :class:`LogHead` keeps (what is needed of a log before it is read); the rest
#: comes with the log.
HEAD_META = ("point", "maneuver", "status_point", "sensor_positions_ft", "geometry", "imported")
#: Of those, the parts a campaign's logs share: one object for all heads.
SHARED_META = ("sensor_positions_ft", "geometry")


@dataclass(frozen=True)
class LogHead(_Described):
    """A log before its samples are read: its path, metadata (:data:`HEAD_META`) and column names.
    Work on thousands of logs holds these and reads each log (:meth:`read`) where it is used, one
    at a time."""

    path: str
    meta: dict
    columns: tuple[str, ...]

    def read(self) -> Log:
        """The whole log, checked (:func:`read_parquet`, :func:`read_csv`)."""
        return read_csv(self.path) if self.path.endswith(".csv") else read_parquet(self.path)


def _validate(path: str, df: pd.DataFrame, meta: dict) -> None:
    for key in REQUIRED_META:
        if key not in meta:
            raise LogError(f"{path}: metadata field {key!r} missing")
    for col in REQUIRED_COLUMNS:
        if col not in df.columns:
            raise LogError(f"{path}: column {col!r} missing")
        column = df[col]
        numeric = isinstance(column.dtype, np.dtype) and column.dtype.kind in "fiub"  # as written: no parsing
        values = (column if numeric else pd.to_numeric(column, errors="coerce")).to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raw = df[col].iloc[bad[0]]
            shown = "empty" if pd.isna(raw) else repr(str(raw))
            raise LogError(f"{path}: column {col!r}, row {bad[0] + 1}: not a finite number ({shown})")
        lo, hi = PLAUSIBLE.get(col, (-np.inf, np.inf))
        out = np.flatnonzero((values < lo) | (values > hi))
        if out.size:
            raise LogError(
                f"{path}: column {col!r}, row {out[0] + 1}: {values[out[0]]:g} is outside "
                f"{lo:g}..{hi:g} (units? the column's unit is in its name)"
            )
    if len(df) < 10:
        raise LogError(f"{path}: only {len(df)} rows")


def _derive(meta: dict, df: pd.DataFrame) -> dict:
    """Name in the metadata the channels the log lacks and the analysis derives."""
    derived = {c: how for c, how in DERIVED.items() if c not in df.columns}
    if derived:
        meta = {**meta, "derived_channels": {**meta.get("derived_channels", {}), **derived}}
    return meta


def checked(path: str, data: pd.DataFrame, meta: dict) -> Log:
    """A log made in memory, checked as a file's would be: metadata fields, schema columns, finite
    and plausible values (:data:`REQUIRED_META`, :data:`REQUIRED_COLUMNS`, :data:`PLAUSIBLE`).

    Parameters
    ----------
    path : str
        What names the log in messages and results (a file name, or a label).
    data : DataFrame
        Columns of the log schema, units in their names.
    meta : dict
        The metadata (:data:`REQUIRED_META` and what else the log's file would hold).

    Raises
    ------
    LogError
        One line naming the log, and the field, column and row.
    """
    _validate(path, data, meta)
    return Log(path, data.astype({c: float for c in REQUIRED_COLUMNS}), _derive(meta, data))


def read_table(path: str | Path):
    """One Parquet file as a ``pyarrow.Table`` (without ``pq.read_table``'s dataset discovery,
    which takes longer than the read of a log)."""
    with pq.ParquetFile(path) as f:
        return f.read()


def read_parquet(path: str | Path) -> Log:
    """Read one Parquet log written by a campaign."""
    try:
        table = read_table(path)
    except (OSError, ValueError) as exc:  # pyarrow.ArrowInvalid is a ValueError
        raise LogError(f"{path}: not a readable Parquet log ({str(exc).splitlines()[0][:120]})") from None
    meta = json.loads((table.schema.metadata or {}).get(b"gearid", b"{}"))
    df = table.to_pandas()
    _validate(str(path), df, meta)
    return Log(str(path), df, _derive(meta, df))


def read_csv(path: str | Path) -> Log:
    """Read a CSV log in the schema with its sidecar ``<name>.json`` metadata."""
    path = Path(path)
    side = path.with_suffix(".json")
    if not side.exists():
        raise LogError(f"{path}: metadata sidecar {side.name} missing")
    try:
        meta = json.loads(side.read_text())
    except json.JSONDecodeError as exc:
        raise LogError(f"{side}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    try:
        df = pd.read_csv(path)
    except (ValueError, UnicodeDecodeError) as exc:  # pandas' ParserError and EmptyDataError are ValueErrors
        raise LogError(f"{path}: not a readable CSV log ({str(exc).splitlines()[0][:120]})") from None
    _validate(str(path), df, meta)
    return Log(str(path), df.astype({c: float for c in REQUIRED_COLUMNS}), _derive(meta, df))


def read_head(path: str | Path) -> LogHead:
    """A log's metadata and column names, its metadata checked; a Parquet log's samples are not
    read (a CSV's are, and dropped)."""
    if str(path).endswith(".csv"):
        log = read_csv(path)
        return LogHead(log.path, _head_meta(log.meta), _shared(tuple(log.data.columns)))
    try:
        schema = pq.read_schema(path)
    except (OSError, ValueError) as exc:
        raise LogError(f"{path}: not a readable Parquet log ({str(exc).splitlines()[0][:120]})") from None
    meta = json.loads((schema.metadata or {}).get(b"gearid", b"{}"))
    for key in REQUIRED_META:
        if key not in meta:
            raise LogError(f"{path}: metadata field {key!r} missing")
    return LogHead(str(path), _head_meta(meta), _shared(tuple(schema.names)))


_SHARED: dict[str, object] = {}


def _head_meta(meta: dict) -> dict:
    """The :data:`HEAD_META` of a log's metadata, the :data:`SHARED_META` parts shared."""
    return {k: _shared(meta[k]) if k in SHARED_META else meta[k] for k in HEAD_META if k in meta}


def _shared(value):
    """One object for equal values (metadata parts, column lists) across the heads of a campaign:
    9,700 points' heads held 160 MB, mostly copies of the same metadata."""
    return _SHARED.setdefault(type(value).__name__ + json.dumps(value, sort_keys=True), value)


def read_campaign(folder: str | Path) -> list[Log]:
    """Every log of a campaign folder (manifest order), or of a folder of CSVs."""
    return [read_parquet(f) if f.suffix == ".parquet" else read_csv(f) for f in campaign_files(folder)]


def read_heads(folder: str | Path) -> list[LogHead]:
    """:func:`read_head` of every log of a campaign folder, in :func:`read_campaign`'s order."""
    return [read_head(f) for f in campaign_files(folder)]


def campaign_files(folder: str | Path) -> list[Path]:
    """The logs of a campaign folder (its manifest's points that flew, in order), or of a folder of
    Parquet and CSV files (Parquet first, each sorted by name)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise LogError(f"{folder}: not a folder")
    manifest = folder / "manifest.json"
    if manifest.exists():
        try:
            man = json.loads(manifest.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise LogError(f"{manifest}: not valid JSON ({getattr(exc, 'msg', exc)})") from None
        return [folder / f for p in man.get("points", []) if p["status"] == "ok" for f in p["files"]]
    csvs = sorted(folder.glob("*.csv"))
    parquets = sorted(folder.glob("*.parquet"))
    if not csvs and not parquets:
        raise LogError(f"{folder}: no manifest.json, Parquet or CSV logs")
    return parquets + csvs
