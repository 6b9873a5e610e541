"""A synthetic imperfect polarization sensor, for tests and benchmarks of the calibration.

Each pixel follows the forward model of :mod:`polcam.calibration.model` with
its own gain, diattenuation and orientation, plus a dark offset, and hot pixels
with dark current; frames get shot noise (Poisson, ``full_well`` electrons at
normalised value 1), dark-current shot noise, Gaussian read noise (electrons),
quantisation to ``bit_depth`` bits and clipping to the counts range::

    electrons = Poisson(full_well * v + hot_e) + Normal(0, read_noise)
    counts    = round(offset + electrons * span / full_well),  span = white - black

with ``v = g/2 (S0 + D (S1 cos 2theta + S2 sin 2theta))`` the normalised signal.
The true dark level of a pixel is ``offset + hot_e * span / full_well``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from polcam.calibration.model import extinction_to_diattenuation, forward, nominal_orientation
from polcam.errors import PolcamError
from polcam.frame import Frame
from polcam.mosaic import Layout, parse_layout

__all__ = ["ImperfectSensor"]


@dataclass
class ImperfectSensor:
    """A polarization sensor with planted per-pixel imperfections.

    Attributes
    ----------
    layout
        Sensor layout.
    gain, diattenuation, orientation_deg
        (H, W) true polarizer model of every pixel (orientation in degrees).
    offset
        (H, W) dark offset in counts (black level and fixed-pattern offset).
    hot_electrons
        (H, W) dark-current electrons per frame (0 except on hot pixels).
    bit_depth, black_level
        Counts range and the black level the camera *reports* (what an
        uncalibrated pipeline subtracts).
    full_well
        Electrons at normalised signal 1.
    read_noise
        Read noise, electrons RMS.
    metadata
        Sidecar values every frame gets (camera_id, exposure_us, gain_db).
    """

    layout: Layout
    gain: np.ndarray
    diattenuation: np.ndarray
    orientation_deg: np.ndarray
    offset: np.ndarray
    hot_electrons: np.ndarray
    bit_depth: int = 12
    black_level: float = 64.0
    full_well: float = 20000.0
    read_noise: float = 4.0
    metadata: dict[str, Any] = field(default_factory=lambda: {
        "camera_id": "synthetic-imx250", "exposure_us": 10000.0, "gain_db": 0.0})

    def __post_init__(self) -> None:
        self.layout = parse_layout(self.layout)
        shape = np.shape(self.gain)
        for name in ("diattenuation", "orientation_deg", "offset", "hot_electrons"):
            if np.shape(getattr(self, name)) != shape:
                raise PolcamError(f"ImperfectSensor: {name} of shape {np.shape(getattr(self, name))}: "
                                  f"expected {shape} like gain")

    # ------------------------------------------------------------- building
    @classmethod
    def random(cls, layout: str | Layout, height: int, width: int, *, seed: int = 0,
               gain_spread: float = 0.05, extinction_range: tuple[float, float] = (50.0, 300.0),
               class_offsets_deg: tuple[float, float, float, float] = (1.5, -2.0, 2.5, -1.0),
               orientation_spread_deg: float = 1.0, offset_spread: float = 3.0,
               hot_fraction: float = 0.003, hot_counts: tuple[float, float] = (80.0, 800.0),
               **kwargs: Any) -> ImperfectSensor:
        """A sensor with random imperfections.

        Parameters
        ----------
        layout, height, width
            Layout and size (even).
        seed
            Seed of the random maps.
        gain_spread
            Relative standard deviation of the per-pixel gain (Gaussian, mean 1).
        extinction_range
            Extinction ratios drawn uniformly from this range;
            ``D = (ER - 1) / (ER + 1)``.
        class_offsets_deg
            Mean orientation error of the 0, 45, 90 and 135-degree pixels.
        orientation_spread_deg
            Per-pixel orientation scatter (Gaussian) around the class offset.
        offset_spread
            Standard deviation of the fixed-pattern dark offset, counts
            (around the black level).
        hot_fraction
            Share of hot pixels.
        hot_counts
            Range of their extra dark level, counts (uniform).
        **kwargs
            Other fields (``bit_depth``, ``black_level``, ``full_well``,
            ``read_noise``, ``metadata``).
        """
        lay = parse_layout(layout)
        rng = np.random.default_rng(seed)
        shape = (height, width)
        gain = 1.0 + gain_spread * rng.standard_normal(shape)
        er = rng.uniform(*extinction_range, size=shape)
        dia = extinction_to_diattenuation(er)
        nominal = nominal_orientation(lay, height, width)
        cls_off = np.asarray(class_offsets_deg, dtype=np.float64)[lay.angle_index(height, width)]
        theta = np.mod(nominal + cls_off + orientation_spread_deg * rng.standard_normal(shape), 180.0)
        black = float(kwargs.get("black_level", 64.0))
        offset = black + offset_spread * rng.standard_normal(shape)
        full_well = float(kwargs.get("full_well", 20000.0))
        bits = int(kwargs.get("bit_depth", 12))
        span = (2**bits - 1) - black
        hot = rng.random(shape) < hot_fraction
        hot_e = np.where(hot, rng.uniform(*hot_counts, size=shape) * full_well / span, 0.0)
        return cls(lay, gain, dia, theta, offset, hot_e, **kwargs)

    # ------------------------------------------------------------ properties
    @property
    def shape(self) -> tuple[int, int]:
        """(H, W)."""
        return tuple(np.shape(self.gain))  # type: ignore[return-value]

    @property
    def white_level(self) -> float:
        """Saturation counts, ``2**bit_depth - 1``."""
        return float(2**self.bit_depth - 1)

    @property
    def span(self) -> float:
        """Counts from the reported black level to white."""
        return self.white_level - self.black_level

    @property
    def dark(self) -> np.ndarray:
        """(H, W) true mean dark level, counts."""
        return self.offset + self.hot_electrons * self.span / self.full_well

    @property
    def hot(self) -> np.ndarray:
        """(H, W) bool: pixels with dark current."""
        return self.hot_electrons > 0

    def ideal(self) -> ImperfectSensor:
        """The same sensor without imperfections (gain 1, D 1, nominal angles, uniform dark, no hot pixels)."""
        h, w = self.shape
        return ImperfectSensor(self.layout, np.ones(self.shape), np.ones(self.shape),
                               nominal_orientation(self.layout, h, w), np.full(self.shape, self.black_level),
                               np.zeros(self.shape), bit_depth=self.bit_depth, black_level=self.black_level,
                               full_well=self.full_well, read_noise=self.read_noise, metadata=dict(self.metadata))

    # --------------------------------------------------------------- frames
    def signal(self, stokes: tuple[Any, Any, Any]) -> np.ndarray:
        """Noise-free normalised signal ``v`` of every pixel (H, W), float64.

        Parameters
        ----------
        stokes
            (S0, S1, S2): scalars, (H, W) maps, or (H, W, 3) RGB maps (each
            pixel reads the channel of its colour filter).
        """
        h, w = self.shape
        parts = []
        for s in stokes:
            a = np.asarray(s, dtype=np.float64)
            if a.ndim == 3:
                if a.shape != (h, w, 3):
                    raise PolcamError(f"Stokes map of shape {a.shape}: expected ({h}, {w}, 3) or ({h}, {w})")
                yy, xx = np.indices((h, w))
                a = a[yy, xx, self.layout.channel_index(h, w)]
            parts.append(np.broadcast_to(a, (h, w)))
        return forward(tuple(parts), self.gain, self.diattenuation, self.orientation_deg)

    def expose(self, stokes: tuple[Any, Any, Any], *, n: int = 1,
               rng: np.random.Generator | int | None = None) -> np.ndarray:
        """``n`` noisy frames of counts.

        Parameters
        ----------
        stokes
            Incident (S0, S1, S2) in normalised units (see :meth:`signal`).
        n
            Number of frames.
        rng
            Generator or seed of the noise.

        Returns
        -------
        numpy.ndarray
            (n, H, W) uint16 counts in [0, 2**bit_depth - 1].
        """
        gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        v = np.maximum(self.signal(stokes), 0.0)
        lam = v * self.full_well + self.hot_electrons
        out = np.empty((n,) + self.shape, dtype=np.uint16)
        scale = self.span / self.full_well
        for i in range(n):
            e = gen.poisson(lam).astype(np.float64)
            if self.read_noise > 0:
                e += gen.normal(0.0, self.read_noise, size=self.shape)
            counts = np.rint(self.offset + e * scale)
            out[i] = np.clip(counts, 0, self.white_level).astype(np.uint16)
        return out

    def frame(self, counts: np.ndarray, **metadata: Any) -> Frame:
        """Wrap counts (H, W) as a :class:`Frame` with this sensor's layout, levels and metadata."""
        meta = dict(self.metadata)
        meta.update(metadata)
        return Frame(np.asarray(counts), layout=self.layout, bit_depth=self.bit_depth,
                     black_level=self.black_level, white_level=self.white_level, metadata=meta)

    def frames(self, stokes: tuple[Any, Any, Any], *, n: int = 1,
               rng: np.random.Generator | int | None = None, **metadata: Any) -> list[Frame]:
        """``n`` noisy frames as :class:`Frame` objects (see :meth:`expose`)."""
        return [self.frame(c, **metadata) for c in self.expose(stokes, n=n, rng=rng)]
