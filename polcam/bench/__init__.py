"""Benchmarks of polcam's stages against ground truth and against other tools.

One module per benchmark, each runnable as ``python -m polcam.bench.<name>`` and
reported in docs/benchmarks.md; for example :mod:`polcam.bench.demosaic`
(demosaicing quality and speed, polcam's methods and polanalyser, on real and
synthetic full-resolution polarization stacks).
"""

from __future__ import annotations
