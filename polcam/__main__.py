"""``python -m polcam``: the same as the ``polcam`` command."""

import sys

from polcam.commands import main

sys.exit(main())
