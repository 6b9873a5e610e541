"""What the commands share: option parsing, camera arguments, running a command with exit statuses.

Exit statuses of every command (:func:`run_command`): 0 done; 1 some frames
failed (each reported); 2 bad input or options (a :class:`PolcamError`, its
message on stderr; nothing done); 3 camera unavailable; 130 interrupted.
"""

from __future__ import annotations

import argparse
import difflib
import json
import re
import sys
from collections.abc import Sequence
from typing import Any, NoReturn

from polcam.camera.base import TRIGGER_MODES, Camera
from polcam.camera.registry import backend_for, camera_flags
from polcam.errors import CameraUnavailableError, PolcamError
from polcam.separation import default_method

__all__ = [
    "CAMERA_SETTINGS",
    "CommandParser",
    "positive_int",
    "add_max_pixels_argument",
    "default_methods_text",
    "add_camera_arguments",
    "camera_options",
    "configure_camera",
    "parse_option",
    "parse_options",
    "run_command",
    "reproducing_command",
]


def _suggest(word: str, candidates: Sequence[str]) -> str:
    """`` (did you mean X?)`` for the closest candidate, or ``""``."""
    close = difflib.get_close_matches(word, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


class CommandParser(argparse.ArgumentParser):
    """The parser of polcam and of each of its commands: errors name the command and suggest.

    A command's parser reports arguments it does not know itself (argparse
    leaves them to the top-level parser, which prints its own usage): the
    command's usage, ``unrecognized arguments``, and the closest of its flags
    (``--methd`` -> ``--method``).  An invalid choice (a command, ``--format``,
    ...) is followed by the closest valid one.  Exit status 2, before any work.
    """

    def parse_known_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                         namespace: argparse.Namespace | None = None) -> tuple[argparse.Namespace, list[str]]:
        ns, extras = super().parse_known_args(args, namespace)
        if extras and getattr(self, "_polcam_command", False):
            flags = [s for a in self._actions for s in a.option_strings if s.startswith("--")]
            hints = "".join(_suggest(e.split("=", 1)[0], flags) for e in extras if e.startswith("-"))
            self.error(f"unrecognized arguments: {' '.join(extras)}{hints}")
        return ns, extras

    def error(self, message: str) -> NoReturn:
        got = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if got:
            message += _suggest(got.group(1), re.findall(r"'([^']*)'", got.group(2)))
        super().error(message)

    def add_subparsers(self, **kwargs: Any) -> Any:
        kwargs.setdefault("parser_class", _CommandLevel)
        return super().add_subparsers(**kwargs)


class _CommandLevel(CommandParser):
    """A command's (or sub-command's) parser: it reports its own unrecognized arguments."""

    _polcam_command = True


def reproducing_command(prog: str, args: argparse.Namespace, names: Sequence[str]) -> str:
    """The command line that repeats a parsed run: ``prog``, then ``--name value`` for each of ``names``.

    Floats are written with ``%g``; an underscore in a name becomes a hyphen, as argparse reads it.
    What a training command stores beside the weights it writes.
    """
    parts = [prog]
    for name in names:
        value = getattr(args, name)
        parts.append(f"--{name.replace('_', '-')} {value:g}" if isinstance(value, float) else
                     f"--{name.replace('_', '-')} {value}")
    return " ".join(parts)


def positive_int(text: str) -> int:
    """argparse type: an integer of at least 1 (``--workers 0`` and ``-3`` are refused)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def parse_option(text: str, *, flag: str = "--option") -> tuple[str, Any]:
    """``KEY=VALUE`` of a method-option flag: VALUE as JSON, else the string itself."""
    if "=" not in text:
        raise PolcamError(f"{flag} {text!r}: expected KEY=VALUE (VALUE as JSON, e.g. max_iter=50)")
    key, value = text.split("=", 1)
    try:
        return key.strip(), json.loads(value)
    except ValueError:
        return key.strip(), value


def add_max_pixels_argument(parser: Any) -> None:
    """``--max-pixels N``: the largest frame a command reads (a larger declared size is refused unread)."""
    parser.add_argument("--max-pixels", type=int, metavar="N",
                        help="largest frame to read, pixels (default 134217728 = 2^27); a file whose header "
                             "or sidecar declares more is refused before it is read")


def default_methods_text() -> str:
    """``"tensor for colour, imin for mono"``: the registry's default separation per frame kind."""
    return f"{default_method('stack')} for colour, {default_method('mono-stack')} for mono"


def parse_options(texts: list[str] | None, *, flag: str = "--option") -> dict[str, Any]:
    """Every ``KEY=VALUE`` of a repeatable method-option flag as a dict (:func:`parse_option`)."""
    return dict(parse_option(t, flag=flag) for t in texts or [])


