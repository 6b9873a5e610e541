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


def test_output_into_a_closed_pipe_ends_quietly():
    # `polcam formats | head -1`: the reader goes away; no traceback, the shell's SIGPIPE status
    import fcntl
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "polcam", "formats"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    # a one-page pipe (before polcam has imported anything): its ~7.5 kB table cannot all fit
    fcntl.fcntl(proc.stdout.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), 4096)
    proc.stdout.readline()
    proc.stdout.close()           # the reader stops after one line
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(60) == 141 and "Traceback" not in err and "BrokenPipe" not in err, err


def test_each_backend_gets_the_flags_it_declares():
    """A backend registered with its own flag: the commands add the flag, and a --device string
    selecting that backend hands it that flag's value and no other backend's."""
    from polcam.camera.base import CameraSettingError
    from polcam.camera.registry import CameraFlag, register_backend, unregister_backend
    from polcam.commands._args import add_camera_arguments, camera_options

    opened = {}

    def factory(rest, **options):
        opened.update(rest=rest, **options)
        return "camera"

    register_backend("probe:", factory, flags=(CameraFlag("--probe-level", "level", "probe: a level",
                                                           {"type": int, "metavar": "N"}),),
                      open_settings=("frame_rate",))
    try:
        parser = argparse.ArgumentParser()
        add_camera_arguments(parser)
        args = parser.parse_args(["--probe-level", "3", "--frame-rate", "5", "--socket-buffer", "4096"])
        args.device = "probe:x"
        assert camera_options(args) == {"level": 3, "frame_rate": 5.0}
        args.device = "replay:/nowhere"
        assert camera_options(args) == {"loop": False, "frame_rate": 5.0}
        args.device = "Fake_1"                                  # the default backend: Aravis
        assert camera_options(args) == {"n_buffers": 16, "packet_size": 1500, "socket_buffer_bytes": 4096}
        args.packet_size = "jumbo"
        with pytest.raises(CameraSettingError, match="--packet-size 'jumbo'"):
            camera_options(args)
    finally:
        unregister_backend("probe:")
    parser = argparse.ArgumentParser()
    add_camera_arguments(parser)
    with pytest.raises(SystemExit):                            # the flag went with its backend
        parser.parse_args(["--probe-level", "3"])
