"""``python -m polcam.capture ...``: the capture command on its own (a shim).

The library is :mod:`polcam.acquisition` (saving, live processing, the
capture run); the command line is :mod:`polcam.commands.capture`.
"""

from __future__ import annotations

import sys

from polcam.commands.capture import main

__all__ = ["main"]

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