def run_command(args: argparse.Namespace) -> int:
    """Run a parsed command (its ``func``) and map errors to exit statuses.

    0 or the command's own status; 3 when a camera is unavailable (Aravis
    missing, no such camera, busy); 2 for any other :class:`PolcamError`
    (the message on stderr); 130 when interrupted; 141 (as a shell reports SIGPIPE) when the
    reader of the output went away, quietly.  The standalone entry
    points (``python -m polcam.capture``, ``python -m polcam.calibration``)
    use it too.
    """
    try:
        return int(args.func(args) or 0)
    except CameraUnavailableError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 3
    except PolcamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into a reader that stopped (`polcam formats | head`)
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 141


def add_camera_arguments(parser: Any, *, layout: bool = True) -> None:
    """Add the camera options ``polcam capture`` and ``polcam calibrate --device`` share.

    Settings (``--pixel-format``, ``--layout``, ``--exposure``, ``--gain``,
    ``--roi``, ``--frame-rate``, ``--trigger``, ``--reverse-x``,
    ``--reverse-y``), ``--timeout``, and the flags each camera backend declares
    (:func:`polcam.camera.registry.camera_flags`: ``--loop`` for replay;
    ``--buffers``, ``--packet-size``, ``--socket-buffer`` for Aravis); read
    them back with :func:`camera_options` and :func:`configure_camera`.

    Parameters
    ----------
    parser
        The command's ``argparse.ArgumentParser``, or an argument group of it.
    layout
        Add ``--layout`` too (a command that has its own leaves it out).
    """
    p = parser
    p.add_argument("--pixel-format", help="GenICam PixelFormat (`polcam formats` lists what polcam reads)")
    if layout:
        p.add_argument("--layout", help="sensor layout for plain Mono/Bayer formats (imx250mzr, imx250myr, "
                                        "mono:A,B,C,D, color:A,B,C,D:BAYER)")
    p.add_argument("--exposure", type=float, metavar="US", help="exposure time, microseconds")
    p.add_argument("--gain", type=float, metavar="DB", help="gain, dB")
    p.add_argument("--roi", type=int, nargs=4, metavar=("X", "Y", "W", "H"),
                   help="region of interest on the sensor (aligned down to whole polarizer cells)")
    p.add_argument("--frame-rate", type=float, metavar="FPS",
                   help="frame rate (replay: playback rate; default as fast as read, lossless)")
    p.add_argument("--trigger", help=f"{' | '.join(TRIGGER_MODES)} | a line (Line0, ...); default: "
                                     "as the camera is")
    p.add_argument("--reverse-x", action="store_true", default=None, help="mirror the image left-right")
    p.add_argument("--reverse-y", action="store_true", default=None, help="mirror the image top-bottom")
    p.add_argument("--timeout", type=float, default=10.0,
                   help="give up when no frame arrives for S seconds (default 10)")
    for flag in camera_flags():  # each backend's own (polcam.camera.registry)
        p.add_argument(flag.flag, help=flag.help, **flag.argparse)


#: Destinations of the camera settings :func:`add_camera_arguments` adds, with their flags.
CAMERA_SETTINGS: dict[str, str] = {
    "pixel_format": "--pixel-format", "exposure": "--exposure", "gain": "--gain", "roi": "--roi",
    "frame_rate": "--frame-rate", "trigger": "--trigger", "reverse_x": "--reverse-x", "reverse_y": "--reverse-y",
}


def camera_options(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments of :func:`polcam.camera.open_camera` from the parsed camera options: the
    values of the flags the ``--device`` string's backend declares, and the settings it takes when
    opened (:class:`polcam.camera.registry.Backend`).

    Raises
    ------
    CameraSettingError
        A value the backend refuses (a ``--packet-size`` that is neither a number nor ``auto``).
    CameraNotFoundError
        An empty ``--device``, or no backend for it.
    """
    backend, _ = backend_for(args.device)
    return backend.options(vars(args))


def configure_camera(camera: Camera, args: argparse.Namespace, *, quiet: bool = False) -> dict[str, Any]:
    """Apply the parsed camera settings to an open camera; returns what it reports.

    Settings the camera cannot change are listed in the result's ``ignored``
    and, unless ``quiet``, named in a note on stderr.

    Raises
    ------
    CameraSettingError, PixelFormatError, LayoutError
        A setting the camera refuses (the message names it and the value).
    """
    settings = camera.configure(
        pixel_format=args.pixel_format, layout=args.layout, exposure_us=args.exposure,
        gain_db=args.gain, roi=tuple(args.roi) if args.roi else None,
        frame_rate=None if "frame_rate" in backend_for(args.device)[0].open_settings else args.frame_rate,
        trigger=args.trigger, reverse_x=args.reverse_x, reverse_y=args.reverse_y,
    )
    if settings.get("ignored") and not quiet:
        print(f"note: camera {camera.camera_id} cannot change {', '.join(settings['ignored'])}; ignored",
              file=sys.stderr)
    return settings
