"""``polcam bench``: every benchmark and tool is a sub-command of the one command line."""

from __future__ import annotations

import argparse
import subprocess
import sys

import pytest

from polcam.cli import build_parser, main
from polcam.synth.scenes import SCENES

BENCHES = {"demosaic", "train-lmmse", "demosaic-validation", "sihr", "quality", "speed", "real", "stability",
           "default-rule", "calibration", "scenes", "train-residual"}


def _bench_parser() -> argparse.ArgumentParser:
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["bench"]


def test_every_benchmark_is_a_sub_command():
    sub = next(a for a in _bench_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert set(sub.choices) == BENCHES
    for name, parser in sub.choices.items():
        assert callable(parser.get_default("bench_run")), name


def test_scenes_prints_every_scene(capsys):
    assert main(["bench", "scenes", "--size", "24"]) == 0
    rows = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("| ") and "scene (size" not in ln]
    assert [r.split("|")[1].strip() for r in rows] == list(SCENES)


def test_an_unknown_benchmark_is_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["bench", "no-such"])
    assert exc.value.code == 2 and "no-such" in capsys.readouterr().err


def test_python_m_polcam_calibration_bench_forwards_to_polcam_bench_calibration():
    proc = subprocess.run([sys.executable, "-m", "polcam.calibration", "bench", "--help"], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: polcam bench calibration") and "--dark-frames" in proc.stdout
