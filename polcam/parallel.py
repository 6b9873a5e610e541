"""polcam's one policy for running work in parallel: start method, worker count, BLAS threads.

Worker processes are started by **forkserver** where the platform has it
(Linux, macOS), by spawn elsewhere; never by plain fork.  A process that forks
while other threads run (BLAS and OpenMP pools, OpenImageIO, a live view's
reader thread, a user's application) hands the child copies of locks those
threads may hold at that instant, and a child that then takes such a lock
waits forever (Python 3.12 warns about it; 3.14 made forkserver the default on
Linux).  A fork server is a clean single-threaded process, started once, that
forks each worker: as cheap per worker as fork after its first start (about
0.4 s, which :func:`start_workers` can pay up front), with the modules of
:data:`PRELOAD` (and a caller's ``preload``) imported once in the server.
Like spawn, it imports the main script in each worker, which must be guarded
by ``if __name__ == "__main__":``.

Every worker limits its BLAS/OpenMP pools to ``blas_threads`` threads (default
1): the work is split among processes, and N workers each running a pool of
the CPU count's threads oversubscribe the cores (OpenBLAS' threaded complex SVD
of the tensor method's slice sizes ran 12 times slower than its
single-threaded one on a 2-core machine).

Public API::

    default_workers(limit=MAX_AUTO_WORKERS) -> int      # CPU count, at most limit
    context(preload=()) -> multiprocessing context        # the start method above
    start_workers(preload=()) -> str                      # start the fork server now
    process_pool(workers, *, preload=(), blas_threads=1, initializer=None)  # a ProcessPoolExecutor
    map_processes(fn, jobs, workers, ...) -> list         # [fn(j) for j in jobs] in processes
    submit_processes(fn, jobs, workers, ...) -> (pool, futures)
    blas_limit(threads=1)                                 # context manager, this process
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from typing import Any

from threadpoolctl import threadpool_limits

__all__ = [
    "MAX_AUTO_WORKERS",
    "PRELOAD",
    "default_workers",
    "start_method",
    "context",
    "start_workers",
    "process_pool",
    "map_processes",
    "submit_processes",
    "blas_limit",
]

#: Most workers chosen automatically (each holds a few hundred MB at most).
MAX_AUTO_WORKERS = 8
#: Modules the fork server imports once for all its workers (the separation methods: numpy,
#: scipy, OpenCV and polcam's methods).
PRELOAD: tuple[str, ...] = ("polcam.separation",)


def default_workers(limit: int = MAX_AUTO_WORKERS) -> int:
    """Workers used when none is asked for: the CPUs this process may run on, at most ``limit``."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - not Linux
        n = os.cpu_count() or 1
    return max(1, min(n, int(limit)))


def start_method() -> str:
    """``"forkserver"`` where the platform has it, else ``"spawn"`` (never ``"fork"``)."""
    return "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"


def context(preload: Sequence[str] = ()) -> Any:
    """The multiprocessing context of every polcam worker pool (:func:`start_method`).

    ``preload``: modules the fork server imports besides :data:`PRELOAD`; it has
    effect only before the server starts (the first pool, or :func:`start_workers`).
    """
    ctx = multiprocessing.get_context(start_method())
    if ctx.get_start_method() == "forkserver":
        ctx.set_forkserver_preload(sorted(set(PRELOAD) | set(preload)))
    return ctx


def start_workers(preload: Sequence[str] = ()) -> str:
    """Start the fork server now (if that is the start method); returns the start method.

    The server starts on first use, which costs about 0.4 s (a fresh interpreter
    importing the preloaded modules): a program that times its work, or runs
    it repeatedly, can pay it up front.
    """
    ctx = context(preload)
    method = ctx.get_start_method()
    if method == "forkserver":
        from multiprocessing import forkserver

        forkserver.ensure_running()
    return method


def _limit_blas(threads: int, then: Callable[[], None] | None = None) -> None:
    """Worker initializer: at most ``threads`` BLAS/OpenMP threads for the worker's life, then ``then()``."""
    threadpool_limits(limits=threads)
    if then is not None:
        then()


def blas_limit(threads: int = 1) -> Any:
    """Context manager: at most ``threads`` BLAS threads in this process while it is open."""
    return threadpool_limits(limits=threads, user_api="blas")


def process_pool(workers: int, *, preload: Sequence[str] = (), blas_threads: int = 1,
                 initializer: Callable[[], None] | None = None) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes started by :func:`context`, each with ``blas_threads`` BLAS threads.

    ``initializer``: a module-level function each worker runs once after limiting its threads.
    """
    return ProcessPoolExecutor(max_workers=workers, mp_context=context(preload), initializer=_limit_blas,
                               initargs=(int(blas_threads), initializer))


def submit_processes(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int, *,
                     preload: Sequence[str] = ()) -> tuple[ProcessPoolExecutor, list[Future]]:
    """Start ``fn(j)`` for every job in ``workers`` processes; returns the pool and the futures.

    The caller collects the results and shuts the pool down (``with pool:``).
    """
    pool = process_pool(workers, preload=preload)
    try:
        return pool, [pool.submit(fn, job) for job in jobs]
    except BaseException:
        pool.shutdown(cancel_futures=True)
        raise


def map_processes(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int, *,
                  preload: Sequence[str] = (), in_flight: int = 2) -> list[Any]:
    """``[fn(j) for j in jobs]`` in ``workers`` processes, at most ``in_flight`` jobs per worker queued.

    Jobs are drawn from the iterable as workers free up, so a generator of
    large jobs is never held whole in memory.
    """
    out: dict[int, Any] = {}
    it = iter(enumerate(jobs))
    with process_pool(workers, preload=preload) as pool:
        pending: dict[Future, int] = {}
        for i, job in it:
            pending[pool.submit(fn, job)] = i
            if len(pending) >= in_flight * workers:
                break
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                out[pending.pop(f)] = f.result()
                nxt = next(it, None)
                if nxt is not None:
                    pending[pool.submit(fn, nxt[1])] = nxt[0]
    return [out[i] for i in range(len(out))]
