"""The Rerun live view of a capture (rerun-sdk 0.41).

Entity paths (DESIGN.md section 3):

=============================== ==================================================
``/camera/raw``                 the raw mosaic, full resolution, 8-bit (its top 8
                                significant bits); every ``raw_every``-th frame
``/polarization/s0``            S0 / 2 (= Ic, the mean over the four angles), 8-bit
                                grey (mono) or RGB (colour), linear, [0, 1] -> 0..255
``/polarization/dolp``          DoLP in [0, 1] as a colour-mapped class image: class
                                ``1 + round(254 DoLP)``, coloured by viridis
``/polarization/aolp``          AoLP as hue (HSV, full saturation and value) through a
                                class image: class ``1 + round(AoLP in degrees) mod 180``,
                                hue ``2 x`` AoLP, so 0 and 180 degrees meet
``/layers/diffuse``             diffuse layer, 8-bit like S0 / 2
``/layers/specular``            specular layer, 8-bit on the same scale
``/stats/fps``                  frames per second received from the camera
``/stats/dropped``              frames dropped so far (camera and queues)
``/stats/incomplete``           incomplete frames so far
``/stats/separation_seconds``   seconds the last separation took
=============================== ==================================================

Timelines: ``frame`` (a sequence: the capture's frame index) and ``device_time``
(a duration: the camera's timestamp in ns; GigE Vision cameras count from
power-up, so it is logged as a duration, not a date).

Compact logging: every image goes out as 8-bit, one byte per value.  DoLP
and AoLP are ``SegmentationImage`` class maps (one byte a pixel) whose colour
maps are logged once as static ``AnnotationContext`` palettes (the viewer
colours them; hovering shows the value as the class label).  Maps are
downscaled by ``view_scale`` (default 0.5: 612 x 512 for the 1224 x 1024
polarizer-cell maps of a 5 MP sensor, by pixel-area averaging; AoLP by
nearest neighbour so orientations never average across the 0/180 wrap), and
the full-resolution raw mosaic goes out every ``raw_every``-th frame only.
A 5 MP mono frame costs about 2 MB of log data (colour about 3.5 MB) instead
of the ~60 MB of its float32 maps.

Targets: a ``.rrd`` file (written by Rerun's own thread), ``spawn`` (starts a
viewer; needs a display) or ``serve`` (a gRPC server plus the web viewer on
this machine, no display needed).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np

__all__ = [
    "AOLP_LEVELS",
    "DOLP_LEVELS",
    "ENTITIES",
    "RerunSink",
    "aolp_ids",
    "blueprint",
    "dolp_ids",
    "mosaic_u8",
    "palettes",
    "unit_u8",
]

#: Entity paths the sink logs, by role.
ENTITIES: dict[str, str] = {
    "raw": "/camera/raw",
    "s0": "/polarization/s0",
    "dolp": "/polarization/dolp",
    "aolp": "/polarization/aolp",
    "diffuse": "/layers/diffuse",
    "specular": "/layers/specular",
    "fps": "/stats/fps",
    "dropped": "/stats/dropped",
    "incomplete": "/stats/incomplete",
    "separation_seconds": "/stats/separation_seconds",
}

_STATS = ("fps", "dropped", "incomplete", "separation_seconds")


def _viridis_rgb() -> np.ndarray:
    ramp = np.arange(256, dtype=np.uint8).reshape(256, 1)
    return cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)[:, 0, ::-1].copy()  # (256, 3) RGB


def _hue_rgb(n: int) -> np.ndarray:
    """RGB of n hues evenly spaced around the HSV circle, full saturation and value."""
    hue = np.round(np.arange(n) * 180.0 / n).astype(np.uint8).reshape(n, 1)
    full = np.full_like(hue, 255)
    return cv2.cvtColor(cv2.merge([hue, full, full]), cv2.COLOR_HSV2RGB)[:, 0, :].copy()


def unit_u8(img: np.ndarray, *, scale: float = 1.0) -> np.ndarray:
    """``round(clip(img * scale, 0, 1) * 255)`` as uint8.

    Parameters
    ----------
    img
        (H, W) or (H, W, 3) float32, or uint16 fixed-point values.
    scale
        Factor applied first (e.g. 0.5 to show S0 as Ic, 1/16384 for
        fixed-point maps).

    Returns
    -------
    numpy.ndarray
        uint8 of the same shape (OpenCV's saturating conversion).
    """
    a = np.ascontiguousarray(img)
    if a.dtype == np.uint8 and abs(255.0 * float(scale) - 1.0) < 1e-9:
        return a  # already 8-bit display values
    if a.dtype not in (np.uint8, np.uint16, np.float32):
        a = a.astype(np.float32)
    return cv2.addWeighted(a, 255.0 * float(scale), a, 0.0, 0.0, dtype=cv2.CV_8U)


#: DoLP classes: DoLP d is class 1 + round(254 d); class 0 is not used.
DOLP_LEVELS = 255
#: AoLP classes: AoLP of a degrees is class 1 + round(a) mod 180.
AOLP_LEVELS = 180


def dolp_ids(dolp: np.ndarray) -> np.ndarray:
    """DoLP (H, W) in [0, 1] as class ids ``1 + round(254 DoLP)`` (uint8, 1..255)."""
    a = np.ascontiguousarray(dolp, dtype=np.float32)
    return cv2.addWeighted(a, DOLP_LEVELS - 1.0, a, 0.0, 1.0, dtype=cv2.CV_8U)


def aolp_ids(aolp: np.ndarray) -> np.ndarray:
    """AoLP (H, W) in radians, [0, pi), as class ids ``1 + round(degrees) mod 180`` (uint8, 1..180)."""
    a = np.ascontiguousarray(aolp, dtype=np.float32)
    deg = cv2.addWeighted(a, 180.0 / np.pi, a, 0.0, 0.0, dtype=cv2.CV_8U)  # 0..180
    deg = cv2.threshold(deg, AOLP_LEVELS - 1, 0, cv2.THRESH_TOZERO_INV)[1]  # 180 is 0
    return cv2.add(deg, 1)


def palettes() -> dict[str, list[tuple[int, str, tuple[int, int, int]]]]:
    """(class id, label, RGB colour) of the DoLP and AoLP class maps."""
    vir = _viridis_rgb()
    hues = _hue_rgb(AOLP_LEVELS)
    dolp = [(i + 1, f"DoLP {i / (DOLP_LEVELS - 1):.3f}",
             tuple(int(c) for c in vir[round(i * 255 / (DOLP_LEVELS - 1))])) for i in range(DOLP_LEVELS)]
    aolp = [(i + 1, f"AoLP {i} deg", tuple(int(c) for c in hues[i])) for i in range(AOLP_LEVELS)]
    return {"dolp": dolp, "aolp": aolp}  # type: ignore[dict-item]


def _resize(img: np.ndarray, scale: float, *, nearest: bool = False) -> np.ndarray:
    if scale == 1.0:
        return img
    h, w = img.shape[:2]
    size = (max(1, int(round(w * scale))), max(1, int(round(h * scale))))
    return cv2.resize(img, size, interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def mosaic_u8(mosaic: np.ndarray, *, bit_depth: int) -> np.ndarray:
    """The top 8 significant bits of a raw mosaic, uint8 (H, W)."""
    if mosaic.dtype == np.uint8 or bit_depth <= 8:
        return np.ascontiguousarray(mosaic, dtype=np.uint8)
    return cv2.convertScaleAbs(np.ascontiguousarray(mosaic), alpha=1.0 / (1 << (int(bit_depth) - 8)))


def blueprint() -> Any:
    """The layout of the live view: images on two rows, the statistics plot beside the layers."""
    import rerun.blueprint as rrb

    def view(role: str, name: str) -> Any:
        return rrb.Spatial2DView(origin=ENTITIES[role], name=name)

    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(view("raw", "raw"), view("s0", "S0"), view("dolp", "DoLP"), view("aolp", "AoLP")),
            rrb.Horizontal(view("diffuse", "diffuse"), view("specular", "specular"),
                           rrb.TimeSeriesView(origin="/stats", name="statistics")),
        ),
        collapse_panels=True,
    )


class RerunSink:
    """Log a capture to Rerun.

    Parameters
    ----------
    target
        ``"spawn"`` (start a native viewer), ``"serve"`` (gRPC server + web
        viewer), or a file path ending in ``.rrd``.
    application_id
        Rerun application id.
    recording_id
        Rerun recording id (default: a fresh one).
    raw_every
        Log the full-resolution raw mosaic every this many :meth:`log_raw`
        calls (1: every time).
    view_scale
        Size factor of the logged maps (0 < view_scale <= 1).
    open_browser
        ``serve``: open a browser on the web viewer.

    Notes
    -----
    Logging calls may come from several threads; each group of
    ``set_time`` + ``log`` calls is made under a lock, so frames never get
    each other's time stamps.
    """

    def __init__(self, target: str | Path, *, application_id: str = "polcam",
                 recording_id: str | None = None, raw_every: int = 10, view_scale: float = 0.5,
                 open_browser: bool = False) -> None:
        import rerun as rr

        if int(raw_every) < 1:
            raise ValueError(f"raw_every {raw_every!r}: expected a positive integer")
        if not 0 < float(view_scale) <= 1:
            raise ValueError(f"view_scale {view_scale!r}: expected a number in (0, 1]")
        self.view_scale = float(view_scale)
        self._rr = rr
        self.raw_every = int(raw_every)
        self._raw_calls = 0
        self._lock = threading.Lock()
        self.target = str(target)
        self.url: str | None = None
        rec = rr.RecordingStream(application_id, recording_id=recording_id)
        bp = blueprint()
        if self.target == "spawn":
            rec.spawn(default_blueprint=bp)
        elif self.target == "serve":
            self.url = rec.serve_grpc(default_blueprint=bp)
            rr.serve_web_viewer(connect_to=self.url, open_browser=open_browser)
        else:
            path = Path(self.target)
            if path.suffix.lower() != ".rrd":
                raise ValueError(
                    f"Rerun target {self.target!r}: expected 'spawn', 'serve' or a file ending in .rrd"
                )
            path.parent.mkdir(parents=True, exist_ok=True)
            rec.save(path, default_blueprint=bp)
        self._rec = rec
        self.logged: dict[str, int] = {role: 0 for role in ENTITIES}
        for role, pal in palettes().items():
            rec.log(ENTITIES[role], rr.AnnotationContext(pal), static=True)

    def _time(self, index: int, timestamp_ns: int | None) -> None:
        self._rec.set_time("frame", sequence=int(index))
        if timestamp_ns is not None:
            self._rec.set_time("device_time", duration=np.timedelta64(int(timestamp_ns), "ns"))

    def _image(self, role: str, img: np.ndarray) -> None:
        self._rec.log(ENTITIES[role], self._rr.Image(img))
        self.logged[role] += 1

    def log_raw(self, index: int, timestamp_ns: int | None, mosaic: np.ndarray, *, bit_depth: int) -> bool:
        """Log the raw mosaic (every ``raw_every``-th call); returns True when it was logged."""
        with self._lock:
            call = self._raw_calls
            self._raw_calls += 1
        if call % self.raw_every:
            return False
        img = mosaic_u8(mosaic, bit_depth=bit_depth)
        with self._lock:
            self._time(index, timestamp_ns)
            self._image("raw", img)
        return True

    def log_polarization(self, index: int, timestamp_ns: int | None, *, ic: np.ndarray,
                         dolp: np.ndarray, aolp: np.ndarray, scale: float = 1.0) -> None:
        """Log S0, DoLP and AoLP as 8-bit images.

        ``ic * scale`` is Ic = S0 / 2 normalised by the white level ([0, 1]),
        logged at ``/polarization/s0``; ``dolp`` in [0, 1]; ``aolp`` in
        radians, [0, pi).
        """
        v = self.view_scale
        s0_img = _resize(unit_u8(ic, scale=scale), v)
        dolp_img = _resize(dolp_ids(dolp), v)
        aolp_img = _resize(aolp_ids(aolp), v, nearest=True)
        with self._lock:
            self._time(index, timestamp_ns)
            self._image("s0", s0_img)
            for role, ids in (("dolp", dolp_img), ("aolp", aolp_img)):
                self._rec.log(ENTITIES[role], self._rr.SegmentationImage(ids, opacity=1.0))
                self.logged[role] += 1

    def log_layers(self, index: int, timestamp_ns: int | None, *, diffuse: np.ndarray,
                   specular: np.ndarray, scale: float = 1.0) -> None:
        """Log the diffuse and specular layers (``value * scale`` on the scale of one
        polarization image, [0, 1] shown as 0..255)."""
        v = self.view_scale
        imgs = (_resize(unit_u8(diffuse, scale=scale), v), _resize(unit_u8(specular, scale=scale), v))
        with self._lock:
            self._time(index, timestamp_ns)
            self._image("diffuse", imgs[0])
            self._image("specular", imgs[1])

    def log_stats(self, index: int, timestamp_ns: int | None, **values: float | None) -> None:
        """Log scalars among ``fps``, ``dropped``, ``incomplete``, ``separation_seconds``."""
        unknown = set(values) - set(_STATS)
        if unknown:
            raise ValueError(f"unknown statistics {sorted(unknown)}; expected some of {', '.join(_STATS)}")
        with self._lock:
            self._time(index, timestamp_ns)
            for name, value in values.items():
                if value is None:
                    continue
                self._rec.log(ENTITIES[name], self._rr.Scalars(float(value)))
                self.logged[name] += 1

    def close(self) -> None:
        """Flush everything to the target and disconnect."""
        with self._lock:
            self._rec.flush()
            if self.target not in ("spawn", "serve"):
                self._rec.disconnect()
