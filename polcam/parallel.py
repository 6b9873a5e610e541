"""polcam's one policy for running work in parallel: threads in the library, processes in the commands.

**The library** (``polcam.separate`` and the steps it runs) works in
**threads** (:func:`map_threads`, :func:`submit_threads`), so a call works the
same from any caller: a script with or without an ``if __name__ ==
"__main__":`` guard, a script piped to ``python -``, ``python -c``, a
notebook, a thread, a Dask worker (whose daemonic processes may not start
processes of their own).  The heavy parts release the GIL (LAPACK through
:mod:`polcam.separation._lapack`, BLAS, FFTs, numpy's element-wise loops on
large arrays).  While threads run, BLAS is limited to one thread for the whole
process by :func:`blas_limit`: threadpoolctl's limits are process-global (they
set OpenBLAS' one thread count), so one limit is held around the whole
threaded section, counted across concurrent sections so that the first one
in sets it and the last one out restores what was there before.

**The commands** (``polcam process``), where polcam owns ``__main__``, run
frames in worker **processes** (:func:`process_pool`), and inside a command
(:func:`commands_own_main`, entered by :func:`polcam.commands.main`)
:func:`map_workers` and :func:`submit_workers` use processes too (a fifth
faster than threads for the tensor method's many small tiles on 2 cores), started by
**forkserver** where the platform has it (Linux, macOS), by spawn elsewhere;
never by plain fork.  A process that forks while other threads run (BLAS and
OpenMP pools, OpenImageIO, a live view's reader thread, a user's application)
hands the child copies of locks those threads may hold at that instant, and a
child that then takes such a lock waits forever (Python 3.12 warns about it;
3.14 made forkserver the default on Linux).  A fork server is a clean
single-threaded process, started once, that forks each worker: as cheap per
worker as fork after its first start (about 0.4 s, which
:func:`start_workers` can pay up front), with the modules of :data:`PRELOAD`
(and a caller's ``preload``) imported once in the server.  Like spawn, it
imports the main script in each worker: only code that owns ``__main__`` may
use it.

Every worker process limits its BLAS/OpenMP pools to ``blas_threads`` threads
(default 1): the work is split among processes, and N workers each running a
pool of the CPU count's threads oversubscribe the cores (OpenBLAS' threaded
complex SVD of the tensor method's slice sizes ran 12 times slower than its
single-threaded one on a 2-core machine).

**Memory.** A process polcam owns (a command, and each worker process)
keeps the memory it frees for its next frame (:func:`hold_freed_memory`):
glibc's default hands every large array back to the system when it is freed
and takes fresh, zero-filled pages for the next one, and for a wen21 separation
of a 1224 x 1024 colour stack those page faults cost 0.26 s of kernel time
per frame (0.72 s wall against 0.49 s; docs/decisions/memory-in-commands.md).

Public API::

    default_workers(limit=MAX_AUTO_WORKERS) -> int      # CPU count, at most limit
    map_threads(fn, jobs, workers) -> list               # [fn(j) for j in jobs] in threads
    submit_threads(fn, jobs, workers) -> (pool, futures)
    blas_limit(threads=1)                                # context manager, process-wide, counted
    context(preload=()) -> multiprocessing context        # the start method above
    start_workers(preload=()) -> str                      # start the fork server now
    process_pool(workers, *, preload=(), blas_threads=1, initializer=None)  # a ProcessPoolExecutor
    map_processes(fn, jobs, workers, ...) -> list         # [fn(j) for j in jobs] in processes
    submit_processes(fn, jobs, workers, ...) -> (pool, futures)
    hold_freed_memory() -> bool                           # keep freed memory for reuse (glibc)
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor, wait
from typing import Any

from threadpoolctl import threadpool_limits

__all__ = [
    "MAX_AUTO_WORKERS",
    "PRELOAD",
    "default_workers",
    "map_threads",
    "submit_threads",
    "commands_own_main",
    "map_workers",
    "submit_workers",
    "blas_limit",
    "limit_blas",
    "start_method",
    "context",
    "start_workers",
    "process_pool",
    "map_processes",
    "submit_processes",
    "hold_freed_memory",
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


#: glibc's mallopt parameters (malloc.h).
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8


def hold_freed_memory() -> bool:
    """Keep the memory this process frees for its later allocations (glibc; process-wide, for good).

    Sets glibc's allocator so that arrays up to 1 GiB come from the heap
    rather than from fresh ``mmap`` pages, freed memory is not trimmed back to
    the system, and all threads share one arena (a thread's own arena holds at
    most 64 MiB, so the 30-60 MB arrays of a separation thread would be mapped
    afresh every time).  The process's resident memory then stays at its peak
    instead of falling between frames, and the peak can be higher by what
    fragmentation leaves unused (one freed 100 MB array held beside the next
    in the test; a ``polcam process`` worker's ``wen21`` peak fell instead,
    906 MB -> 874 MB).

    polcam's commands and their worker processes call it (they own the process);
    a program that runs many frames through the library can call it too.

    Returns
    -------
    bool
        True where applied; False where the C library has no ``mallopt``
        (not glibc) or refused a setting.
    """
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    done = [mallopt(_M_ARENA_MAX, 1), mallopt(_M_MMAP_THRESHOLD, 1 << 30), mallopt(_M_TRIM_THRESHOLD, 2**31 - 1)]
    return all(r == 1 for r in done)


def limit_blas(threads: int, then: Callable[[], None] | None = None) -> None:
    """Worker initializer: at most ``threads`` BLAS/OpenMP threads for the worker's life, and the
    freed memory kept (:func:`hold_freed_memory`), then ``then()``."""
    threadpool_limits(limits=threads)
    hold_freed_memory()
    if then is not None:
        then()


_BLAS_LOCK = threading.Lock()
_BLAS_HELD: list[Any] = []     # the open limit (threadpoolctl's), while sections are open
_BLAS_OPEN = 0                 # sections open, in all threads


def _in_own_thread(fn: Callable[[], Any]) -> Any:
    """``fn()`` run in a short-lived thread of its own; its result.

    threadpoolctl lets one Python thread at a time change OpenBLAS' thread count
    (the "controlling thread", until it leaves its last limit context or ends),
    and ignores the others.  Setting and restoring the limit each in a thread
    that ends at once lets any caller's thread open the first section and any
    close the last.
    """
    box: list[Any] = []
    errors: list[BaseException] = []

    def run() -> None:
        try:
            box.append(fn())
        except BaseException as exc:  # pragma: no cover - threadpoolctl failing
            errors.append(exc)

    t = threading.Thread(target=run, name="polcam-blas-limit")
    t.start()
    t.join()
    if errors:  # pragma: no cover
        raise errors[0]
    return box[0]


@contextlib.contextmanager
def blas_limit(threads: int = 1) -> Iterator[None]:
    """Context manager: at most ``threads`` BLAS threads in this process while any section is open.

    The limit is process-wide (threadpoolctl sets the BLAS libraries' own
    thread counts), so sections opened by concurrent callers (two threads each
    running ``polcam.separate``) share one: the first section in sets it, the
    last one out restores the counts found by the first, whichever threads
    they run in; a section opened while another is open keeps the open one's
    limit.  BLAS calls of the process's other threads run under the limit
    meanwhile.  A thread of the caller's that holds threadpoolctl limits of its
    own (``with threadpool_limits(...)``, open) keeps them: threadpoolctl lets
    only that thread change them.
    """
    global _BLAS_OPEN
    with _BLAS_LOCK:
        if _BLAS_OPEN == 0:
            _BLAS_HELD.append(_in_own_thread(lambda: threadpool_limits(limits=int(threads), user_api="blas")))
        _BLAS_OPEN += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _BLAS_OPEN -= 1
            if _BLAS_OPEN == 0:
                _in_own_thread(_BLAS_HELD.pop().restore_original_limits)


def _map_bounded(pool: Executor, fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int,
                 in_flight: int) -> list[Any]:
    """``[fn(j) for j in jobs]`` on ``pool``, at most ``in_flight`` jobs per worker submitted ahead."""
    out: dict[int, Any] = {}
    it = iter(enumerate(jobs))
    pending: dict[Future, int] = {}
    try:
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
    except BaseException:
        for f in pending:
            f.cancel()
        raise
    return [out[i] for i in range(len(out))]


def map_threads(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int, *, in_flight: int = 2
                ) -> list[Any]:
    """``[fn(j) for j in jobs]`` in ``workers`` threads, at most ``in_flight`` jobs per thread queued.

    Jobs are drawn from the iterable as threads free up, so a generator of
    large jobs is never held whole in memory.  The first exception raised by
    ``fn`` is raised here (jobs not started are cancelled).  The caller limits
    BLAS (:func:`blas_limit`) around it where the jobs call BLAS.
    """
    if workers < 1:
        raise ValueError(f"workers = {workers!r}: expected a positive integer")
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="polcam") as pool:
        return _map_bounded(pool, fn, jobs, workers, in_flight)


def submit_threads(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int
                   ) -> tuple[ThreadPoolExecutor, list[Future]]:
    """Start ``fn(j)`` for every job in ``workers`` threads; returns the pool and the futures.

    The caller collects the results and shuts the pool down (``with pool:``).
    """
    if workers < 1:
        raise ValueError(f"workers = {workers!r}: expected a positive integer")
    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="polcam")
    try:
        return pool, [pool.submit(fn, job) for job in jobs]
    except BaseException:
        pool.shutdown(cancel_futures=True)
        raise


_COMMANDS_OWN_MAIN = 0   # depth of commands_own_main() sections open


@contextlib.contextmanager
def commands_own_main() -> Iterator[None]:
    """Context manager: a polcam command is running, so ``__main__`` is polcam's own.

    Inside it :func:`map_workers` and :func:`submit_workers` use worker
    processes, which import the main script; outside it (a library call from
    any script, notebook, thread or Dask worker) they use threads.  Entered by
    :func:`polcam.commands.main`.
    """
    global _COMMANDS_OWN_MAIN
    _COMMANDS_OWN_MAIN += 1
    try:
        yield
    finally:
        _COMMANDS_OWN_MAIN -= 1


def map_workers(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int) -> list[Any]:
    """``[fn(j) for j in jobs]`` in ``workers`` processes inside a polcam command, else threads.

    Small jobs whose Python overhead holds the GIL (the tensor method's tiles)
    run about a fifth faster in processes on 2 cores; only a command may start
    them (:func:`commands_own_main`).
    """
    if _COMMANDS_OWN_MAIN:
        return map_processes(fn, jobs, workers)
    return map_threads(fn, jobs, workers)


def submit_workers(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int
                   ) -> tuple[Executor, list[Future]]:
    """Start ``fn(j)`` for every job: processes inside a polcam command, else threads (as :func:`map_workers`)."""
    if _COMMANDS_OWN_MAIN:
        return submit_processes(fn, jobs, workers)
    return submit_threads(fn, jobs, workers)


def process_pool(workers: int, *, preload: Sequence[str] = (), blas_threads: int = 1,
                 initializer: Callable[[], None] | None = None) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes started by :func:`context`, each with ``blas_threads`` BLAS threads.

    ``initializer``: a module-level function each worker runs once after limiting its threads.
    """
    return ProcessPoolExecutor(max_workers=workers, mp_context=context(preload), initializer=limit_blas,
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
    large jobs is never held whole in memory.  For code that owns ``__main__``
    (the commands): the workers import the main script.
    """
    with process_pool(workers, preload=preload) as pool:
        return _map_bounded(pool, fn, jobs, workers, in_flight)
