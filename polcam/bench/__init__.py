"""Benchmarks of polcam's stages against ground truth and against other tools.

One module per benchmark, each run by ``polcam bench <name>`` (:mod:`polcam.commands.bench`) and
reported in docs/benchmarks.md; for example :mod:`polcam.bench.demosaic`
(demosaicing quality and speed, polcam's methods and polanalyser, on real and
synthetic full-resolution polarization stacks).  The tooling that made or chose what
the library ships lives here too: :mod:`polcam.bench.lmmse_training` (the ``lmmse``
weights), :mod:`polcam.bench.demosaic_validation` (their settings) and
:mod:`polcam.bench.default_rule` (the default separation method per input form).
"""

from __future__ import annotations
