"""The Rerun view of polcam's data (rerun-sdk 0.41): one sink for capture, process and view.

Every writer (``polcam capture --rerun``, ``polcam process --rerun``,
``polcam view``) logs through :class:`RerunSink`, so each entity path has one
meaning whoever wrote it:

=============================== ==================================================
``/camera/raw``                 the raw mosaic, full resolution, 8-bit (its top 8
                                significant bits); every ``raw_every``-th frame
``/polarization/s0``            S0 = (I0 + I45 + I90 + I135) / 2 (the full S0, never
                                S0 / 2) on a fixed 8-bit scale: value
                                ``round(255 S0 / 2)``, so 255 is S0 = 2 (every
                                polarizer image at white); grey (mono) or RGB
``/polarization/dolp``          DoLP in [0, 1] as a colour-mapped class image: class
                                ``1 + round(254 DoLP)``, coloured by viridis; colour:
                                of the luminance-weighted Stokes vector (R + 2G + B) / 4;
                                class 0 (black) where S0 is too dark to have one
                                (its code below ``DARK_CODE``, S0 < ~0.02)
``/polarization/aolp``          AoLP as hue (HSV, full saturation and value) through a
                                class image: class ``1 + round(AoLP in degrees) mod 180``,
                                hue ``2 x`` AoLP, so 0 and 180 degrees meet (cyclic);
                                class 0 where dark, as DoLP
``/polarization/aolp_dolp``     AoLP as hue with DoLP as value (HSV: hue ``2 x``
                                AoLP, full saturation, value
                                ``min(1, DoLP / 0.25)`` in 32 steps) through a uint16
                                class image: class ``1 + round(AoLP in degrees)
                                mod 180 + 180 level``; class 0 where dark
``/layers/diffuse``             diffuse layer, on the scale of one polarization image:
                                value ``round(255 diffuse)``
``/layers/specular``            specular layer, on the same scale
``/stats/fps``                  frames per second received from the camera
``/stats/dropped``              frames dropped so far (camera and queues)
``/stats/incomplete``           incomplete frames so far
``/stats/separation_seconds``   seconds the last separation took
``/stats/maps_fps``             frames whose maps (S0, DoLP, AoLP) were computed and
                                logged, per second (over the last 5 s)
``/stats/layers_fps``           frames separated into layers, per second (over the
                                last 5 s)
=============================== ==================================================

Timelines: ``frame`` (a sequence: the capture's frame index, or the frame's
position in a batch) and ``device_time`` (a duration: the camera's timestamp
in ns; GigE Vision cameras count from power-up, so it is logged as a
duration, not a date).

Why 8 bits: Rerun shows a float image on a range it guesses from the values
(0..1 when they lie there, else 0..255), so S0 (up to 2) or AoLP in radians
(up to pi) logged as floats come out black.  Fixed 8-bit codes show the same
way in every viewer and cost one byte a value.  DoLP and AoLP are
``SegmentationImage`` class maps whose colour maps are logged once as static
``AnnotationContext`` palettes (hovering shows the value as the class label).
Maps can be downscaled by ``view_scale`` (capture's default 0.5, by
pixel-area averaging; AoLP by nearest neighbour so orientations never average
across the 0/180 wrap).

Targets: a ``.rrd`` file, ``spawn`` (starts the native viewer; needs a
display) or ``serve``: Rerun's web viewer and its data server (gRPC), run as
a child process of the Rerun command-line tool bound to ``bind`` (127.0.0.1
by default: Rerun's own default would be every interface), on ``port`` (the
web page) and ``port + 1`` (the data).  The server keeps the most recent
``memory_limit`` of data for viewers that connect later, and stops with the
sink (and with this process, even when it is killed).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from polcam.sinks.base import Record, SinkBase
from polcam.sinks.files import read_frame_folder
from polcam.sinks.rerun_web import LOOPBACK, WebServer, is_loopback, native_viewer

__all__ = [
    "AOLP_DOLP_FULL",
    "AOLP_DOLP_STEPS",
    "AOLP_LEVELS",
    "AOLP_TIE_BREAK",
    "DARK_CODE",
    "LOOPBACK",
    "LUMA_WEIGHTS",
    "TIE_BREAK",
    "WebServer",
    "DOLP_LEVELS",
    "ENTITIES",
    "RerunSink",
    "aolp_dolp_ids",
    "aolp_ids",
    "blueprint",
    "dolp_ids",
    "is_loopback",
    "luminance_orientation",
    "mosaic_u8",
    "s0_u8",
    "palettes",
    "unit_u8",
]

#: Entity paths the sink logs, by role.
ENTITIES: dict[str, str] = {
    "raw": "/camera/raw",
    "s0": "/polarization/s0",
    "dolp": "/polarization/dolp",
    "aolp": "/polarization/aolp",
    "aolp_dolp": "/polarization/aolp_dolp",
    "diffuse": "/layers/diffuse",
    "specular": "/layers/specular",
    "fps": "/stats/fps",
    "dropped": "/stats/dropped",
    "incomplete": "/stats/incomplete",
    "separation_seconds": "/stats/separation_seconds",
    "maps_fps": "/stats/maps_fps",
    "layers_fps": "/stats/layers_fps",
}

_STATS = ("fps", "dropped", "incomplete", "separation_seconds", "maps_fps", "layers_fps")


def _viridis_rgb() -> np.ndarray:
    ramp = np.arange(256, dtype=np.uint8).reshape(256, 1)
    return cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)[:, 0, ::-1].copy()  # (256, 3) RGB


def _hue_rgb(n: int) -> np.ndarray:
    """RGB of n hues evenly spaced around the HSV circle, full saturation and value."""
    hue = np.round(np.arange(n) * 180.0 / n).astype(np.uint8).reshape(n, 1)
    full = np.full_like(hue, 255)
    return cv2.cvtColor(cv2.merge([hue, full, full]), cv2.COLOR_HSV2RGB)[:, 0, :].copy()


#: Added before rounding to a code: exact halves (frequent with 8-bit sensors, whose sums of
#: four angles are whole numbers) round up whichever float32 rounding error came before, so
#: two computations of the same value give the same code.  Far below a code, far above
#: float32 noise (~2e-5 of a code at 255).
TIE_BREAK = 1.0 / 512.0
#: The same for AoLP in degrees, wider: the live path's OpenCV ``cartToPolar`` differs from
#: ``arctan2`` by up to ~0.005 degrees, and exact halves (22.5, 67.5, ...: S1 = +-S2) are frequent.
AOLP_TIE_BREAK = 1.0 / 64.0


def unit_u8(img: np.ndarray, *, scale: float = 1.0) -> np.ndarray:
    """``round(clip(img * scale, 0, 1) * 255)`` as uint8 (halves round up, :data:`TIE_BREAK`).

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
    return cv2.addWeighted(a, 255.0 * float(scale), a, 0.0, TIE_BREAK, dtype=cv2.CV_8U)


