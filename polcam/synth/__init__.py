"""Synthetic polarization data with ground truth.

:mod:`polcam.synth.patterns` builds full-resolution test patterns (smooth and
textured albedo, sharp edges, the whole range of DoLP and AoLP; mono and RGB)
for the demosaicing benchmark and the tests; its scene names are
``polcam.synth.patterns.SCENES``.  The mesh renderer lives beside it in its own
modules.
"""

from __future__ import annotations

from polcam.synth.patterns import (
    PolarizationScene,
    make_scene,
    stack_from_stokes,
    uniform_scene,
)

__all__ = ["PolarizationScene", "make_scene", "stack_from_stokes", "uniform_scene"]
