"""``python -m polcam.calibration bench|dark|flat|polarizer ...``: a shim onto the ``polcam`` command line.

``bench`` is ``polcam bench calibration``; ``dark``, ``flat`` and ``polarizer``
are ``polcam calibrate ...`` (:mod:`polcam.commands.calibrate`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from polcam.commands import main as polcam_main


def main(argv: Sequence[str] | None = None) -> int:
    """Forward to ``polcam bench calibration`` or ``polcam calibrate``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "bench":
        return polcam_main(["bench", "calibration", *args[1:]])
    return polcam_main(["calibrate", *args])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
