"""The ``polcam`` entry point (``polcam.cli:main``): a shim onto :mod:`polcam.commands`.

``python -m polcam.cli --markdown [PAGE]`` prints docs/reference/PAGE.md (``cli``, the default, or
``cli-bench``).
"""

from __future__ import annotations

import sys

from polcam.commands import build_parser, main, parse_option, reference_markdown, run_command

__all__ = ["build_parser", "main", "parse_option", "reference_markdown", "run_command"]

if __name__ == "__main__":  # pragma: no cover
    if sys.argv[1:2] == ["--markdown"] and len(sys.argv) <= 3:
        sys.stdout.write(reference_markdown(*sys.argv[2:]))
        sys.exit(0)
    sys.exit(main())
