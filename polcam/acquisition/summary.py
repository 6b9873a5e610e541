"""A capture's summary: what it holds (:func:`summarize`) and where it goes (:func:`write_summary`:
``OUT/summary.json``, else the temporary or the current folder)."""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from polcam.acquisition.saving import os_reason
from polcam.errors import PolcamError
from polcam.io.atomic import atomic_write

if TYPE_CHECKING:
    from polcam.acquisition.run import Capture

__all__ = ["summarize", "write_summary"]


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


def summarize(capture: Capture) -> dict[str, Any]:
    """The summary of a capture that ran (:meth:`polcam.acquisition.run.Capture.summary`).

    Keys and their meaning: :func:`polcam.acquisition.run.run_capture`, docs/guide/faults.md.
    """
    st = capture.camera.stats()
    elapsed = max(capture.t_end - capture.t_start, 1e-9)
    live, saver, opts = capture.live, capture.saver, capture.options
    error = capture.error
    if live is not None and live.error is not None:
        error = f"live processing failed: {live.error}"
    return {
        "camera": capture.camera.info,
        "stop_reason": capture.reason,
        "error": error,
        "frames_good": st.good,
        "frames_incomplete": st.incomplete,
        "frames_dropped": st.dropped,
        "frames_received": capture.received,
        "frames_saved": len(saver.saved) if saver else 0,
        "frames_save_failed": len(saver.failed) if saver else 0,
        "frames_unsaved": saver.unsaved if saver else 0,
        "frames_left_at_stop": st.left_at_stop,
        "frames_processed": live.processed if live else 0,
        "frames_skipped": live.skipped if live else 0,
        "separation": capture.separate,
        "separation_options": dict(capture.separate_options),
        "separation_illuminant_held": live.held_illuminant if live else None,
        "separations": live.separations if live else 0,
        "separations_skipped": live.separations_skipped if live else 0,
        "separation_seconds_mean": (float(np.mean(live.separation_seconds))
                                    if live and live.separation_seconds else None),
        "separation_errors": list(live.separation_errors) if live else [],
        "separation_abandoned": live.separation_abandoned if live else False,
        "duration_s": elapsed,
        "fps": capture.received / elapsed,
        "fps_processed": (live.processed / elapsed) if live else 0.0,
        # the two live rates over the capture: maps computed (and logged), frames separated
        "maps_frames": live.processed if live else 0,
        "maps_fps": (live.processed / elapsed) if live else 0.0,
        "layers_frames": live.separations if live else 0,
        "layers_fps": (live.separations / elapsed) if live else 0.0,
        "live_seconds_per_frame": (live.seconds / live.processed) if live and live.processed else None,
        "save_seconds_per_frame": (saver.seconds / len(saver.saved)) if saver and saver.saved else None,
        "by_status": st.by_status,
        "queue_overflow": st.queue_overflow,
        "on_write_error": opts.on_write_error,
        "write_error": saver.write_error if saver else None,
        # seconds from the first failed write to the end of acquisition
        "write_error_to_stop_s": (max(0.0, capture.t_end - saver.failed_at)
                                  if saver is not None and saver.failed_at is not None else None),
        "stream": st.stream,
        "format": opts.save_format if saver else None,
        "out": None if capture.out is None else str(capture.out),
        "rerun": None if opts.rerun is None else str(opts.rerun),
        "stale_temporaries_removed": capture.stale,
        "calibration": capture.cal_file,
        "calibration_sha256": capture.cal_sha,
        "calibration_stages": capture.calibration.applied_stages if capture.calibration is not None else None,
        "save_errors": saver.failed if saver else [],
        "files": sorted(saver.saved) if saver else [],
        "summary_file": None,
        "summary_error": None,
    }
