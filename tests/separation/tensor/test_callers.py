"""``polcam.separate`` with the tensor method from every kind of caller a user has.

The parallel parts run in threads (:mod:`polcam.parallel`), so a call does not
depend on how the caller's ``__main__`` was started: a script without an
``if __name__ == "__main__":`` guard, a script piped to ``python -``,
``python -c``, a thread, a daemonic process (what a Dask worker is).
"""

from __future__ import annotations

import multiprocessing
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from polcam.separation import separate

#: A user's script, unguarded: it prints a line first (a worker process that imported the
#: script would print it again), then separates a 512 x 512 colour stack with the tensor
#: method (tiled at this size) in two threads.
SCRIPT = """\
print("start")
import numpy as np
import polcam

rng = np.random.default_rng(0)
yy, xx = np.mgrid[0:512, 0:512] / 512
albedo = np.stack([0.5 + 0.3 * np.cos(3 * xx), 0.4 + 0.2 * np.sin(2 * yy), 0.3 + 0.1 * xx], axis=-1)
spec = 0.4 * np.exp(-((xx - 0.5) ** 2 + (yy - 0.5) ** 2) / 0.02)[..., None]
angles = np.deg2rad([0, 45, 90, 135])[:, None, None, None]
stack = albedo / 2 + spec * (0.5 + 0.45 * np.cos(2 * angles - 1.0))
stack = np.clip(stack + rng.normal(0, 0.003, stack.shape), 0, 1)
res = polcam.separate(stack, method="tensor", max_iter=3, workers=2)
assert res.info["method"] == "tensor" and res.info["tiles"] > 1, res.info
assert np.all(np.isfinite(res.diffuse)) and res.diffuse.shape == (512, 512, 3)
print("done", res.info["tiles"])
"""


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONWARNINGS"] = "default"   # any warning would show on stderr
    return env


def _check(proc: subprocess.CompletedProcess) -> None:
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""
    lines = proc.stdout.split()
    assert lines.count("start") == 1 and "done" in lines


def test_unguarded_script_file(tmp_path: Path):
    script = tmp_path / "user_script.py"
    script.write_text(SCRIPT)
    _check(subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True,
                          env=_env(), timeout=240))


def test_script_through_stdin(tmp_path: Path):
    _check(subprocess.run([sys.executable, "-"], input=SCRIPT, cwd=tmp_path, capture_output=True, text=True,
                          env=_env(), timeout=240))


def _small_stack() -> np.ndarray:
    rng = np.random.default_rng(1)
    base = rng.uniform(0.2, 0.5, (1, 24, 24, 3))
    angles = np.deg2rad([0, 45, 90, 135])[:, None, None, None]
    return np.clip(base * (1 + 0.3 * np.cos(2 * angles)), 0, 1)


def test_from_a_thread_same_answer():
    stack = _small_stack()
    here = separate(stack, method="tensor", tile=12, overlap=4, workers=2, max_iter=20)
    got: dict[str, np.ndarray] = {}
    t = threading.Thread(target=lambda: got.setdefault(
        "d", separate(stack, method="tensor", tile=12, overlap=4, workers=2, max_iter=20).diffuse))
    t.start()
    t.join()
    np.testing.assert_array_equal(got["d"], here.diffuse)


def _in_daemon(queue) -> None:   # pragma: no cover - runs in the child
    res = separate(_small_stack(), method="tensor", tile=12, overlap=4, workers=2, max_iter=20)
    queue.put(res.diffuse)


def test_in_a_daemonic_process():
    """A Dask worker is a daemonic process, which may not start processes of its own."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_in_daemon, args=(queue,), daemon=True)
    proc.start()
    try:
        got = queue.get(timeout=120)
    finally:
        proc.join(timeout=30)
    assert proc.exitcode == 0
    here = separate(_small_stack(), method="tensor", tile=12, overlap=4, workers=2, max_iter=20)
    np.testing.assert_array_equal(got, here.diffuse)


def test_threads_give_the_sequential_answer_bit_for_bit():
    """Above 256 x 256 pixels both parallel parts run (the initial diffuse's four Yang'10 runs
    and the tiles, each in threads): the answer is that of one worker, bit for bit."""
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:260, 0:260] / 260
    albedo = np.stack([0.5 + 0.3 * np.cos(3 * xx), 0.4 + 0.2 * np.sin(2 * yy), 0.3 + 0.1 * xx], axis=-1)
    spec = 0.4 * np.exp(-((xx - 0.5) ** 2 + (yy - 0.5) ** 2) / 0.02)[..., None]
    angles = np.deg2rad([0, 45, 90, 135])[:, None, None, None]
    stack = np.clip(albedo / 2 + spec * (0.5 + 0.45 * np.cos(2 * angles - 1.0))
                    + rng.normal(0, 0.003, (4, 260, 260, 3)), 0, 1)
    one = separate(stack, method="tensor", workers=1, max_iter=4)
    two = separate(stack, method="tensor", workers=2, max_iter=4)
    assert two.info["tiles"] > 1
    np.testing.assert_array_equal(two.diffuse, one.diffuse)