#: DoLP classes: DoLP d is class 1 + round(254 d); class 0 is not used.
DOLP_LEVELS = 255
#: AoLP classes: AoLP of a degrees is class 1 + round(a) mod 180.
AOLP_LEVELS = 180


def dolp_ids(dolp: np.ndarray) -> np.ndarray:
    """DoLP (H, W) in [0, 1] as class ids ``1 + round(254 DoLP)`` (uint8, 1..255)."""
    a = np.ascontiguousarray(dolp, dtype=np.float32)
    return cv2.addWeighted(a, DOLP_LEVELS - 1.0, a, 0.0, 1.0 + TIE_BREAK, dtype=cv2.CV_8U)


def aolp_ids(aolp: np.ndarray) -> np.ndarray:
    """AoLP (H, W) in radians, [0, pi), as class ids ``1 + round(degrees) mod 180`` (uint8, 1..180)."""
    a = np.ascontiguousarray(aolp, dtype=np.float32)
    deg = cv2.addWeighted(a, 180.0 / np.pi, a, 0.0, AOLP_TIE_BREAK, dtype=cv2.CV_8U)  # 0..180
    deg = cv2.threshold(deg, AOLP_LEVELS - 1, 0, cv2.THRESH_TOZERO_INV)[1]  # 180 is 0
    return cv2.add(deg, 1)


#: DoLP at which the AoLP x DoLP map reaches full value: diffuse surfaces polarize weakly (the real
#: fixture's median DoLP is 0.07), so value = DoLP itself would leave them near black.
AOLP_DOLP_FULL = 0.25
#: Value steps of the AoLP x DoLP map: value ``level / (AOLP_DOLP_STEPS - 1)``.
AOLP_DOLP_STEPS = 32


def aolp_dolp_ids(aolp: np.ndarray, dolp: np.ndarray) -> np.ndarray:
    """AoLP as hue, DoLP as value: class ids ``aolp_ids(aolp) + 180 level`` (uint16, 1..5760).

    Parameters
    ----------
    aolp
        (H, W) AoLP in radians, [0, pi).
    dolp
        (H, W) DoLP in [0, 1]; ``level = round(31 min(1, DoLP / AOLP_DOLP_FULL))``.
    """
    d = np.ascontiguousarray(dolp, dtype=np.float32)
    level = cv2.addWeighted(d, (AOLP_DOLP_STEPS - 1) / AOLP_DOLP_FULL, d, 0.0, TIE_BREAK, dtype=cv2.CV_8U)
    level = np.minimum(level, AOLP_DOLP_STEPS - 1).astype(np.uint16)
    return aolp_ids(aolp).astype(np.uint16) + np.uint16(AOLP_LEVELS) * level


