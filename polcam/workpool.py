"""Supervised worker processes for batches: one job per worker at a time, so a death is charged to its job.

:class:`concurrent.futures.ProcessPoolExecutor` breaks as a whole when one
worker dies (``BrokenProcessPool``: every pending future fails, the other
workers are terminated) and cannot say which job the dead worker held.
:func:`run_jobs` starts its own workers (by :func:`polcam.parallel.context`:
forkserver where the platform has it), gives each one job at a time over a
pipe, and watches every worker's exit: a worker killed by the out-of-memory
killer, ``kill -9`` or a crash costs only the job it held, which is reported
to ``on_lost`` with the reason; a new worker takes its place and the other
jobs go on.

Workers die with the process that started them (``kill -9`` of the parent
must not leave workers writing to a folder a rerun is using):

* each worker holds the read end of a *lifeline* pipe whose only write end is
  in the parent; a thread in the worker waits on it and kills the worker when
  it reads end-of-file (the parent is gone);
* on Linux the worker also asks the kernel for ``SIGKILL`` when its parent
  process dies (``prctl(PR_SET_PDEATHSIG)``; the parent of a forkserver worker
  is the fork server, which exits once no process holds its alive pipe);
* :func:`orphaned` lets a job check, just before it publishes its results,
  that the parent is still there.

Workers ignore ``SIGINT``: a terminal's Ctrl-C reaches the whole process group,
and the parent decides whether the jobs in progress finish (first Ctrl-C) or
are cancelled (``abort``).  ``SIGTERM`` keeps its default action.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import threading
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import wait as wait_ready
from typing import Any

from polcam.parallel import context, limit_blas

__all__ = ["Lost", "orphaned", "run_jobs"]

_PR_SET_PDEATHSIG = 1
_LIFELINE: Any = None      # in a worker: the read end of its lifeline pipe


@dataclass(frozen=True)
class Lost:
    """Why a job's worker ended before returning a result."""

    reason: str                 # one line: what happened to the worker
    signal: int | None = None   # the signal that ended it, if one did


