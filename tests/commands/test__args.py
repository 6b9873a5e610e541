"""polcam.commands._args: option parsing and the exit statuses every command shares."""

from __future__ import annotations

import argparse

import pytest

from polcam.commands._args import default_methods_text, parse_option, parse_options, run_command
from polcam.errors import CameraUnavailableError, LayoutError, PolcamError


def test_option_values_are_json_else_text():
    assert parse_option("max_iter=50") == ("max_iter", 50)
    assert parse_option("device=cuda") == ("device", "cuda")
    assert parse_options(["a=[1, 2]", "b=true"]) == {"a": [1, 2], "b": True}
    assert parse_options(None) == {}
    with pytest.raises(PolcamError, match="--separate-option 'x': expected KEY=VALUE"):
        parse_option("x", flag="--separate-option")


@pytest.mark.parametrize("raised, status", [(None, 0), (LayoutError("bad layout"), 2),
                                            (CameraUnavailableError("no camera"), 3), (KeyboardInterrupt(), 130)])
def test_exit_statuses(raised, status, capsys):
    def func(_args):
        if raised is not None:
            raise raised
        return 0

    assert run_command(argparse.Namespace(func=func)) == status
    if isinstance(raised, Exception):
        assert str(raised) in capsys.readouterr().err


def test_default_methods_come_from_the_registry():
    from polcam.separation import default_method

    assert default_methods_text() == f"{default_method('stack')} for colour, {default_method('mono-stack')} for mono"
