"""polcam.workpool: a dead worker costs only its job; an abort cancels the jobs in progress."""

from __future__ import annotations

import time

from polcam.workpool import orphaned, run_jobs

_KILL = "__import__('os').kill(__import__('os').getpid(), 9)"


def test_a_killed_worker_costs_only_its_job():
    results, lost = {}, {}
    run_jobs(eval, ["1+1", _KILL, "3*3", "2**10"], 2,
             on_result=lambda job, r: results.__setitem__(job, r), on_lost=lambda job, why: lost.__setitem__(job, why))
    assert results == {"1+1": 2, "3*3": 9, "2**10": 1024}
    assert list(lost) == [_KILL]
    assert lost[_KILL].signal == 9 and "killed (SIGKILL" in lost[_KILL].reason


def test_abort_cancels_the_jobs_in_progress():
    cancelled, t0 = [], time.monotonic()
    run_jobs(eval, ["__import__('time').sleep(60)", "__import__('time').sleep(60)", "1"], 2,
             on_result=lambda job, r: None, on_lost=lambda job, why: None, on_cancel=cancelled.append,
             abort=lambda: time.monotonic() - t0 > 1.0)
    assert len(cancelled) == 2 and time.monotonic() - t0 < 20


def test_stop_lets_the_jobs_in_progress_finish():
    done, t0 = [], time.monotonic()
    run_jobs(eval, ["__import__('time').sleep(1) or 'a'", "'b'", "'c'"], 1,
             on_result=lambda job, r: done.append(r), on_lost=lambda job, why: None,
             stop=lambda: time.monotonic() - t0 > 0.2)
    assert done == ["a"]


def test_not_orphaned_outside_a_worker():
    assert orphaned() is False


def test_an_idle_worker_that_died_loses_no_job():
    """Kill the only worker between two jobs: the next job goes to a new worker."""
    import multiprocessing
    import os
    import signal

    seen = []

    def on_result(job, r):
        seen.append(r)
        if len(seen) == 1:  # the worker is idle now: kill it before it gets the next job
            for c in multiprocessing.active_children():
                if c.name == "polcam-worker":
                    os.kill(c.pid, signal.SIGKILL)
                    c.join(5)

    run_jobs(eval, ["'a'", "'b'", "'c'"], 1, on_result=on_result, on_lost=lambda job, why: seen.append(why))
    assert seen == ["a", "b", "c"]
