"""Every flag error exits 2 before any work, with a message that names the flag (and a suggestion).

Run through ``polcam.cli.main`` (the parser and exit statuses of the ``polcam`` command), and the
two a new user meets first also as a subprocess.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from polcam.cli import main

REPO = Path(__file__).resolve().parents[2]
COLOUR = REPO / "fixtures" / "raw" / "synthetic_bunny5.png"


def _run(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:                   # argparse's own errors
        code = exc.code
    return int(code), capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["process", "IN", "-o", "OUT", "--methd", "tensor"],
     "polcam process: error: unrecognized arguments: --methd tensor (did you mean --method?)"),
    (["process", "IN", "-o", "OUT", "--fromat", "exr"],
     "polcam process: error: unrecognized arguments: --fromat exr (did you mean --format?)"),
    (["process", "IN", "-o", "OUT", "--methd=tensor"], "(did you mean --method?)"),
    (["stokes", "IN", "-o", "OUT", "--resolutoin", "cell"], "(did you mean --resolution?)"),
    (["calibrate", "dark", "IN", "-o", "OUT.npz", "--layot", "imx250mzr"],
     "polcam calibrate dark: error: unrecognized arguments: --layot imx250mzr (did you mean --layout?)"),
    (["capture", "--device", "replay:IN", "--seperate", "imin"], "(did you mean --separate?)"),
    (["process", "IN", "-o", "OUT", "--format", "exs"], "(did you mean exr?)"),
    (["process", "IN", "-o", "OUT", "--workers", "0"], "argument --workers: expected a positive integer, got 0"),
    (["process", "IN", "-o", "OUT", "--workers", "-3"], "argument --workers: expected a positive integer, got -3"),
    (["process", "IN", "-o", "OUT", "--workers", "two"], "expected a positive integer, got 'two'"),
    (["bench", "speed", "--workers", "0"], "argument --workers: expected a positive integer, got 0"),
])
def test_parser_errors(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, err = _run(argv, capsys)
    assert code == 2
    assert message in err
    assert "usage: polcam " + argv[0] in err           # the command's own usage, not the top level's
    assert list(tmp_path.iterdir()) == []               # nothing created


def test_misspelled_command_is_suggested(capsys):
    code, err = _run(["proces", "IN"], capsys)
    assert code == 2 and "(did you mean process?)" in err


def test_option_of_the_wrong_type_is_refused_before_any_frame(capsys, tmp_path):
    out = tmp_path / "out"
    code, err = _run(["process", str(COLOUR), "-o", str(out), "--method", "tensor", "--option", "max_iter=abc"],
                     capsys)
    assert code == 2
    assert "option max_iter='abc' of method 'tensor': expected an integer" in err
    assert not out.exists()


def test_capture_option_of_the_wrong_type_is_refused_before_any_frame(capsys, tmp_path):
    out = tmp_path / "out"
    code, err = _run(["capture", "--device", f"replay:{COLOUR.parent}", "--frames", "1", "--out", str(out),
                      "--method", "tensor", "--option", "tile=true", "--quiet"], capsys)
    assert code == 2
    assert "option tile=True of method 'tensor': expected an integer or a list of 2 integers or None" in err
    assert not out.exists()


def test_one_vocabulary_old_spellings_kept():
    from polcam.cli import build_parser

    p = build_parser()
    new = p.parse_args(["capture", "--device", "x", "--method", "tensor", "--option", "max_iter=3"])
    old = p.parse_args(["capture", "--device", "x", "--separate", "tensor", "--separate-option", "max_iter=3"])
    assert vars(new) == vars(old)
    assert new.separate == "tensor" and new.separate_option == ["max_iter=3"]
    demo_new = p.parse_args(["demo", "--method", "imin"])
    assert vars(demo_new) == vars(p.parse_args(["demo", "--separate", "imin"]))
    proc = p.parse_args(["process", "IN", "-o", "OUT", "--method", "imin", "--option", "a=1"])
    assert proc.method == "imin" and proc.option == ["a=1"]


def _polcam(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-m", "polcam", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)


def test_as_a_user_runs_it(tmp_path):
    r = _polcam("process", str(COLOUR), "-o", "out", "--methd", "tensor", cwd=tmp_path)
    assert r.returncode == 2 and "did you mean --method?" in r.stderr and "usage: polcam process" in r.stderr
    r = _polcam("process", str(COLOUR), "-o", "out", "--method", "tensor", "--option", "max_iter=abc",
                cwd=tmp_path)
    assert r.returncode == 2 and "option max_iter='abc' of method 'tensor': expected an integer" in r.stderr
    assert list(tmp_path.iterdir()) == []