def _die_with_parent() -> None:
    """Ask the kernel to SIGKILL this process when its parent dies (Linux; elsewhere nothing)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        parent = os.getppid()
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        if os.getppid() != parent:  # the parent died before the request took effect
            os.kill(os.getpid(), signal.SIGKILL)
    except (OSError, AttributeError):  # pragma: no cover - no prctl (not Linux)
        pass


def _watch_lifeline(lifeline: Any) -> None:
    try:
        while True:
            lifeline.recv_bytes()
    except (EOFError, OSError):
        pass
    os.kill(os.getpid(), signal.SIGKILL)


def orphaned() -> bool:
    """True in a worker of :func:`run_jobs` whose parent has died (False anywhere else)."""
    if _LIFELINE is None:
        return False
    try:
        return bool(_LIFELINE.poll(0))      # readable means end-of-file: nothing is ever sent
    except (EOFError, OSError):
        return True


def _worker_main(conn: Any, lifeline: Any, fn: Callable[[Any], Any], blas_threads: int,
                 initializer: Callable[[], None] | None) -> None:
    global _LIFELINE
    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _LIFELINE = lifeline
    threading.Thread(target=_watch_lifeline, args=(lifeline,), name="polcam-lifeline", daemon=True).start()
    limit_blas(blas_threads, initializer)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        key, job = msg
        conn.send((key, fn(job)))


def _describe_exit(code: int | None) -> Lost:
    if code is not None and code < 0:
        sig = -code
        try:
            name = signal.Signals(sig).name
        except ValueError:
            name = f"signal {sig}"
        if sig == signal.SIGKILL:
            why = f"the worker process was killed ({name}: the out-of-memory killer, or kill -9)"
        else:
            why = f"the worker process was stopped by {name}"
        return Lost(why, sig)
    return Lost(f"the worker process exited with status {code} before finishing the frame")


class _Worker:
    def __init__(self, ctx: Any, fn: Callable[[Any], Any], blas_threads: int,
                 initializer: Callable[[], None] | None) -> None:
        self.conn, child = ctx.Pipe()
        life_r, self.life_w = ctx.Pipe(duplex=False)
        self.proc = ctx.Process(target=_worker_main, args=(child, life_r, fn, blas_threads, initializer),
                                daemon=True, name="polcam-worker")
        self.proc.start()
        child.close()
        life_r.close()
        self.job: tuple[int, Any] | None = None

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.close()

    def close(self) -> None:
        for c in (self.conn, self.life_w):
            try:
                c.close()
            except OSError:  # pragma: no cover
                pass


def run_jobs(fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int, *,
             on_result: Callable[[Any, Any], None], on_lost: Callable[[Any, Lost], None],
             stop: Callable[[], bool] = lambda: False, abort: Callable[[], bool] = lambda: False,
             on_cancel: Callable[[Any], None] | None = None, preload: Sequence[str] = (),
             blas_threads: int = 1, initializer: Callable[[], None] | None = None,
             poll: float = 0.2) -> None:
    """Run ``fn(job)`` for every job in ``workers`` supervised processes.

    Parameters
    ----------
    fn
        A module-level function (it is pickled to the workers); it should not
        raise (an exception ends its worker, reported as lost).
    jobs
        Drawn one at a time as workers free up.
    workers
        Number of worker processes (at least 1).
    on_result
        ``on_result(job, fn(job))`` in this process, as each job completes.
    on_lost
        ``on_lost(job, Lost)``: the worker holding ``job`` ended without a result.
    stop
        Polled between events: when True, no new job starts; the jobs in
        progress finish.
    abort
        Polled between events: when True, the jobs in progress are cancelled
        (their workers killed) and reported to ``on_cancel``; the call returns.
    on_cancel
        ``on_cancel(job)`` for each job in progress at an abort.
    preload, blas_threads, initializer
        As :func:`polcam.parallel.process_pool`.
    poll
        Seconds between checks of ``stop`` and ``abort``.
    """
    workers = max(1, int(workers))
    ctx = context(preload)
    it = iter(enumerate(jobs))
    exhausted = False
    again: list[tuple[int, Any]] = []   # jobs to hand out again (sent to a worker that had died)
    pool: list[_Worker] = []
    try:
        while True:
            if abort():
                _cancel(pool, on_cancel)
                return
            if not (exhausted and not again) and not stop():
                if _hand_out(pool, again, it, workers, stop, lambda: _Worker(ctx, fn, blas_threads, initializer)):
                    exhausted = True
            busy = [w for w in pool if w.job is not None]
            if not busy:
                if (again or not exhausted) and not stop():
                    continue        # a job to hand out again, or a worker to start
                return
            ready = set(wait_ready([w.conn for w in busy] + [w.proc.sentinel for w in busy], timeout=poll))
            _collect(busy, ready, pool, on_result, on_lost)
    finally:
        _shut_down(pool)


def _cancel(pool: list[_Worker], on_cancel: Callable[[Any], None] | None) -> None:
    """Kill the workers holding a job and report each job to ``on_cancel``."""
    for w in pool:
        if w.job is not None:
            job = w.job[1]
            w.job = None
            w.kill()
            if on_cancel is not None:
                on_cancel(job)


def _hand_out(pool: list[_Worker], again: list[tuple[int, Any]], it: Any, workers: int, stop: Callable[[], bool],
              make: Callable[[], _Worker]) -> bool:
    """Give a job to every idle worker, starting workers up to ``workers``; True when the jobs ran out.

    A job sent to an idle worker that had died never started: it goes to ``again``.
    """
    for w in [w for w in pool if w.job is None] + [None] * (workers - len(pool)):
        if stop():
            break
        nxt = again.pop() if again else next(it, None)
        if nxt is None:
            return True
        if w is None:
            w = make()
            pool.append(w)
        try:
            w.conn.send(nxt)
        except OSError:     # the idle worker had died: the job never started there
            again.append(nxt)
            pool.remove(w)
            w.kill()
            continue
        w.job = nxt
    return False


def _collect(busy: list[_Worker], ready: set[Any], pool: list[_Worker], on_result: Callable[[Any, Any], None],
             on_lost: Callable[[Any, Lost], None]) -> None:
    """Results of the busy workers that sent one; workers that ended without one are reported lost."""
    for w in busy:
        assert w.job is not None
        if w.conn in ready:
            try:
                key, result = w.conn.recv()
            except (EOFError, OSError):
                pass            # died while sending: handled below as lost
            else:
                job = w.job[1]
                w.job = None
                on_result(job, result)
                continue
        if w.proc.sentinel in ready or not w.proc.is_alive():
            w.proc.join(5)
            job = w.job[1]
            w.job = None
            pool.remove(w)
            w.close()
            on_lost(job, _describe_exit(w.proc.exitcode))


def _shut_down(pool: list[_Worker]) -> None:
    """Tell the idle live workers to stop, then join (and kill) every worker."""
    for w in pool:
        if w.job is None and w.proc.is_alive():
            try:
                w.conn.send(None)
            except OSError:
                pass
    for w in pool:
        w.proc.join(2)
        w.kill()
