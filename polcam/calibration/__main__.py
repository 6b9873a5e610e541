"""``python -m polcam.calibration bench|dark|flat|polarizer ...``.

``bench`` runs :mod:`polcam.calibration.bench`; ``dark``, ``flat`` and
``polarizer`` are ``polcam calibrate ...`` (:mod:`polcam.commands.calibrate`).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> int:
    """Dispatch to the benchmark or to the calibrate command."""
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] == "bench":
        from polcam.calibration.bench import main as bench_main

        return bench_main(args[1:])
    from polcam.commands.calibrate import main as cli_main

    return cli_main(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
