"""Measured logs: read from files, made from a pandas DataFrame, written as Parquet."""

from __future__ import annotations

import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import pandas as pd

from campaign.errors import UserError
from identify.logs import REQUIRED_COLUMNS, Log, LogError

#: The channels a DataFrame must hold (the rest of the log schema is optional): eq. (1) and the
#: states need them. ``mach``, ``qbar_psf`` and ``ias_kt`` are derived from ``tas_kt`` and
#: ``alt_ft`` through the standard atmosphere when absent; ``mass_slug`` may be given as a number.
FRAME_COLUMNS = tuple(c for c in REQUIRED_COLUMNS if c not in ("mach", "qbar_psf", "mass_slug"))


def read_logs(path: str | Path) -> list[Log]:
    """Read measured logs.

    Parameters
    ----------
    path : str or Path
        A campaign folder (``manifest.json`` and its Parquet logs, as ``fly`` or ``campaign import``
        write them), a folder of Parquet logs or of CSV logs with their JSON sidecars, or one
        ``.parquet`` or ``.csv`` file.

    Returns
    -------
    list of Log
        One per manoeuvre (a campaign's in its manifest's order): ``log.data`` is a DataFrame in
        the log schema (units in the column names), ``log.meta`` its metadata.

    Raises
    ------
    UserError
        One line naming the file, and the field, column or row that is wrong.
    """
    from campaign.diagnosis.run import load_data

    return load_data(Path(path))


