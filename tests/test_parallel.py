"""polcam's parallel-execution policy: start method, worker count, BLAS threads in workers."""

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


def test_blas_limit_in_this_process():
    from threadpoolctl import threadpool_info

    with parallel.blas_limit(1):
        assert all(p["num_threads"] == 1 for p in threadpool_info() if p["user_api"] == "blas")


@pytest.mark.parametrize("bad", [0])
def test_bad_worker_count(bad):
    with pytest.raises(ValueError):
        parallel.process_pool(bad)
