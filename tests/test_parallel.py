"""polcam's parallel-execution policy: threads in the library, processes in the commands, BLAS threads."""

from __future__ import annotations

import multiprocessing
import os
import threading

import pytest

from polcam import parallel


def _pid_and_blas(_: int) -> tuple[int, list[int]]:
    from threadpoolctl import threadpool_info

    return os.getpid(), [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def _square(x: int) -> int:
    return x * x


def test_never_fork():
    method = parallel.start_method()
    assert method != "fork"
    if "forkserver" in multiprocessing.get_all_start_methods():
        assert method == "forkserver"
    assert parallel.context().get_start_method() == method


def test_default_workers_is_bounded():
    n = parallel.default_workers()
    assert 1 <= n <= parallel.MAX_AUTO_WORKERS
    assert parallel.default_workers(limit=1) == 1


def test_map_processes_keeps_order_and_limits_blas_in_workers():
    assert parallel.map_processes(_square, iter(range(7)), 2) == [x * x for x in range(7)]
    got = parallel.map_processes(_pid_and_blas, range(4), 2)
    assert all(pid != os.getpid() for pid, _ in got)
    assert all(all(n == 1 for n in blas) for _, blas in got)


def test_pools_work_with_a_thread_running():
    release = threading.Event()
    other = threading.Thread(target=release.wait, daemon=True)
    other.start()
    try:
        assert parallel.start_workers() == parallel.start_method()
        pool, futures = parallel.submit_processes(_square, [3, 4], 2)
        with pool:
            assert [f.result() for f in futures] == [9, 16]
    finally:
        release.set()
        other.join()


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info

    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_blas_limit_in_this_process():
    with parallel.blas_limit(1):
        assert all(n == 1 for n in _blas_threads())


def test_blas_limit_overlapping_sections_restore_the_original():
    """Two threads' sections overlap (A in, B in, A out, B out): the limit holds until the last
    one leaves, which restores the counts found before the first (threadpoolctl's limits are
    process-wide, and it lets one thread at a time change them)."""
    before = _blas_threads()
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen: dict[str, list[int]] = {}

    def a() -> None:
        with parallel.blas_limit(1):
            a_in.set()
            seen["a"] = _blas_threads()
            b_in.wait(10)
        a_out.set()

    def b() -> None:
        a_in.wait(10)
        with parallel.blas_limit(1):
            b_in.set()
            a_out.wait(10)
            seen["after_a_left"] = _blas_threads()

    ta, tb = threading.Thread(target=a), threading.Thread(target=b)
    ta.start()
    tb.start()
    ta.join()
    tb.join()
    assert seen["a"] and all(n == 1 for n in seen["a"] + seen["after_a_left"])
    assert _blas_threads() == before
    if any(n > 1 for n in before):   # the restore did something (more than one core here)
        with parallel.blas_limit(1):
            assert _blas_threads() != before
        assert _blas_threads() == before


def test_map_threads_keeps_order_runs_in_threads_and_raises():
    assert parallel.map_threads(_square, iter(range(9)), 2, in_flight=1) == [x * x for x in range(9)]
    names = parallel.map_threads(lambda _: threading.current_thread().name, range(4), 2)
    assert all(n.startswith("polcam") for n in names)
    started: list[int] = []

    def fail_at_3(x: int) -> int:
        started.append(x)
        if x == 3:
            raise ValueError("job 3")
        return x

    with pytest.raises(ValueError, match="job 3"):
        parallel.map_threads(fail_at_3, iter(range(100)), 2, in_flight=1)
    assert len(started) < 100            # jobs after the failure were not all started
    pool, futures = parallel.submit_threads(_square, [3, 4], 2)
    with pool:
        assert [f.result() for f in futures] == [9, 16]


@pytest.mark.parametrize("bad", [0, -3])
def test_bad_worker_count(bad):
    with pytest.raises(ValueError):
        parallel.process_pool(bad)
    with pytest.raises(ValueError):
        parallel.map_threads(_square, [1], bad)
    with pytest.raises(ValueError):
        parallel.submit_threads(_square, [1], bad)


def test_map_workers_uses_processes_only_inside_a_command():
    """A library call runs its jobs in threads of this process; inside a polcam command (which
    owns __main__) the same call runs them in worker processes."""
    pids = {pid for pid, _ in parallel.map_workers(_pid_and_blas, range(4), 2)}
    assert pids == {os.getpid()}
    with parallel.commands_own_main():
        pids = {pid for pid, _ in parallel.map_workers(_pid_and_blas, range(4), 2)}
        pool, futures = parallel.submit_workers(_square, range(3), 2)
        with pool:
            assert [f.result() for f in futures] == [0, 1, 4]
    assert os.getpid() not in pids
    pool, futures = parallel.submit_workers(_square, range(3), 2)
    with pool:
        assert isinstance(pool, parallel.ThreadPoolExecutor) and [f.result() for f in futures] == [0, 1, 4]



_MEMORY = """
import os, sys, threading
import numpy as np
from polcam.parallel import hold_freed_memory
held = hold_freed_memory() if sys.argv[1] == "hold" else None
page = os.sysconf("SC_PAGE_SIZE")

def rss():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * page

out = []
def frames():
    for _ in range(5):  # a frame's large temporary: allocated, written, freed
        a = np.empty(12_500_000)  # 100 MB
        a[:] = 1.0
        top = rss()
        del a
        out.append((top, rss()))

t = threading.Thread(target=frames)  # as a live separation thread allocates
t.start()
t.join()
print(held, *[v for pair in out for v in pair])
"""


def test_held_freed_memory_stays_in_the_process_and_is_reused():
    # glibc's default unmaps a freed 100 MB array (the next one is mapped and zero-filled afresh);
    # held, it stays resident and later frames' arrays reuse it: the memory stops growing
    import subprocess
    import sys

    def run(mode: str) -> tuple[str, list[int]]:
        out = subprocess.run([sys.executable, "-c", _MEMORY, mode], capture_output=True, text=True,
                             timeout=60, check=True).stdout.split()
        return out[0], [int(v) for v in out[1:]]

    held, hold = run("hold")
    if held != "True":
        pytest.skip("the C library has no mallopt (not glibc)")
    _, default = run("default")
    mb = 1 << 20
    assert all(top - after > 90 * mb for top, after in zip(default[::2], default[1::2]))  # given back
    assert all(top - after < 5 * mb for top, after in zip(hold[::2], hold[1::2]))  # kept
    # and reused: from the second frame on, every frame's array fits in memory already held
    assert max(hold) - hold[2] < 5 * mb