def _number(key: str, value, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise UserError(f"log_from_frame: {key}: expected a number, found {value!r}")
    x = float(value)
    if not np.isfinite(x) or (positive and x <= 0):
        raise UserError(f"log_from_frame: {key}: {x:g} must be {'positive and ' if positive else ''}finite")
    return x


def _accuracy_value(path: str, where: str, value, unit: str) -> float:
    """An accuracy number given from Python: in the channel's unit (``scale`` [-], ``delay`` [s])."""
    return _number(where, value)


def log_from_frame(  # noqa: C901, PLR0913
    frame: pd.DataFrame,
    *,
    S_ft2: float,
    cbar_ft: float,
    iyy_slugft2: float,
    mass_slug: float | None = None,
    ixx_slugft2: float = 0.0,
    izz_slugft2: float = 0.0,
    ixz_slugft2: float = 0.0,
    b_ft: float = 0.0,
    thrust_z_arm_ft: float = 0.0,
    cg_x_in: float | None = None,
    cg_z_in: float | None = None,
    aerorp_x_in: float | None = None,
    aerorp_z_in: float | None = None,
    latitude_deg: float | None = None,
    gravity_fps2: float | None = None,
    sensor_positions_ft: dict[str, Iterable[float]] | None = None,
    instrument_accuracy: dict[str, dict[str, float]] | None = None,
    name: str | None = None,
    maneuver: str | None = None,
) -> Log:
    """A measured log from a pandas DataFrame in the log schema, checked as a file's would be.

    Parameters
    ----------
    frame : DataFrame
        One manoeuvre, one row per sample, columns named ``<quantity>_<unit>`` as the log schema
        names them: at least :data:`FRAME_COLUMNS` (``t_s`` [s], ``alt_ft`` [ft], ``tas_kt`` [kt],
        ``alpha_deg``, ``theta_deg`` [deg], ``p_dps``, ``q_dps``, ``r_dps`` [deg/s], ``ax_fps2``,
        ``az_fps2`` [ft/s^2], ``thrust_lbf`` [lbf], ``elevator_deg``, ``stabilizer_deg``,
        ``flap_deg`` [deg], ``gear_norm`` [-]). Columns outside the schema are dropped.
    S_ft2 : float
        Reference wing area [ft^2]. Required.
    cbar_ft : float
        Reference chord [ft]. Required.
    iyy_slugft2 : float
        Pitch moment of inertia [slug ft^2]. Required.
    mass_slug : float, optional
        Mass [slug], if the frame has no ``mass_slug`` column (one of the two is required).
    ixx_slugft2, izz_slugft2, ixz_slugft2 : float
        The other moments and product of inertia [slug ft^2]; 0 by default (they matter when
        the roll and yaw rates do).
    b_ft : float
        Wing span [ft]; 0 by default.
    thrust_z_arm_ft : float
        Height of the thrust line above the CG [ft] (negative below it: the thrust's pitching-moment
        arm, moment -thrust_z_arm_ft * thrust_lbf); 0 by default.
    cg_x_in, cg_z_in, aerorp_x_in, aerorp_z_in : float, optional
        CG and aerodynamic reference point, structural frame [in]; without them the moments are
        taken about the CG.
    latitude_deg : float, optional
        Latitude [deg]: the data compatibility's Earth rate, and the local gravity (WGS84 normal gravity
        at the log's mean altitude) when ``gravity_fps2`` is not given.
    gravity_fps2 : float, optional
        Local gravity [ft/s^2], 9.7 to 9.9 m/s^2; without it and without a latitude the standard
        32.174 ft/s^2.
    sensor_positions_ft : dict, optional
        Channel -> documented position ``[x, y, z]`` from the CG, body axes [ft] (``alpha_deg``,
        ``beta_deg``, ``ax_fps2``, ``ay_fps2``, ``az_fps2``).
    instrument_accuracy : dict, optional
        Channel -> the instrumentation's specified accuracy: ``noise`` (1 sigma) and ``bias`` (largest)
        in the channel's unit, ``scale`` (largest scale-factor error) [-], ``delay`` (largest) [s], as an
        import map's ``[accuracy]`` gives it. The diagnosis draws its noise floor and the instrument
        errors' reach from it; without it, measured data get a stated conservative default.
    name : str, optional
        The log's name: its status point's id, and the stem of its file (``log.path`` is
        ``<name>.parquet``, the file :func:`write_logs` writes). By default
        ``h<altitude>_m<Mach>_f<flap>_g<up|dn>__<manoeuvre>`` from the first second, the status
        point's id being the part before ``__``, as a campaign names its logs.
    maneuver : str, optional
        ``"gear_extension"``, ``"gear_retraction"``, ``"level_turn"`` or an excitation's name
        (``"doublet"``, ``"multisine"``); by default a gear extension or retraction if the gear
        moves from one end to the other, else ``"excitation"``.

    Returns
    -------
    Log
        ``log.data`` the schema's columns (Mach, dynamic pressure and calibrated airspeed derived
        if absent), ``log.meta`` the metadata a file would hold. Its status point is the first
        second's mean: altitude to 500 ft, Mach to 0.01, flap as flown, gear down if
        ``gear_norm`` starts at 0.5 or more.

    Raises
    ------
    UserError
        One line naming the key, column or row: a missing column or key, a value that is not a
        finite number or lies outside the plausible range of its unit.
    """
    from campaign.importing.declared import check_gravity, parse_accuracy
    from campaign.importing.importer import schema_log, schema_unit
    from campaign.simulation.catalog import LOG_COLUMNS
    from campaign.simulation.instruments import POSITIONED
    from identify.logs import checked

    if not isinstance(frame, pd.DataFrame):
        raise UserError(f"log_from_frame: frame: expected a pandas DataFrame, found {type(frame).__name__}")
    missing = [c for c in FRAME_COLUMNS if c not in frame.columns]
    if missing:
        raise UserError(f"log_from_frame: column {missing[0]!r} missing (needed: {', '.join(FRAME_COLUMNS)})")
    if "mass_slug" not in frame.columns and mass_slug is None:
        raise UserError("log_from_frame: mass_slug: give it as a column or as a number")
    air = {
        "S": _number("S_ft2", S_ft2, True),
        "cbar": _number("cbar_ft", cbar_ft, True),
        "iyy": _number("iyy_slugft2", iyy_slugft2, True),
        "ixx": _number("ixx_slugft2", ixx_slugft2),
        "izz": _number("izz_slugft2", izz_slugft2),
        "ixz": _number("ixz_slugft2", ixz_slugft2),
        "b": _number("b_ft", b_ft),
        "thrust_z_arm": _number("thrust_z_arm_ft", thrust_z_arm_ft),
    }
    if mass_slug is not None:
        air["mass"] = _number("mass_slug", mass_slug, True)
    for key, value in (
        ("cg_x", cg_x_in),
        ("cg_z", cg_z_in),
        ("aerorp_x", aerorp_x_in),
        ("aerorp_z", aerorp_z_in),
        ("latitude", latitude_deg),
    ):
        if value is not None:
            air[key] = _number(f"{key}_{'deg' if key == 'latitude' else 'in'}", value)
    positions = []
    for ch, xyz in (sensor_positions_ft or {}).items():
        if ch not in POSITIONED:
            raise UserError(
                f"log_from_frame: sensor_positions_ft.{ch}: a position applies only to {', '.join(POSITIONED)}"
            )
        xyz = list(xyz)
        if len(xyz) != 3:
            raise UserError(f"log_from_frame: sensor_positions_ft.{ch}: expected [x, y, z] [ft]")
        positions.append((ch, tuple(_number(f"sensor_positions_ft.{ch}", v) for v in xyz)))
    cols = {}
    for c in LOG_COLUMNS:
        if c in frame.columns and c != "t_s":
            v = pd.to_numeric(frame[c], errors="coerce").to_numpy(dtype=float)
            bad = np.flatnonzero(~np.isfinite(v))
            if bad.size:
                raise UserError(
                    f"log_from_frame: column {c!r}, row {bad[0] + 1}: not a finite number ({frame[c].iloc[bad[0]]!r})"
                )
            cols[c] = v
    t = pd.to_numeric(frame["t_s"], errors="coerce").to_numpy(dtype=float)
    if len(t) < 10:
        raise UserError(f"log_from_frame: only {len(t)} rows")
    dt = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(dt <= 0):
        i = int(np.flatnonzero(~np.isfinite(t[1:]) | ~(dt > 0))[0]) + 2 if len(dt) else 1
        raise UserError(f"log_from_frame: column 't_s', row {i}: time must be finite and increase")
    if maneuver is not None and (not isinstance(maneuver, str) or not maneuver):
        raise UserError(f"log_from_frame: maneuver: expected a manoeuvre's name, found {maneuver!r}")
    if name is not None and (not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_.-]+", name)):
        raise UserError(f"log_from_frame: name: {name!r}: letters, digits, '_', '.' and '-' only")
    if gravity_fps2 is not None:
        air["gravity"] = check_gravity("log_from_frame", "gravity_fps2", _number("gravity_fps2", gravity_fps2))
    accuracy = parse_accuracy("log_from_frame", instrument_accuracy or {}, _accuracy_value, schema_unit)
    log, meta = schema_log(
        name or "log",
        t - t[0],
        cols,
        air,
        positions,
        extra={"imported": {"source": "a pandas DataFrame"}, **({"instrument_accuracy": accuracy} if accuracy else {})},
    )
    if maneuver is not None:
        meta["maneuver"] = maneuver
    if name is None:
        sp = meta["status_point"]
        point = f"h{int(sp['alt_ft']):05d}_m{sp['mach']:.2f}_f{sp['flap_deg']:02.0f}_g{'dn' if sp['gear'] == 'down' else 'up'}"
        meta.update(point=point, status_point={**sp, "id": point})
        name = f"{point}__{meta['maneuver']}"
    try:
        return checked(f"{name}.parquet", log, meta)
    except LogError as exc:
        raise UserError(f"log_from_frame: {exc}") from None


def write_logs(logs: Iterable[Log], folder: str | Path) -> list[Path]:
    """Write logs as Parquet files (``<name>.parquet``, metadata in the file) into ``folder``, which
    :func:`read_logs`, ``campaign identify`` and ``campaign diagnose`` then read like a campaign.

    Parameters
    ----------
    logs : iterable of Log
    folder : str or Path
        Created if needed; a log of the same name already there is not overwritten.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    UserError
        If a file of that name exists, or two logs have one name.
    """
    from campaign.orchestration.store import write_log

    folder = Path(folder)
    logs = list(logs)
    names = [Path(lg.path).name for lg in logs]
    twice = next((n for n in names if names.count(n) > 1), None)
    if twice:
        raise UserError(f"{folder}: two logs are named {twice}")
    paths = [folder / (n if n.endswith(".parquet") else f"{n}.parquet") for n in names]
    there = next((p for p in paths if p.exists()), None)
    if there:
        raise UserError(f"{there}: exists; will not overwrite")
    folder.mkdir(parents=True, exist_ok=True)
    for lg, p in zip(logs, paths):
        write_log(p, lg.data, lg.meta)
    return paths
