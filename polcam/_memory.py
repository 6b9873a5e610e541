"""Memory of this process and of the machine: per-frame peaks and the worker count they allow.

* :func:`reset_peak` / :func:`peak_rss_mb`: the largest resident set size
  (RSS) of this process since the last reset.  On Linux the kernel's
  high-water mark ``VmHWM`` is reset by writing ``5`` to
  ``/proc/self/clear_refs``, so each frame of a worker gets its own peak;
  where that is refused the figure is the process's lifetime peak
  (``resource.getrusage``), an upper bound.  RSS counts the interpreter and
  libraries (about 150-250 MB) and pages shared with the fork server in full.
* :func:`available_mb`: the memory the machine can give without swapping
  (``MemAvailable`` of ``/proc/meminfo``; psutil where that file is missing
  and psutil is installed).
* :func:`workers_for_memory`: how many workers of a given peak fit in it.
"""

from __future__ import annotations

import math
import resource
import sys

from polcam.separation import default_method

__all__ = ["METHOD_PEAK_MB", "auto_workers", "available_mb", "peak_rss_mb", "reset_peak", "worker_peak_mb",
           "workers_for_memory"]

#: Peak RSS of one ``polcam process`` worker (MB) for a 2448 x 2048 colour frame at the default
#: cell resolution, per method, as measured (docs/benchmarks.md, "Speed: maps and separation");
#: methods not listed use :data:`_OTHER_PEAK_MB`.
METHOD_PEAK_MB: dict[str, float] = {
    "imin": 550.0, "wen21": 849.0, "yang10": 971.0, "polarized-residual": 1355.0,
    "tensor": 1276.0, "tensor-tau": 1276.0, "tensor-plain": 1276.0,
}
_OTHER_PEAK_MB = 1400.0
#: The share of the available memory the workers may take together.
_USABLE = 0.8


def reset_peak() -> bool:
    """Restart this process's peak-RSS count (Linux); False where the kernel does not allow it."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        return False
    return True


def _proc_mb(path: str, key: str) -> float | None:
    """The ``key:`` line of a Linux /proc file (in kB) as MB; None where it cannot be read."""
    try:
        with open(path) as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def peak_rss_mb() -> float:
    """Largest RSS of this process since :func:`reset_peak` (else since it started), MB."""
    hwm = _proc_mb("/proc/self/status", "VmHWM")
    if hwm is not None:
        return hwm
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0  # bytes on macOS, KiB elsewhere


def available_mb() -> float | None:
    """Memory available to new work without swapping, MB (None where it cannot be read)."""
    avail = _proc_mb("/proc/meminfo", "MemAvailable")
    if avail is not None:
        return avail
    try:
        import psutil
    except ImportError:
        return None
    return float(psutil.virtual_memory().available) / 2**20


def worker_peak_mb(method: str, pixels: int = 2448 * 2048) -> float:
    """Expected peak RSS of a worker separating colour frames of ``pixels`` (sensor pixels) by ``method``:
    the measured 5 MP figure, scaled by the pixel count above 5 MP (never below it)."""
    base = METHOD_PEAK_MB.get(method, _OTHER_PEAK_MB)
    return base * max(1.0, pixels / (2448 * 2048))


def workers_for_memory(per_worker_mb: float, cores: int, *, available: float | None = None) -> int:
    """Workers to start: at most ``cores``, and no more than fit in 80 % of the available memory
    (at least 1).  ``available`` None: :func:`available_mb` (cores alone where it is unknown)."""
    avail = available_mb() if available is None else available
    if avail is None or not per_worker_mb > 0:
        return max(1, cores)
    return max(1, min(cores, math.floor(_USABLE * avail / per_worker_mb)))


def auto_workers(method: str | None, resolution: str, cores: int, *, available: float | None = None) -> int:
    """``polcam process``'s worker count when none is given: the cores, no more than the workers
    whose expected peak (:func:`worker_peak_mb` of ``method``, None: the colour default, for a
    2448 x 2048 frame; four times the pixels at full resolution) fits in the available memory."""
    if method is None:
        method = default_method("stack")
    pixels = 2448 * 2048 * (4 if resolution == "full" else 1)
    return workers_for_memory(worker_peak_mb(method, pixels), cores, available=available)
