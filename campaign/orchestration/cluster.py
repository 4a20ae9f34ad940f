"""Fly status points on a Dask cluster (dask.distributed).

The workers may be other machines: the aircraft folder and the effect overlay
travel as data (:class:`infra.pool.Shipment`), each worker writes them once into its own
temporary folder and builds its own FGFDMExec there. The logs come back as
data and the client writes them, atomically, as a local run does; they are
bit-identical to a local run's (the folder path is in no log).
"""

from __future__ import annotations

import os
import socket
import struct
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator
from urllib.parse import urlsplit

from campaign.simulation.aircraft import AircraftSource, Effects
from campaign.simulation.engine import FlightConfig
from campaign.errors import UserError
from campaign.simulation.matrix import StatusPoint
from campaign.orchestration.store import failed_record
from infra.pool import Shipment, landed, ship


def pack(source: AircraftSource) -> Shipment:
    """The aircraft folder and overlay of ``source`` as data (the overlay as ``effects.xml`` beside
    the folder)."""
    fx = Path(source.effects.path).read_bytes() if source.effects.path else None
    return ship(Path(source.folder), (("effects.xml", fx),) if fx is not None else ())


def unpack(shipment: Shipment, config: FlightConfig) -> FlightConfig:
    """``config`` with its aircraft and overlay read from this machine's copy of ``shipment``."""
    return replace(config, aircraft=unpack_source(shipment, config.aircraft.effects))


def unpack_source(shipment: Shipment, effects: Effects) -> AircraftSource:
    """The aircraft of ``shipment`` (and its overlay, parsed as ``effects``) from this machine's
    copy, written once per worker machine (:func:`infra.pool.landed`)."""
    home = landed(shipment)
    fx = home / "effects.xml"
    return AircraftSource(str(home / shipment.name), Effects(str(fx) if fx.exists() else None, effects.functions))


def fly_shipped(point: StatusPoint, config: FlightConfig, shipment: Shipment, fly: Callable):
    """On a worker: fly one point with the shipped aircraft; ``fly(point, config)`` returns
    ``(record, logs)``."""
    return fly(point, unpack(shipment, config))


#: How long :func:`connect`'s probe waits to connect, and then for the service's greeting [s]: a Dask scheduler
#: speaks first over tcp, a message whose first 8 bytes give its length; a service whose first bytes read as a
#: length above :data:`GREETING_MAX_BYTES` (an SSH server's banner, 3.5e18) is not one (the client would try
#: to allocate that much and stop with a traceback).
GREETING_S = 0.5
GREETING_MAX_BYTES = 2**30


def greeting(host: str, port: int) -> bytes:
    """The first 8 bytes (or fewer) the service at ``host:port`` sends within :data:`GREETING_S` of a
    connection made within :data:`GREETING_S`; nothing where none is made (refused, unreachable, slow: the
    client then tries, retries and says why)."""
    first = b""
    try:
        with socket.create_connection((host, port), timeout=GREETING_S) as probe:
            end = time.monotonic() + GREETING_S
            while len(first) < 8 and (left := end - time.monotonic()) > 0:
                probe.settimeout(left)
                more = probe.recv(8 - len(first))
                if not more:
                    break
                first += more
    except OSError:
        pass
    return first


def connect(address: str, timeout_s: float = 10.0):
    """A client of the scheduler at ``address`` (``tcp://HOST:PORT``); a one-line :class:`UserError` if none
    answers there within ``timeout_s`` [s], or at once where another service greets on a tcp address
    (:func:`greeting`)."""
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - distributed is a dependency
        raise UserError("--cluster: dask.distributed is not installed (pip install distributed)") from None
    parts = urlsplit(address)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("tcp", "tls") or not parts.hostname or port is None:
        raise UserError(f"--cluster {address}: expected a scheduler address tcp://HOST:PORT")
    first = greeting(parts.hostname, port) if parts.scheme == "tcp" else b""  # a TLS server waits for the client
    if len(first) == 8 and struct.unpack("Q", first)[0] > GREETING_MAX_BYTES:
        said = first.decode("ascii", "replace")
        raise UserError(f"--cluster {address}: the service there is not a Dask scheduler (it greets with {said!r})")
    try:
        return Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError, MemoryError) as exc:
        raise UserError(
            f"--cluster {address}: no Dask scheduler answers ({type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else 'no reply'})"
        ) from None


def fly_on_cluster(
    client, points: list[StatusPoint], config: FlightConfig, fly: Callable
) -> Iterator[tuple[dict, list]]:
    """Fly ``points`` on the cluster of ``client`` (:func:`connect`; closed at the end), yielding
    ``(record, logs)`` as each finishes.

    A point whose worker dies (abort, segfault, out of memory) more often than the
    scheduler allows (``distributed.scheduler.allowed-failures``) is flown again at
    the end, alone on the cluster (it may only have shared the worker with the point
    that killed it); if its worker dies then, it comes back failed with the reason.
    The others are unaffected.
    """
    from distributed import as_completed

    try:
        ship = pack(config.aircraft)  # in each task, not scattered: a dead worker's copy would cancel the rest

        def submit(p: StatusPoint):
            return client.submit(fly_shipped, p, config, ship, fly, pure=False, key=f"fly-{p.id}-{os.urandom(4).hex()}")

        futures = {submit(p): p for p in points}
        killed = []
        for fut in as_completed(list(futures), loop=client.loop):
            p = futures.pop(fut)  # released once read: the cluster keeps a result while a future holds it
            outcome = _outcome(fut, p)
            fut.release()
            if outcome is None:  # it may only have shared a worker with the point that killed it
                killed.append(p)
                continue
            yield outcome
        for p in killed:  # once more, alone on the cluster: a death now is its own
            fut = submit(p)
            yield _outcome(fut, p, last=True)
    finally:
        client.close()


def _outcome(fut, p: StatusPoint, last: bool = False):
    """``(record, logs)`` of a finished future; None if its worker died (or the cluster cancelled it)
    and it may be tried again."""
    from distributed.client import FutureCancelledError

    try:
        return fut.result()
    except UserError:
        raise
    except FutureCancelledError as exc:
        if not last:
            return None
        return failed_record(p, f"cancelled on the cluster ({exc})"), []
    except Exception as exc:  # noqa: BLE001 - a worker's death or error fails its point only
        kind = type(exc).__name__
        if kind == "KilledWorker" and not last:
            return None
        why = "its worker died while flying it, alone on the cluster" if kind == "KilledWorker" else "a worker raised"
        return failed_record(p, f"{why} ({kind}: {str(exc).splitlines()[0] if str(exc) else ''})", transient=True), []
