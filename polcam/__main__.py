"""``python -m polcam``: the same as the ``polcam`` command."""

import sys

from polcam.cli import main

sys.exit(main())
