"""The results store: Parquet logs written atomically, and the manifest."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from campaign.errors import UserError
from identify.logs import read_table

META_KEY = b"gearid"
MANIFEST = "manifest.json"
#: The lock a command holds on the campaign folder it writes (the kernel drops it when the process dies).
LOCK = ".campaign.lock"


def log_name(point_id: str, maneuver: str) -> str:
    """File name of one flown manoeuvre, e.g. ``h02000_m0.30_f05_gdn__doublet.parquet``."""
    return f"{point_id}__{maneuver}.parquet"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write) -> None:
    """Write ``path`` through ``write(tmp)`` into a temporary beside it, then rename: readers see the
    old file or the new one, never a part (a killed writer leaves a ``.*.tmp`` that
    :func:`clean_temporaries` removes)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file ordinary permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_log(path: Path, log: pd.DataFrame, meta: dict) -> None:
    """Write one log as Parquet (zstd) with ``meta`` in the schema metadata, atomically.

    The float columns are written byte-stream-split without a dictionary (a sensor's samples
    hardly repeat): a third smaller and three times faster to write than the defaults. The
    index is not written (logs are read back with a range index).
    """
    table = pa.table(
        {str(c): s.to_numpy() if s.dtype.kind == "f" else pa.array(s) for c, s in log.items()},
        metadata={META_KEY: json.dumps(meta, sort_keys=True).encode()},
    )
    floats = {c for c, t in zip(table.column_names, table.schema.types) if pa.types.is_floating(t)}
    atomic_write(
        Path(path),
        lambda tmp: pq.write_table(
            table,
            tmp,
            compression="zstd",
            use_dictionary=False,
            column_encoding={c: "BYTE_STREAM_SPLIT" for c in floats},
        ),
    )


def read_log(path: Path) -> tuple[pd.DataFrame, dict]:
    """Read a log and its metadata."""
    table = read_table(path)
    meta = json.loads(table.schema.metadata[META_KEY])
    return table.to_pandas(), meta


def read_meta(path: Path) -> dict | None:
    """A log's metadata alone (its footer), or None if the file is missing or not a complete log."""
    try:
        return json.loads(pq.read_schema(path).metadata[META_KEY])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_json(path: Path, obj: dict) -> None:
    """Write JSON atomically."""
    text = json.dumps(obj, indent=2, sort_keys=False) + "\n"
    atomic_write(Path(path), lambda tmp: Path(tmp).write_text(text))


def read_manifest(folder: Path) -> dict | None:
    """The manifest of a campaign folder, or None if there is none."""
    p = Path(folder) / MANIFEST
    if not p.exists():
        return None
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise UserError(f"{p}: not valid JSON ({exc.msg} at line {exc.lineno})") from None


def clean_temporaries(folder: Path) -> None:
    """Remove temporaries left by a killed run in ``folder`` and the folders below it."""
    for tmp in Path(folder).rglob(".*.tmp"):
        tmp.unlink(missing_ok=True)


def readable_log(path: Path) -> bool:
    """True if ``path`` is a complete Parquet file (its footer reads)."""
    try:
        pq.read_metadata(path)
        return True
    except (OSError, ValueError):
        return False


@contextmanager
def holding(folder: Path, command: str):
    """Hold ``folder`` for one command: a second command on it is refused with a UserError.

    The lock is an ``flock`` on :data:`LOCK`: the kernel releases it when the
    holder exits, however it exits, so a lock left by a killed run never blocks
    the resume. The file stays, empty (removing it would race with the next holder;
    writing into it would change a folder that a refused command must leave alone),
    except after a UserError: bad input leaves neither the lock file nor the folder
    if this command made them.
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder}: is a file, not a folder")
    created, fresh = not folder.exists(), not (folder / LOCK).exists()
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT, 0o666 & ~_umask())
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise UserError(
            f"{folder}: another campaign command (run, fly, identify, replay or plots) is writing this "
            f"folder; wait for it to finish, or choose another folder"
        ) from None
    try:
        yield
    except UserError:  # bad input leaves no lock file, nor a folder, that were not there
        if fresh:
            (folder / LOCK).unlink(missing_ok=True)
        if created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    finally:
        os.close(fd)


def failed_record(point, reason: str, transient: bool = False) -> dict:
    """The manifest record of a status point that did not fly; a ``transient`` failure (not the aircraft's
    doing, e.g. a worker's death) is flown again on resume."""
    rec = {"id": point.id, "status": "failed", "reason": reason, "files": [], "seeds": {}, "excursions": {}}
    if transient:
        rec["transient"] = True
    return rec