def palettes() -> dict[str, list[tuple[int, str, tuple[int, int, int]]]]:
    """(class id, label, RGB colour) of the DoLP, AoLP and AoLP x DoLP class maps."""
    vir = _viridis_rgb()
    hues = _hue_rgb(AOLP_LEVELS)
    dolp = [(i + 1, f"DoLP {i / (DOLP_LEVELS - 1):.3f}",
             tuple(int(c) for c in vir[round(i * 255 / (DOLP_LEVELS - 1))])) for i in range(DOLP_LEVELS)]
    aolp = [(i + 1, f"AoLP {i} deg", tuple(int(c) for c in hues[i])) for i in range(AOLP_LEVELS)]
    top = AOLP_DOLP_STEPS - 1
    both = [(1 + i + AOLP_LEVELS * k,
             f"AoLP {i} deg, DoLP {'>= ' if k == top else ''}{k * AOLP_DOLP_FULL / top:.3f}",
             tuple(int(round(int(c) * k / top)) for c in hues[i]))
            for k in range(AOLP_DOLP_STEPS) for i in range(AOLP_LEVELS)]
    dark = (0, f"too dark (S0 code < {DARK_CODE})", (0, 0, 0))
    return {"dolp": [dark, *dolp], "aolp": [dark, *aolp], "aolp_dolp": [dark, *both]}  # type: ignore[dict-item]


#: DoLP and AoLP are not shown (class 0, black) where the S0 code is below this, i.e. S0 < 2.5 / 127.5
#: (about 1 % of white): there they are the orientation of noise, a speckle that hides the scene.
DARK_CODE = 3


def _lit(s0_code: np.ndarray) -> np.ndarray:
    """(H, W) uint8 mask: 255 where the S0 code (brightest channel) is at least :data:`DARK_CODE`, else 0."""
    level = s0_code
    if s0_code.ndim == 3:  # OpenCV per-channel maxima: numpy's max over a last axis of 3 is ~20x slower
        r, g, b = cv2.split(s0_code)
        level = cv2.max(cv2.max(r, g), b)
    return cv2.threshold(np.ascontiguousarray(level, dtype=np.uint8), DARK_CODE - 1, 255, cv2.THRESH_BINARY)[1]


