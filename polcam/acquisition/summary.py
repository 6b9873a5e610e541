"""Where a capture's summary goes: ``OUT/summary.json``, else the temporary or the current folder."""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

from polcam.acquisition.saving import os_reason
from polcam.errors import PolcamError
from polcam.io.atomic import atomic_write

__all__ = ["write_summary"]


def _summary_target(out: Path) -> Path:
    """``out/summary.json``, or ``out/summary-N.json`` (N = 2, 3, ...) when earlier captures left theirs."""
    first = out / "summary.json"
    if not first.exists():
        return first
    n = 2
    while (out / f"summary-{n}.json").exists():
        n += 1
    return out / f"summary-{n}.json"


def write_summary(summary: dict[str, Any], out: Path) -> Path | None:
    """Write a capture's summary where it can go; record where in ``summary_file``.

    Tried in order: the output folder (``summary.json``, or ``summary-N.json``
    beside an earlier capture's), the temporary folder (``$TMPDIR``), the
    current folder (``polcam-capture-summary-<time>-<pid>.json``).  The reason
    the output folder refused it goes to ``summary_error``.

    Returns
    -------
    pathlib.Path or None
        The file written, or ``None`` when no place took it (the caller
        prints the counts).
    """
    stamp = f"polcam-capture-summary-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}.json"
    targets = [_summary_target(Path(out)), Path(tempfile.gettempdir()) / stamp, Path.cwd() / stamp]
    for target in targets:
        summary["summary_file"] = str(target)
        try:
            with atomic_write(target, "w") as fh:
                json.dump(summary, fh, indent=2, default=str)
                fh.write("\n")
        except (PolcamError, OSError) as exc:
            if summary.get("summary_error") is None:
                summary["summary_error"] = f"cannot write {target}: {os_reason(exc)}"
            continue
        return target
    summary["summary_file"] = None
    return None
