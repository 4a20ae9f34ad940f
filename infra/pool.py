"""Local worker processes, forked from a server that has already imported what they need.

A worker started afresh (``spawn``, as joblib's loky does) spends 1.2-1.5 s importing numpy,
scipy, pandas and JSBSim before its first task, and every command that fans out paid
that once per pool. Here the standard library's ``forkserver`` imports the modules
once, in one process, from the moment :func:`warm` is called (the caller goes on with
its own serial work meanwhile); each worker is a fork of that server, ready in
milliseconds, sharing the imported code's pages. Where ``forkserver`` does not exist
(Windows) the workers are spawned.

The workers import what they run by module name and never import the caller's ``__main__``
(:class:`LibraryForkServer`); a function defined there travels by value instead (cloudpickle,
:func:`portable`). The standard library's workers would run ``__main__`` again, which breaks a
caller that is a script without an ``if __name__ == "__main__"`` guard (each worker would
start the script's work again, and multiprocessing refuses that), a script read from standard
input (``python -``: ``<stdin>`` is no file) and a notebook's kernel alike.

The pool is kept for the life of the process, so a worker's caches (its JSBSim
evaluator, :func:`diagnose.evaluate.evaluator_for`) serve the next call; it is made
again if a worker died. Each worker does its linear algebra on one BLAS thread: the
matrices are small and the cores are the workers' (:func:`one_blas_thread`).

Inside :func:`on_cluster` the same calls go to a Dask cluster instead (dask.distributed's own
futures); a folder the tasks read travels with them as data (:func:`ship`, :func:`landed`).
"""

from __future__ import annotations

import hashlib
import io
import multiprocessing as mp
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import context, process, spawn, util
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

_POOL: dict[int, ProcessPoolExecutor] = {}  # at most one pool: {jobs: pool}
_CLUSTER: list = []  # the Dask client of the innermost on_cluster, if any
_WARMED: list = []  # not empty once :func:`warm` has started the fork server


#: What the standard library's start-up data tells a new process to import as ``__main__``.
MAIN_KEYS = ("init_main_from_name", "init_main_from_path")


if "forkserver" in mp.get_all_start_methods():
    from multiprocessing import forkserver, popen_forkserver

    class _LibraryPopen(popen_forkserver.Popen):
        """The fork server's ``Popen`` (``multiprocessing.popen_forkserver``), its start-up data
        without :data:`MAIN_KEYS`: the new worker keeps the fork server's own ``__main__``."""

        def _launch(self, process_obj) -> None:
            prep = {k: v for k, v in spawn.get_preparation_data(process_obj._name).items() if k not in MAIN_KEYS}
            buf = io.BytesIO()
            context.set_spawning_popen(self)
            try:
                context.reduction.dump(prep, buf)
                context.reduction.dump(process_obj, buf)
            finally:
                context.set_spawning_popen(None)
            self.sentinel, w = forkserver.connect_to_new_process(self._fds)
            parent_w = os.dup(w)  # the child's sentinel of this process, as the standard library keeps it
            self.finalizer = util.Finalize(self, util.close_fds, (parent_w, self.sentinel))
            with open(w, "wb", closefd=True) as f:
                f.write(buf.getbuffer())
            self.pid = forkserver.read_signed(self.sentinel)

    class _LibraryProcess(process.BaseProcess):
        _start_method = "forkserver"

        @staticmethod
        def _Popen(process_obj):
            return _LibraryPopen(process_obj)

    class LibraryForkServer(context.ForkServerContext):
        """The ``forkserver`` start method for workers that run library functions only: they import
        what they run by module name, never the caller's ``__main__`` (a script without a guard,
        ``python -``, a notebook's kernel)."""

        Process = _LibraryProcess

    _LIBRARY = LibraryForkServer()
else:  # Windows: spawned workers import ``__main__`` again, which then needs its guard
    _LIBRARY = None


def _context():
    return _LIBRARY if _LIBRARY is not None else mp.get_context("spawn")


