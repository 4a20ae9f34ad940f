"""Local worker processes, forked from a server that has already imported what they need.

A worker started afresh (``spawn``, as joblib's loky does) spends 1.2-1.5 s importing numpy,
scipy, pandas and JSBSim before its first task, and every command that fans out paid
that once per pool. Here the standard library's ``forkserver`` imports the modules
once, in one process, from the moment :func:`warm` is called (the caller goes on with
its own serial work meanwhile); each worker is a fork of that server, ready in
milliseconds, sharing the imported code's pages. Where ``forkserver`` does not exist
(Windows) the workers are spawned.

The pool is kept for the life of the process, so a worker's caches (its JSBSim
evaluator, :func:`diagnose.evaluate.evaluator_for`) serve the next call; it is made
again if a worker died. Each worker does its linear algebra on one BLAS thread: the
matrices are small and the cores are the workers' (:func:`one_blas_thread`).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Callable, Iterable, Iterator

_POOL: dict[int, ProcessPoolExecutor] = {}  # at most one pool: {jobs: pool}


def _context():
    return mp.get_context("forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn")


def warm(modules: Iterable[str]) -> None:
    """Start the fork server now, importing ``modules`` once (in the background: this returns at
    once). Only the first call of a process chooses the modules; later workers import the rest
    themselves on first use."""
    ctx = _context()
    if ctx.get_start_method() != "forkserver":
        return
    from multiprocessing import forkserver
    ctx.set_forkserver_preload(sorted(set(modules)))
    forkserver.ensure_running()


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


def executor(jobs: int) -> ProcessPoolExecutor:
    """This process's pool of ``jobs`` workers (made on first use, or again if the number changed)."""
    pool = _POOL.get(jobs)
    if pool is None:
        for old in _POOL.values():
            old.shutdown(wait=False, cancel_futures=True)
        _POOL.clear()
        pool = _POOL[jobs] = ProcessPoolExecutor(jobs, mp_context=_context(), initializer=one_blas_thread)
    return pool


def _in(cwd: str, func: Callable, args: tuple):
    os.chdir(cwd)  # a worker is forked from the server: relative paths mean the caller's
    return func(*args)


def submit(func: Callable, calls: list[tuple], jobs: int) -> list[Future]:
    """``func(*args)`` for each ``args`` in ``calls`` on the pool of ``jobs`` workers, started now
    (in the caller's working directory); a pool a dead worker broke is made again first."""
    cwd = os.getcwd()

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


def pmap(func: Callable, calls: list[tuple], jobs: int) -> list:
    """``[func(*args) for args in calls]`` on ``jobs`` workers (in this process if 1), in order."""
    if jobs <= 1 or len(calls) <= 1:
        return [func(*args) for args in calls]
    return list(results(submit(func, calls, jobs)))


def _ahead(send, stop, cwd: str, func: Callable, calls: list[tuple]) -> None:
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
    send.close()


class Ahead:
    """Tasks done while a core would otherwise idle, before anyone asks for their results.

    ``func(*args)`` for each ``args`` in ``calls``, one after the other in a process of
    their own (a fork of the warm server; nothing with one job): the caller keeps a core,
    the pool's workers stay free and do not keep what these tasks leave in memory.
    :meth:`stop` ends the chain after the task running, so that work needed now does not
    share the cores with it; :meth:`finished` gives what was done, by index into ``calls``.
    Whatever it lacks the caller computes itself.
    """

    def __init__(self, func: Callable, calls: list[tuple], jobs: int) -> None:
        self._done: dict[int, object] = {}
        self._error: BaseException | None = None
        self._thread = None
        ctx = _context()
        self._stopped = ctx.Event() if jobs > 1 and calls else threading.Event()
        if jobs > 1 and calls:  # a thread starts the process: that waits for the warm server's imports
            self._thread = threading.Thread(target=self._collect, args=(ctx, func, calls), daemon=True)
            self._thread.start()

    def _collect(self, ctx, func: Callable, calls: list[tuple]) -> None:
        recv, send = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=_ahead, args=(send, self._stopped, os.getcwd(), func, calls), daemon=True)
        proc.start()
        send.close()
        try:
            while True:
                i, ok, value = recv.recv()
                if ok:
                    self._done[i] = value
                else:
                    self._error = value
        except EOFError:  # the chain ended (or its process died: the caller computes the rest)
            pass
        finally:
            recv.close()
            proc.join()

    def stop(self) -> None:
        """Start no more tasks."""
        self._stopped.set()

    def finished(self) -> dict[int, object]:
        """Each task's result, by its index, but for those not started (the one running is
        waited for; a task's exception is raised here)."""
        self.stop()
        if self._thread is not None:
            self._thread.join()
        if self._error is not None:
            raise self._error
        return dict(self._done)


class WorkerDied(RuntimeError):
    """The worker process of :func:`alone` died (a signal or an exit) before it answered."""


def _alone(send, cwd: str, func: Callable, args: tuple) -> None:
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
    ctx = _context()
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_alone, args=(send, os.getcwd(), func, args))
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