def _mask_dark(ids: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """``ids`` (uint8 or uint16) with class 0 where ``lit`` (:func:`_lit`) is 0."""
    return cv2.bitwise_and(ids, ids, mask=lit)


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


def s0_u8(s0: np.ndarray, *, scale: float = 1.0) -> np.ndarray:
    """The 8-bit code of ``/polarization/s0``: ``round(255 * clip(S0 / 2, 0, 1))``, uint8.

    Parameters
    ----------
    s0
        (H, W) or (H, W, 3): ``s0 * scale`` is S0 = (I0 + I45 + I90 + I135) / 2
        of intensities normalised to [0, 1], so S0 is in [0, 2].
    scale
        Factor from the stored values to S0 (e.g. ``2 / 255`` for 8-bit Ic values).
    """
    return unit_u8(s0, scale=0.5 * float(scale))


#: Weights of the luminance-weighted Stokes vector of a colour stack, (R + 2 G + B) / 4.
LUMA_WEIGHTS = (0.25, 0.5, 0.25)


def luminance_orientation(s0: np.ndarray, dolp: np.ndarray, aolp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DoLP and AoLP of the luminance-weighted Stokes vector of per-channel colour maps.

    Parameters
    ----------
    s0, dolp, aolp
        (h, w, 3) per-channel S0, DoLP in [0, 1] and AoLP in radians [0, pi).

    Returns
    -------
    dolp, aolp : numpy.ndarray
        (h, w) float32 of ``sum_c w_c (S0, S1, S2)_c`` with weights
        :data:`LUMA_WEIGHTS` (the live colour view's definition), DoLP clipped
        to [0, 1] (0 where S0 is 0), AoLP in [0, pi).
    """
    w = np.asarray(LUMA_WEIGHTS, dtype=np.float64)
    s0 = np.asarray(s0, dtype=np.float64)
    mag = s0 * np.asarray(dolp, dtype=np.float64)
    two = 2.0 * np.asarray(aolp, dtype=np.float64)
    l0 = s0 @ w
    l1 = (mag * np.cos(two)) @ w
    l2 = (mag * np.sin(two)) @ w
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(l0 > 0, np.hypot(l1, l2) / l0, 0.0)
    a = np.mod(0.5 * np.arctan2(l2, l1), np.pi)
    a = np.where(a >= np.pi, 0.0, a)
    return np.clip(d, 0.0, 1.0).astype(np.float32), a.astype(np.float32)


def blueprint(*, live: bool = True) -> Any:
    """The one layout of capture, process and view.

    Raw, S0 and DoLP on the first row; AoLP, diffuse and specular on the
    second (all on the ``frame`` timeline), AoLP as two tabs: AoLP x DoLP
    (hue and value, shown first) and AoLP alone (hue).  With ``live`` (a
    capture), the capture statistics below them as time series: the rates
    (camera frames, maps and layers per second), dropped and incomplete
    frames, separation time; a batch or a folder has
    none, so it gets no empty plots.
    """
    import rerun.blueprint as rrb

    def view(role: str, name: str) -> Any:
        return rrb.Spatial2DView(origin=ENTITIES[role], name=name)

    def plot(roles: tuple[str, ...], name: str) -> Any:
        return rrb.TimeSeriesView(origin="/stats", contents=[ENTITIES[r] for r in roles], name=name)

    aolp = rrb.Tabs(view("aolp_dolp", "AoLP x DoLP (hue, value)"), view("aolp", "AoLP (hue, 0..180 deg)"),
                    active_tab=0, name="AoLP")
    rows = [rrb.Horizontal(view("raw", "raw"), view("s0", "S0"), view("dolp", "DoLP (viridis, 0..1)")),
            rrb.Horizontal(aolp, view("diffuse", "diffuse"), view("specular", "specular"))]
    if live:
        rows.append(rrb.Horizontal(plot(("fps", "maps_fps", "layers_fps"), "frames per second"),
                                   plot(("dropped", "incomplete"), "dropped, incomplete"),
                                   plot(("separation_seconds",), "separation seconds")))
    return rrb.Blueprint(
        rrb.Vertical(*rows, row_shares=[4, 4, 1.5][:len(rows)]),
        rrb.TimePanel(timeline="frame", state="collapsed"),
        collapse_panels=True,
    )


class RerunSink(SinkBase):
    """Log polcam's data to Rerun: the one writer of every entity path.

    Parameters
    ----------
    target
        ``"spawn"`` (start a native viewer), ``"serve"`` (web viewer, see
        :class:`WebServer`), or a file path ending in ``.rrd``.
    application_id
        Rerun application id (``polcam``: the blueprint applies to it).
    recording_id
        Rerun recording id (default: a fresh one).
    raw_every
        Log the full-resolution raw mosaic every this many :meth:`log_raw`
        calls (1: every time).
    view_scale
        Size factor of the logged maps (0 < view_scale <= 1).
    bind, port, memory_limit
        ``serve``: see :class:`WebServer`.
    live
        A live capture: the layout shows the capture statistics
        (:func:`blueprint`); False for a batch or a folder.

    Notes
    -----
    Logging calls may come from several threads; each group of
    ``set_time`` + ``log`` calls is made under a lock, so frames never get
    each other's time stamps.
    """

    def __init__(self, target: str | Path, *, application_id: str = "polcam",
                 recording_id: str | None = None, raw_every: int = 10, view_scale: float = 0.5,
                 bind: str = LOOPBACK, port: int = 9090, memory_limit: str = "1GiB", live: bool = True) -> None:
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
        self.server: WebServer | None = None
        rec = rr.RecordingStream(application_id, recording_id=recording_id)
        bp = blueprint(live=live)
        if self.target == "spawn":  # our own viewer process: the SDK's spawn listens on every interface

            rec.connect_grpc(native_viewer(bind=bind), default_blueprint=bp)
        elif self.target == "serve":
            self.server = WebServer(bind=bind, port=port, memory_limit=memory_limit)
            rec.connect_grpc(self.server.grpc_url, default_blueprint=bp)
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

    def log_polarization(self, index: int, timestamp_ns: int | None, *, s0: np.ndarray,
                         dolp: np.ndarray, aolp: np.ndarray, scale: float = 1.0) -> None:
        """Log S0, DoLP and AoLP.

        Parameters
        ----------
        s0
            (h, w) or (h, w, 3): ``s0 * scale`` is S0 = (I0 + I45 + I90 + I135) / 2
            normalised by the white level ([0, 2]); logged as :func:`s0_u8`.
        dolp
            (h, w) DoLP in [0, 1]; or (h, w, 3) per colour channel, then the
            DoLP and AoLP of the luminance-weighted Stokes vector are logged
            (:func:`luminance_orientation`, what the live colour view shows).
        aolp
            (h, w) AoLP in radians, [0, pi); or (h, w, 3) with ``dolp``.
        scale
            Factor from ``s0``'s values to S0.
        """
        if np.ndim(dolp) == 3:
            dolp, aolp = luminance_orientation(np.asarray(s0, dtype=np.float32) * np.float32(scale), dolp, aolp)
        v = self.view_scale
        s0_img = _resize(s0_u8(s0, scale=scale), v)
        lit = _lit(s0_img)
        dolp_img = _mask_dark(_resize(dolp_ids(dolp), v), lit)
        aolp_small = _resize(np.ascontiguousarray(aolp, dtype=np.float32), v, nearest=True)
        aolp_img = _mask_dark(aolp_ids(aolp_small), lit)
        dolp_small = _resize(np.ascontiguousarray(dolp, dtype=np.float32), v)  # area mean: DoLP is linear
        both_img = _mask_dark(aolp_dolp_ids(aolp_small, dolp_small), lit)
        with self._lock:
            self._time(index, timestamp_ns)
            self._image("s0", s0_img)
            for role, ids in (("dolp", dolp_img), ("aolp", aolp_img), ("aolp_dolp", both_img)):
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
        """Log scalars among ``fps``, ``dropped``, ``incomplete``, ``separation_seconds``,
        ``maps_fps``, ``layers_fps``."""
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

    def log_products(self, index: int, products: dict[str, np.ndarray], *, timestamp_ns: int | None = None,
                     frame: Any = None) -> None:
        """Log one frame's products as process writes them (and view reads them back).

        Parameters
        ----------
        index
            The ``frame`` time.
        products
            ``s0`` (S0, [0, 2]), ``dolp``, ``aolp`` (radians), ``diffuse``,
            ``specular`` (float arrays, (h, w) or (h, w, 3); a missing key is
            not logged).
        timestamp_ns
            The device time, if known.
        frame
            The raw :class:`polcam.frame.Frame`, logged at ``/camera/raw``
            (subject to ``raw_every``), or None.
        """
        self.log(index, Record(frame=frame, products=products, timestamp_ns=timestamp_ns))

    def log_output(self, index: int, folder: str | Path) -> None:
        """Log a frame folder written by ``polcam process``, its files read back
        (:func:`polcam.sinks.files.read_frame_folder`: the products, and the raw
        frame named in ``meta.json`` while it exists).

        Raises
        ------
        FrameReadError
            A product file that is missing or unreadable.
        """
        self.log(index, Record(folder=Path(folder)))

    def log(self, index: int, record: Record) -> None:
        """Log what ``record`` carries (:class:`polcam.sinks.base.Sink`).

        ``record.frame`` goes to ``/camera/raw`` (subject to ``raw_every``);
        ``s0``, ``dolp`` and ``aolp`` in ``record.products`` to
        ``/polarization/*`` (:meth:`log_polarization`, with ``record.scale["s0"]``);
        ``diffuse`` and ``specular`` to ``/layers/*`` (:meth:`log_layers`, with
        ``record.scale["diffuse"]``); ``record.stats`` to ``/stats/*``.  A
        record with only a ``folder`` is a finished ``polcam process`` frame
        folder, read back and logged (:meth:`log_output`).

        Raises
        ------
        FrameReadError
            A frame folder whose product files are missing or unreadable.
        ValueError
            An unknown statistic.
        """
        if record.folder is not None and not record.products and record.frame is None:
            record = read_frame_folder(record.folder)
        ts = record.timestamp_ns
        products, scale = record.products, record.scale
        if record.frame is not None:
            self.log_raw(index, ts, record.frame.mosaic, bit_depth=record.frame.bit_depth)
        if all(k in products for k in ("s0", "dolp", "aolp")):
            self.log_polarization(index, ts, s0=products["s0"], dolp=products["dolp"], aolp=products["aolp"],
                                  scale=scale.get("s0", 1.0))
        if "diffuse" in products and "specular" in products:
            self.log_layers(index, ts, diffuse=products["diffuse"], specular=products["specular"],
                            scale=scale.get("diffuse", 1.0))
        if record.stats:
            self.log_stats(index, ts, **record.stats)

    def close(self) -> None:
        """Flush everything to the target; ``serve`` stops the web viewer."""
        with self._lock:
            self._rec.flush()
            if self.target != "spawn":
                self._rec.disconnect()
            if self.server is not None:
                self.server.stop()