def warm(modules: Iterable[str]) -> None:
    """Start the fork server now, importing ``modules`` once (in the background: this returns at
    once). Only the first call of a process chooses the modules; later workers import the rest
    themselves on first use."""
    _WARMED.append(True)
    ctx = _context()
    if ctx.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver

    ctx.set_forkserver_preload(sorted(set(modules)))
    # the server and its forks ignore Ctrl-C (an ignored signal stays ignored across exec): the
    # terminal sends it to the whole process group, and the caller ends its workers itself
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        forkserver.ensure_running()
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)


#: The packages whose modules a library caller has imported are what its worker processes need.
PACKAGES = ("campaign", "identify", "diagnose", "maneuvers", "infra")


def _warm_as_imported() -> None:
    """:func:`warm` with this package's modules the caller has imported, unless the fork server is
    warm already (the command line warms it with what a command needs). A library caller (a script,
    the tests) otherwise started it cold, and every process forked from it imported numpy, scipy,
    pandas and JSBSim again: 2 s of CPU for each diagnosis's replays ahead."""
    if not _WARMED:
        warm([m for m in list(sys.modules) if m.split(".")[0] in PACKAGES])


#: The variables OpenBLAS, OpenMP and MKL read for their thread count when they are loaded.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """Linear algebra on one BLAS thread in this process, for the libraries loaded now and later.

    ``threadpool_limits`` reaches only the BLAS libraries already loaded, and numpy and scipy
    each load their own OpenBLAS (scipy's on the first ``scipy.linalg`` import): a library loaded
    afterwards starts one thread per core, and beside busy workers those threads wait on each
    other (the noise floor's fits took 5x longer so). The environment variables reach the
    libraries loaded later, and processes started from this one.
    """
    for var in BLAS_THREAD_VARIABLES:
        os.environ[var] = "1"
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")


def trim_memory() -> None:
    """Give the memory this process has freed back to the system (glibc's ``malloc_trim``; nothing
    elsewhere). Large arrays freed stay in the C heap otherwise, and a process that computes one stage
    after another holds the sum of their peaks."""
    if _TRIM is not None:
        _TRIM(0)


def _malloc_trim():
    import ctypes

    try:
        return ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None


_TRIM = _malloc_trim()


def executor(jobs: int) -> ProcessPoolExecutor:
    """This process's pool of ``jobs`` workers (made on first use, or again if the number changed).

    This process keeps working beside its busy workers, so from the first pool on its own linear
    algebra runs on one BLAS thread too (:func:`one_blas_thread`), as the command line's does: a
    library caller's second thread made the data compatibility's fits twice as slow beside them.
    """
    pool = _POOL.get(jobs)
    if pool is None:
        one_blas_thread()
        _warm_as_imported()
        for old in _POOL.values():
            old.shutdown(wait=False, cancel_futures=True)
        _POOL.clear()
        pool = _POOL[jobs] = ProcessPoolExecutor(jobs, mp_context=_context(), initializer=_worker)
    return pool


def _worker() -> None:
    """A worker's set-up: one BLAS thread; Ctrl-C, which the terminal sends to the whole process group,
    left to the caller (it ends the workers, :func:`stop_workers`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_blas_thread()


def stop_workers() -> None:
    """End this process's workers now, their tasks unfinished (the caller was interrupted: what they
    were writing is a temporary file that the next run removes)."""
    for pool in _POOL.values():
        procs = list((getattr(pool, "_processes", None) or {}).values())
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join(5.0)
        pool.shutdown(wait=False, cancel_futures=True)
    _POOL.clear()
    import multiprocessing

    late = multiprocessing.active_children()  # started as the interrupt came (a worker, the replays ahead)
    for proc in late:
        proc.terminate()
    for proc in late:
        proc.join(5.0)


class _ByValue:
    """A function of the caller's ``__main__``, pickled by value: the workers do not import ``__main__``."""

    def __init__(self, func: Callable) -> None:
        import cloudpickle

        self.blob = cloudpickle.dumps(func)

    def __call__(self, *args):
        import cloudpickle

        return cloudpickle.loads(self.blob)(*args)


def portable(func: Callable) -> Callable:
    """``func`` as a worker can call it: itself (pickled by reference to its module), or, if the
    caller's ``__main__`` defines it (a script, ``python -``, a notebook cell), pickled by value."""
    return _ByValue(func) if getattr(func, "__module__", None) == "__main__" else func


def _in(cwd: str, func: Callable, args: tuple):
    os.chdir(cwd)  # a worker is forked from the server: relative paths mean the caller's
    try:
        return func(*args)
    finally:
        trim_memory()  # a worker's next task starts from what it holds, not from this one's peak


@contextmanager
def on_cluster(client):
    """Within: :func:`submit` (and :func:`pmap`) send their calls to the Dask cluster of ``client``
    (a ``distributed.Client``), whatever ``jobs`` says; None changes nothing."""
    if client is None:
        yield
        return
    _CLUSTER.append(client)
    try:
        yield
    finally:
        _CLUSTER.pop()


@contextmanager
def local_workers():
    """Within: the local workers again, inside :func:`on_cluster` (for work that writes this
    machine's files)."""
    saved = list(_CLUSTER)
    _CLUSTER.clear()
    try:
        yield
    finally:
        _CLUSTER[:] = saved


def cluster():
    """The Dask client :func:`on_cluster` holds, or None (local workers)."""
    return _CLUSTER[-1] if _CLUSTER else None


def _on_cluster_worker(func: Callable, args: tuple):
    one_blas_thread()
    try:
        return func(*args)
    finally:
        trim_memory()


def submit(func: Callable, calls: list[tuple], jobs: int) -> list[Future]:
    """``func(*args)`` for each ``args`` in ``calls`` on the pool of ``jobs`` workers, started now
    (in the caller's working directory); a pool a dead worker broke is made again first. Within
    :func:`on_cluster`, on the Dask cluster instead (its futures have the same ``result()``)."""
    client = cluster()
    if client is not None:
        return [client.submit(_on_cluster_worker, func, args, pure=False) for args in calls]
    cwd = os.getcwd()
    func = portable(func)

    def start() -> list[Future]:
        return [executor(jobs).submit(_in, cwd, func, args) for args in calls]

    try:
        return start()
    except BrokenProcessPool:  # a worker died in an earlier call
        _POOL.pop(jobs).shutdown(wait=False, cancel_futures=True)
        return start()


def results(futures: list[Future]) -> Iterator:
    """Each future's result in order, as it comes (a task's exception is raised here)."""
    for f in futures:
        yield f.result()


def imap(func: Callable, calls: list[tuple], jobs: int) -> Iterator:
    """:func:`pmap`'s results one at a time, in order; the caller holds one result at a time, not all
    (each future is dropped once read)."""
    if cluster() is None and (jobs <= 1 or len(calls) <= 1):
        for args in calls:
            yield func(*args)
        return
    futures = deque(submit(func, calls, jobs))
    while futures:
        yield futures.popleft().result()


def pmap(func: Callable, calls: list[tuple], jobs: int) -> list:
    """``[func(*args) for args in calls]`` on ``jobs`` workers (in this process if 1; on the cluster
    within :func:`on_cluster`), in order."""
    if cluster() is None and (jobs <= 1 or len(calls) <= 1):
        return [func(*args) for args in calls]
    return list(results(submit(func, calls, jobs)))


def _ahead(send, stop, cwd: str, func: Callable, calls: list[tuple], nice: int = 0) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller ends this process (a daemon) as it exits
    if nice and hasattr(os, "nice"):
        os.nice(nice)
    os.chdir(cwd)
    one_blas_thread()
    for i, args in enumerate(calls):
        if stop.is_set():
            break
        try:
            send.send((i, True, func(*args)))
        except BaseException as exc:  # handed back to the caller, raised there
            send.send((i, False, exc))
            break
        trim_memory()
    send.close()


class Ahead:
    """Tasks done while a core would otherwise idle, before anyone asks for their results.

    ``func(*args)`` for each ``args`` in ``calls``, one after the other in a process of
    their own (a fork of the warm server; nothing with one job): the caller keeps a core,
    the pool's workers stay free and do not keep what these tasks leave in memory.
    :meth:`stop` ends the chain after the task running, so that work needed now does not
    share the cores with it; :meth:`finished` gives what was done, by index into ``calls``.
    Whatever it lacks the caller computes itself. With ``nice`` (Unix) the process runs at that
    lower priority: beside the caller's busy workers it takes next to no CPU, and it takes a core
    whenever one would idle, the caller's serial work included; :meth:`finished` then ends the
    task running (``cancel``) rather than wait for it. As a context manager, it is cancelled on leaving.
    """

    def __init__(self, func: Callable, calls: list[tuple], jobs: int, nice: int = 0) -> None:
        self._done: dict[int, object] = {}
        self._error: BaseException | None = None
        self._thread = None
        self._proc = None
        self._nice = nice
        ctx = _context()
        self._stopped = ctx.Event() if jobs > 1 and calls else threading.Event()
        self._launched = threading.Event()  # the process started, or will not be
        if jobs > 1 and calls:  # a thread starts the process: that waits for the warm server's imports
            _warm_as_imported()
            self._thread = threading.Thread(target=self._collect, args=(ctx, func, calls), daemon=True)
            self._thread.start()

    def _collect(self, ctx, func: Callable, calls: list[tuple]) -> None:
        try:
            if self._stopped.is_set():  # cancelled before it began
                return
            recv, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(
                target=_ahead, args=(send, self._stopped, os.getcwd(), portable(func), calls, self._nice), daemon=True
            )
            proc.start()
            self._proc = proc
        finally:
            self._launched.set()
        send.close()
        try:
            while True:
                i, ok, value = recv.recv()
                if ok:
                    self._done[i] = value
                else:
                    self._error = value
        except (EOFError, OSError):  # the chain ended, or its process died or was ended mid-message: the
            pass  # caller computes the rest
        finally:
            recv.close()
            proc.join()

    def stop(self) -> None:
        """Start no more tasks."""
        self._stopped.set()

    def __enter__(self) -> Ahead:
        return self

    def __exit__(self, *exc) -> None:
        self.cancel()

    def cancel(self) -> None:
        """Start no more tasks, and end the one running unfinished (its result is left out)."""
        self.stop()
        if self._thread is not None:  # a process being started is waited for, so that none outlives the caller
            self._launched.wait(30.0)
        proc = self._proc
        if proc is not None and proc.is_alive():
            proc.terminate()  # what it was sending is cut short: the collector reads to the end of the pipe

    def finished(self, cancel: bool = False) -> dict[int, object]:
        """Each task's result, by its index, but for those not started (the one running is
        waited for, or with ``cancel`` ended and left out; a task's exception is raised here)."""
        self.cancel() if cancel else self.stop()
        if self._thread is not None:
            self._thread.join()
        if self._error is not None:
            raise self._error
        return dict(self._done)


class WorkerDied(RuntimeError):
    """The worker process of :func:`alone` died (a signal or an exit) before it answered."""


def _alone(send, cwd: str, func: Callable, args: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller, interrupted, ends this process
    try:
        answer = (True, _in(cwd, func, args))
    except BaseException as exc:  # handed back to the caller, raised there
        answer = (False, exc)
    send.send(answer)


def alone(func: Callable, args: tuple):
    """``func(*args)`` in a worker process of its own (a fork of the warm server), in the caller's
    working directory; its exception is raised here.

    Raises
    ------
    WorkerDied
        If the worker dies first, with its exit code (a signal by name: ``SIGABRT(-6)``).
    """
    _warm_as_imported()
    ctx = _context()
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_alone, args=(send, os.getcwd(), portable(func), args))
    proc.start()
    send.close()
    try:
        ok, value = recv.recv()
    except EOFError:
        proc.join()
        code = proc.exitcode
        name = f"{signal.Signals(-code).name}({code})" if code is not None and code < 0 else str(code)
        raise WorkerDied(f"exit code {name}") from None
    except BaseException:  # the caller interrupted: the worker goes too
        proc.terminate()
        raise
    finally:
        recv.close()
    proc.join()
    if not ok:
        raise value
    return value


@dataclass(frozen=True)
class Shipment:
    """A folder as data, for tasks on machines that do not share this one's files.

    Attributes
    ----------
    name : str
        The folder's name (kept: a JSBSim aircraft is found by its folder's name).
    sha256 : str
        The hash of its files (the worker's copy is stored under it).
    files : tuple of (str, bytes)
        Every file, by POSIX path relative to the folder.
    """

    name: str
    sha256: str
    files: tuple[tuple[str, bytes], ...]


def ship(folder: Path, extra: tuple[tuple[str, bytes], ...] = ()) -> Shipment:
    """``folder``'s files (caches left out; and ``extra`` files beside it, by name) as data."""
    folder = Path(folder)
    files = tuple(
        (rel, f.read_bytes())
        for f in sorted(folder.rglob("*"))
        if f.is_file() and "__pycache__" not in (rel := f.relative_to(folder).as_posix())
    )
    digest = hashlib.sha256()
    for rel, data in files + tuple(("../" + n, b) for n, b in extra):
        digest.update(rel.encode() + b"\0" + hashlib.sha256(data).digest())
    return Shipment(folder.name, digest.hexdigest(), tuple((f"{folder.name}/{r}", d) for r, d in files) + extra)


def landed(shipment: Shipment) -> Path:
    """This machine's copy of a shipment (its home folder, holding the folder under its name and
    the extra files), written once per machine, atomically."""
    home = Path(tempfile.gettempdir()) / "gearid-cluster" / shipment.sha256
    if not (home / "complete").exists():
        home.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".unpack-", dir=home.parent))
        for rel, data in shipment.files:
            dest = tmp / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)
        (tmp / "complete").write_text("")
        try:
            os.rename(tmp, home)
        except OSError:  # another worker on this machine got there first
            pass
    return home


