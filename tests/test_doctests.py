"""The Examples sections of the public functions run as written (doctest) and print what they
show.  Each function is found through its public name, so the test follows it if it moves."""

from __future__ import annotations

import doctest
import time

import pytest

import polcam
import polcam.camera

FUNCTIONS = {
    "polcam.read_frame": lambda: polcam.read_frame,
    "polcam.demosaic": lambda: polcam.demosaic,
    "polcam.stokes": lambda: polcam.stokes,
    "polcam.dolp": lambda: polcam.dolp,
    "polcam.aolp": lambda: polcam.aolp,
    "polcam.separate": lambda: polcam.separate,
    "polcam.camera.open_camera": lambda: polcam.camera.open_camera,
}


@pytest.mark.parametrize("name", sorted(FUNCTIONS))
def test_examples_run_as_written(name):
    fn = FUNCTIONS[name]()
    tests = doctest.DocTestFinder(recurse=False).find(fn, name, globs={})
    assert len(tests) == 1 and len(tests[0].examples) >= 2, f"{name} has no Examples section"
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS)
    t0 = time.perf_counter()
    result = runner.run(tests[0], out=lambda text: pytest.fail(text, pytrace=False))
    assert result.failed == 0 and result.attempted == len(tests[0].examples)
    assert time.perf_counter() - t0 < 10, f"{name}: the examples take too long"


def test_a_wrong_output_fails():
    def wrong():
        """
        >>> 1 + 1
        3
        """

    (test,) = doctest.DocTestFinder().find(wrong, "wrong", globs={})
    result = doctest.DocTestRunner().run(test, out=lambda text: None)
    assert result.failed == 1