#: The temporary folders :func:`owned_tmpdir` makes: ``gearid-[<kind>-]<pid>-<random>``.
OWNED = re.compile(r"gearid-(?:[a-z][a-z-]*-)?(\d+)-[^/]+")
_SWEPT: list = []  # not empty once this process has swept the temporary folder


def owned_tmpdir(kind: str = "") -> Path:
    """A new temporary folder, named for this process (``gearid-[<kind>-]<pid>-...``); the first
    call in a process sweeps the temporary folder first (:func:`sweep`)."""
    sweep()
    return Path(tempfile.mkdtemp(prefix=f"gearid-{kind + '-' if kind else ''}{os.getpid()}-"))


def sweep() -> None:
    """Remove the folders of :func:`owned_tmpdir` whose process no longer exists, among this user's in
    the temporary folder (once per process: later calls do nothing).

    A process removes its folders itself (finalizers), but a process killed (``kill -9``, a Dask
    worker its nanny ends, a pytest-xdist worker leaving by ``os._exit``) runs none.
    """
    if _SWEPT:
        return
    _SWEPT.append(True)
    for d in Path(tempfile.gettempdir()).glob("gearid-*"):
        m = OWNED.fullmatch(d.name)
        try:
            if m and d.stat().st_uid == os.getuid() and not _alive(int(m.group(1))):
                shutil.rmtree(d, ignore_errors=True)
        except OSError:  # removed meanwhile by another process's sweep
            pass


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, killed and not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (OSError, IndexError):  # no /proc (macOS), or it ended meanwhile
        return True
