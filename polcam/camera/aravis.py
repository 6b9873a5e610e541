"""The Aravis camera backend: GenICam cameras (GigE Vision, USB3 Vision, Aravis' fakes).

Loading Aravis and listing devices is :mod:`polcam.camera.aravis_lib` (its
names are re-exported here).  This backend is the registry's default: every
device id no other backend's prefix claims opens an :class:`AravisCamera`.
"""

from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np

from polcam.camera.aravis_lib import (
    INSTALL_HINT,
    DeviceInfo,
    aravis_available,
    gerror_message,
    is_busy,
    list_devices,
    load_aravis,
)
from polcam.camera.base import (
    Camera,
    CameraBusyError,
    CameraNotFoundError,
    CameraSettingError,
    CameraSettings,
    CapturedFrame,
    FrameIdTracker,
)
from polcam.camera.registry import CameraFlag, register_backend
from polcam.errors import CameraUnavailableError, LayoutError, PixelFormatError
from polcam.io.packing import unpack
from polcam.io.readers import interleave_angles
from polcam.mosaic import Layout, PixelFormat, layout_for_format, parse_layout, pixel_format

__all__ = ["AravisCamera", "DeviceInfo", "aravis_available", "list_devices", "load_aravis", "INSTALL_HINT"]

# ---------------------------------------------------------------------------
# The Aravis camera backend
# ---------------------------------------------------------------------------

#: Buffer status names (Aravis ``BufferStatus`` nicks) that mean "frame lost
#: because acquisition stopped", not "incomplete frame".
_ABORTED_STATUSES = ("aborted", "cleared")


def _round_down(value: int, step: int) -> int:
    step = max(1, int(step))
    return (int(value) // step) * step


def _lcm(a: int, b: int) -> int:
    import math

    a, b = max(1, int(a)), max(1, int(b))
    return a * b // math.gcd(a, b)


class AravisCamera(Camera):
    """A GenICam camera (GigE Vision, USB3 Vision, Aravis' Fake) through Aravis 0.8.

    Acquisition runs in a dedicated thread that pops buffers from the Aravis
    stream (``timeout_pop_buffer``, which releases the GIL while it waits),
    copies out the image bytes of complete buffers, pushes every buffer back
    to the pool at once, and queues the frame (dropping it, counted, when the
    consumer's queue is full).  Buffers with any other status are counted by
    status and never handed on.

    Parameters
    ----------
    camera_id
        Aravis device id (``polcam devices`` lists them), serial number,
        or address.  Ids starting with ``Fake`` enable Aravis' in-process
        Fake interface (``Fake_1``).
    n_buffers
        Buffers in the Aravis pool.
    queue_frames
        Frames waiting for the consumer before new ones are dropped.
    packet_size
        GigE Vision stream packet size in bytes, set explicitly (default
        1500, which every Ethernet path carries; 8192 or 9000 where jumbo
        frames are enabled end to end), ``"auto"`` for Aravis' probe of the
        largest size that gets through (``gv_auto_packet_size``), or ``None``
        to leave the camera's setting (which may exceed the path MTU).
    packet_delay_ns
        GigE inter-packet delay (``GevSCPD``), to spread the bandwidth of
        several cameras on one link.
    socket_buffer_bytes
        GigE receive socket buffer size (``None``: Aravis' automatic size).
        The system's ``net.core.rmem_max`` caps it (drivers/README.md).
    usb_mode
        USB3 Vision transfer mode, ``"async"`` (default, several transfers
        in flight) or ``"sync"``.
    pop_timeout
        Seconds each wait for a buffer lasts in the acquisition thread.
    probe_after
        Seconds without any buffer after which the acquisition thread asks a
        GigE camera whether it is still there (one GVCP register read, again
        every such period of silence).  A camera that does not answer
        (Aravis gives up after 2.5 s) is taken as disconnected, as it is when
        Aravis' own heartbeat reports the control channel lost (about 6 s):
        :meth:`poll_frames` then raises :class:`CameraDisconnectedError`
        after the frames already delivered.  ``None``: the heartbeat only.

    Notes
    -----
    A camera that went away is not stopped (nothing answers) and is released
    on a background thread: Aravis waits for GVCP timeouts (about 5 s) when
    it lets go of a dead GigE device.
    """

    def __init__(
        self,
        camera_id: str,
        *,
        n_buffers: int = 16,
        queue_frames: int = 8,
        packet_size: int | str | None = 1500,
        packet_delay_ns: int | None = None,
        socket_buffer_bytes: int | None = None,
        usb_mode: str = "async",
        pop_timeout: float = 0.1,
        probe_after: float | None = 1.0,
    ) -> None:
        super().__init__(camera_id, queue_frames=queue_frames)
        if int(n_buffers) < 2:
            raise CameraSettingError(f"n_buffers {n_buffers!r}: expected at least 2")
        if usb_mode not in ("async", "sync"):
            raise CameraSettingError(f"usb_mode {usb_mode!r}: expected 'async' or 'sync'")
        self.n_buffers = int(n_buffers)
        self.packet_size = packet_size
        self.packet_delay_ns = packet_delay_ns
        self.socket_buffer_bytes = socket_buffer_bytes
        self.usb_mode = usb_mode
        self.pop_timeout = float(pop_timeout)
        self.probe_after = None if probe_after is None else float(probe_after)
        self._info: dict[str, Any] = {}
        self._lost_handler: int | None = None
        self._arv: Any = None
        self._cam: Any = None
        self._dev: Any = None
        self._stream: Any = None
        self._thread: threading.Thread | None = None
        self._stop_event = threading.Event()
        self._device_info: DeviceInfo | None = None
        self._vendor = ""
        self._format: PixelFormat | None = None
        self._format_code: int | None = None
        self._sensor_layout: Layout | None = None
        self._layout: Layout | None = None
        self._meta: dict[str, Any] = {}
        self._user_layout: str | Layout | None = None
        self._ids = FrameIdTracker()

    # ------------------------------------------------------------------ open
    def _resolve(self) -> DeviceInfo:
        fake = self.camera_id.startswith("Fake")
        if fake and self.camera_id.split("_")[-1].isdigit():
            # Aravis' in-process Fake camera: no need for a (slow) network discovery
            arv = load_aravis()
            arv.enable_interface("Fake")
            n = int(self.camera_id.split("_")[-1])
            return DeviceInfo(id=self.camera_id, vendor="Aravis", model="Fake", serial=str(n),
                              protocol="Fake", address="0.0.0.0", physical_id=self.camera_id)
        devices = list_devices(fake=fake)
        want = self.camera_id
        for key in ("id", "serial", "address", "physical_id"):
            hits = [d for d in devices if getattr(d, key) == want]
            if len(hits) == 1:
                return hits[0]
        seen = ", ".join(d.id for d in devices) or "none"
        raise CameraNotFoundError(
            f"no camera with id {want!r} (cameras seen: {seen}); list them with `polcam devices` "
            "(`polcam devices --fake` adds Aravis' simulated camera Fake_1); check cabling, power "
            "and network settings (drivers/README.md)"
        )

    def open(self) -> AravisCamera:
        """Find the camera and take control of it.

        Raises
        ------
        CameraUnavailableError
            Aravis is not installed (with install instructions).
        CameraNotFoundError
            No camera with that id, serial or address.
        CameraBusyError
            Another program controls the camera.
        """
        if self._opened:
            return self
        arv = load_aravis()
        info = self._resolve()
        from gi.repository import GLib

        try:
            cam = arv.Camera.new(info.id)
        except GLib.Error as exc:
            msg = gerror_message(exc)
            if "not found" in msg.lower():
                raise CameraNotFoundError(
                    f"no camera with id {info.id!r} ({msg}); list them with `polcam devices` "
                    "(`polcam devices --fake` adds Aravis' simulated camera Fake_1)"
                ) from None
            if is_busy(msg):
                raise CameraBusyError(
                    f"camera {info.id} is busy: another program controls it ({msg}); close that "
                    "program (arv-viewer, a vendor SDK, another polcam) and try again"
                ) from None
            raise CameraUnavailableError(f"cannot open camera {info.id}: {msg}") from None
        self._arv, self._cam, self._dev = arv, cam, cam.get_device()
        try:  # emitted from Aravis' heartbeat thread when the camera stops answering
            self._lost_handler = self._dev.connect("control-lost", self._on_control_lost)
        except TypeError:  # a device class without the signal
            self._lost_handler = None
        self._device_info = info
        self.camera_id = info.id
        self._vendor = self._string("DeviceVendorName") or cam.get_vendor_name() or info.vendor
        if cam.is_gv_device():
            self._setup_gige()
        elif cam.is_uv_device():
            mode = arv.UvUsbMode.ASYNC if self.usb_mode == "async" else arv.UvUsbMode.SYNC
            cam.uv_set_usb_mode(mode)
        self._opened = True
        self._refresh()
        return self

    def _setup_gige(self) -> None:
        from gi.repository import GLib

        cam = self._cam
        try:
            if self.packet_size == "auto":
                cam.gv_auto_packet_size()
            elif self.packet_size is not None:
                cam.gv_set_packet_size(int(self.packet_size))
            if self.packet_delay_ns is not None:
                cam.gv_set_packet_delay(int(self.packet_delay_ns))
        except GLib.Error as exc:
            raise CameraSettingError(
                f"camera {self.camera_id}: cannot set the GigE packet size {self.packet_size!r}: "
                f"{gerror_message(exc)}"
            ) from None

    def _on_control_lost(self, *_args: Any) -> None:
        self._connection_lost("Aravis lost the control channel (no answer to its heartbeat)")

    def close(self) -> None:
        """Stop acquisition and release the camera (a camera that went away: on a background thread)."""
        if self._running:
            self.stop()
        held = [h for h in (self._stream, self._cam, self._dev) if h is not None]
        self._stream = None
        self._cam = None
        self._dev = None
        self._opened = False
        if self.lost is not None and held:
            self._release_later(held)  # the last references: dropped on that thread
        held = []

    def _release_later(self, objects: list[Any]) -> None:
        """Drop Aravis objects of a camera that went away on a background thread: their
        finalizers talk to the camera and wait for GVCP timeouts (about 5 s).  ``objects`` must
        hold the last references."""
        threading.Thread(target=objects.clear, name=f"release-{self.camera_id}", daemon=True).start()

    # ------------------------------------------------------------- features
    def _available(self, name: str) -> bool:
        try:
            return bool(self._dev.is_feature_available(name))
        except Exception:  # noqa: BLE001 - GLib errors for unknown nodes
            return False

    def _string(self, name: str) -> str | None:
        if self._dev is None or not self._available(name):
            return None
        try:
            return self._dev.get_string_feature_value(name)
        except Exception:  # noqa: BLE001
            return None

    def _bool(self, name: str) -> bool:
        if not self._available(name):
            return False
        try:
            return bool(self._dev.get_boolean_feature_value(name))
        except Exception:  # noqa: BLE001
            return False

    def _need_open(self) -> None:
        if not self._opened:
            raise CameraUnavailableError(f"camera {self.camera_id} is not open: call open() first")

    def _refresh(self) -> None:
        """Read back format, region, mirroring, exposure, gain; derive the layout."""
        cam = self._cam
        name = cam.get_pixel_format_as_string()
        self._format_code = int(cam.get_pixel_format())
        try:
            self._format = pixel_format(name, self._vendor)
        except PixelFormatError:
            self._format = None  # reported by configure/start with the supported list
        region = cam.get_region()
        x, y, w, h = int(region.x), int(region.y), int(region.width), int(region.height)
        rx, ry = self._bool("ReverseX"), self._bool("ReverseY")
        self._sensor_layout = None
        self._layout = None
        if self._format is not None:
            try:
                self._sensor_layout = layout_for_format(self._format, self._user_layout)
                self._layout = self._sensor_layout.for_readout(
                    offset_x=x, offset_y=y, width=w, height=h, reverse_x=rx, reverse_y=ry)
            except (LayoutError, PixelFormatError):
                self._layout = None  # a plain format without --layout: frames carry no layout
        meta: dict[str, Any] = {
            "pixel_format": name,
            "vendor": self._vendor,
            "camera_id": self.camera_id,
            "roi": [x, y, w, h],
            "reverse_x": rx,
            "reverse_y": ry,
        }
        if cam.is_exposure_time_available():
            meta["exposure_us"] = float(cam.get_exposure_time())
        if cam.is_gain_available():
            if self._available("Gain"):
                meta["gain_db"] = float(cam.get_gain())
            else:
                meta["gain_raw"] = float(cam.get_gain())
        if cam.is_frame_rate_available():
            meta["frame_rate"] = float(cam.get_frame_rate())
        self._meta = meta
        # what `info` reports, read now: a camera that went away cannot be asked any more
        d = self._device_info.as_dict() if self._device_info else {"id": self.camera_id}
        d["vendor_name"] = self._vendor
        d["model"] = cam.get_model_name() or d.get("model", "")
        d["pixel_format"] = meta.get("pixel_format")
        d["layout"] = None if self._layout is None else self._layout.short_name
        d["settings"] = {k: v for k, v in meta.items() if k not in ("vendor", "camera_id")}
        if cam.is_gv_device():
            d["packet_size"] = int(cam.gv_get_packet_size())
        self._info = d

    @property
    def layout(self) -> Layout | None:
        return self._layout

    @property
    def info(self) -> dict[str, Any]:
        """Vendor, model, serial, protocol, settings, as read when the camera was last configured."""
        if self._info:
            return {**self._info, "settings": dict(self._info.get("settings", {}))}
        return self._device_info.as_dict() if self._device_info else {"id": self.camera_id}

    def readable_formats(self) -> list[str]:
        """Pixel formats this camera offers that polcam can read."""
        self._need_open()
        offered = list(self._cam.dup_available_pixel_formats_as_strings() or [])
        out = []
        for name in offered:
            try:
                fmt = pixel_format(name, self._vendor)
            except PixelFormatError:
                continue
            if fmt.kind != "derived":
                out.append(name)
        return out

    # ------------------------------------------------------------- configure
    def _configure(self, settings: CameraSettings) -> dict[str, Any]:
        """Apply settings (see :meth:`Camera.configure`); returns them as read back.

        Raises
        ------
        PixelFormatError
            A format the camera does not offer or polcam cannot read; the
            message lists the camera's formats that polcam reads.
        LayoutError
            A plain Mono/Bayer format without a layout, or a bad layout.
        CameraSettingError
            A value the camera refuses, a missing feature, an unknown trigger.
        """
        s = settings
        self._need_open()
        if self._running:
            raise CameraSettingError(f"camera {self.camera_id}: stop acquisition before configuring")
        from gi.repository import GLib

        cam = self._cam
        ignored: list[str] = []
        if s.layout is not None:
            self._user_layout = parse_layout(s.layout)

        def attempt(what: str, value: Any, fn: Any, *args: Any) -> None:
            try:
                fn(*args)
            except GLib.Error as exc:
                raise CameraSettingError(
                    f"camera {self.camera_id} refused {what} = {value!r}: {gerror_message(exc)}"
                ) from None

        if s.pixel_format is not None:
            offered = list(cam.dup_available_pixel_formats_as_strings() or [])
            if s.pixel_format not in offered:
                raise PixelFormatError(
                    f"camera {self.camera_id} ({self._vendor}) does not offer pixel format "
                    f"{s.pixel_format!r}; supported (offered by the camera and read by polcam): "
                    f"{', '.join(self.readable_formats()) or 'none'} (camera offers: {', '.join(offered)})"
                )
            fmt = self._lookup(s.pixel_format)
            attempt("PixelFormat", s.pixel_format, cam.set_pixel_format_from_string, fmt.name)
        fmt = self._lookup(cam.get_pixel_format_as_string())
        sensor = layout_for_format(fmt, self._user_layout)  # LayoutError for plain formats without one

        if s.reverse_x is not None or s.reverse_y is not None:
            for feat, val in (("ReverseX", s.reverse_x), ("ReverseY", s.reverse_y)):
                if val is None:
                    continue
                if not self._available(feat):
                    if val:
                        raise CameraSettingError(f"camera {self.camera_id} has no {feat} feature")
                    continue
                attempt(feat, val, self._dev.set_boolean_feature_value, feat, bool(val))

        if s.roi is not None:
            self._set_roi(s.roi, sensor.period, attempt)

        if s.exposure_us is not None:
            if not cam.is_exposure_time_available():
                raise CameraSettingError(f"camera {self.camera_id} has no exposure time feature")
            if cam.is_exposure_auto_available():
                attempt("ExposureAuto", "Off", cam.set_exposure_time_auto, self._arv.Auto.OFF)
            attempt("exposure time (us)", s.exposure_us, cam.set_exposure_time, float(s.exposure_us))
        if s.gain_db is not None:
            if not cam.is_gain_available():
                raise CameraSettingError(f"camera {self.camera_id} has no gain feature")
            if cam.is_gain_auto_available():
                attempt("GainAuto", "Off", cam.set_gain_auto, self._arv.Auto.OFF)
            attempt("gain", s.gain_db, cam.set_gain, float(s.gain_db))
        if s.frame_rate is not None:
            if s.frame_rate <= 0:
                raise CameraSettingError(f"frame rate {s.frame_rate!r}: expected a positive number")
            if cam.is_frame_rate_available():
                attempt("frame rate", s.frame_rate, cam.set_frame_rate, float(s.frame_rate))
            else:
                ignored.append("frame_rate")
        if s.trigger is not None:
            self._set_trigger(s.trigger, attempt)
        self._refresh()
        out = dict(self._meta)
        out["layout"] = None if self._layout is None else self._layout.short_name
        out["sensor_layout"] = sensor.short_name
        out["trigger"] = s.trigger or "unchanged"
        out["ignored"] = ignored
        return out

    def _lookup(self, name: str) -> PixelFormat:
        try:
            fmt = pixel_format(name, self._vendor)
        except PixelFormatError:
            raise PixelFormatError(
                f"camera {self.camera_id} ({self._vendor}) sends pixel format {name!r}, which polcam "
                f"does not read; supported (offered by the camera and read by polcam): "
                f"{', '.join(self.readable_formats()) or 'none'}; choose one with --pixel-format"
            ) from None
        if fmt.kind == "derived":
            raise PixelFormatError(
                f"pixel format {name} carries values computed in the camera, not a raw mosaic; "
                f"supported: {', '.join(self.readable_formats()) or 'none'}"
            )
        return fmt

    def _set_roi(self, roi: tuple[int, int, int, int], period: int, attempt: Any) -> None:
        cam = self._cam
        try:
            x, y, w, h = (int(v) for v in roi)
        except (TypeError, ValueError):
            raise CameraSettingError(f"ROI {roi!r}: expected four integers x, y, width, height") from None
        if x < 0 or y < 0 or w <= 0 or h <= 0:
            raise CameraSettingError(f"ROI {roi!r}: expected x, y >= 0 and width, height > 0")
        sx = _lcm(period, cam.get_x_offset_increment() if cam.is_region_offset_available() else 1)
        sy = _lcm(period, cam.get_y_offset_increment() if cam.is_region_offset_available() else 1)
        sw = _lcm(period, cam.get_width_increment())
        sh = _lcm(period, cam.get_height_increment())
        x, y = _round_down(x, sx), _round_down(y, sy)
        w, h = _round_down(w, sw), _round_down(h, sh)
        sensor = cam.get_sensor_size()
        if w < 2 * period or h < 2 * period or x + w > sensor.width or y + h > sensor.height:
            raise CameraSettingError(
                f"ROI {roi!r} (aligned to whole polarizer cells: {x}, {y}, {w}, {h}) does not fit the "
                f"{sensor.width}x{sensor.height} sensor or is smaller than {2 * period}x{2 * period}"
            )
        # shrink first, then move, then grow: cameras check offset + size against the sensor
        attempt("ROI", roi, cam.set_region, 0, 0, w, h)
        attempt("ROI", roi, cam.set_region, x, y, w, h)

    def _set_trigger(self, trigger: str, attempt: Any) -> None:
        cam = self._cam
        if trigger == "free":
            attempt("trigger", trigger, cam.clear_triggers)
            return
        sources = list(cam.dup_available_trigger_sources() or [])
        if trigger == "software":
            if not cam.is_software_trigger_supported():
                raise CameraSettingError(f"camera {self.camera_id} has no software trigger")
            attempt("trigger", trigger, cam.set_trigger, "Software")
            return
        if trigger not in sources:
            raise CameraSettingError(
                f"trigger {trigger!r}: expected 'free', 'software' or one of the camera's trigger "
                f"sources ({', '.join(s for s in sources if s != 'Software') or 'none'})"
            )
        attempt("trigger", trigger, cam.set_trigger, trigger)

    def trigger(self) -> None:
        """Fire the software trigger (after ``configure(trigger="software")``)."""
        self._need_open()
        self._cam.software_trigger()

    # ------------------------------------------------------------ acquisition
    def _start(self) -> None:
        self._need_open()
        self._refresh()
        fmt = self._lookup(self._meta["pixel_format"])
        self._format = fmt
        arv = self._arv
        cam = self._cam
        from gi.repository import GLib

        try:
            stream = cam.create_stream(None, None)
        except GLib.Error as exc:
            raise CameraUnavailableError(
                f"camera {self.camera_id}: cannot open the stream: {gerror_message(exc)}"
            ) from None
        if cam.is_gv_device():
            if self.socket_buffer_bytes:
                stream.set_property("socket-buffer", arv.GvStreamSocketBuffer.FIXED)
                stream.set_property("socket-buffer-size", int(self.socket_buffer_bytes))
            else:
                stream.set_property("socket-buffer", arv.GvStreamSocketBuffer.AUTO)
        payload = int(cam.get_payload())  # re-read: it changes with format and ROI
        for _ in range(self.n_buffers):
            stream.push_buffer(arv.Buffer.new_allocate(payload))
        self._stream = stream
        self._ids = FrameIdTracker()
        self._stop_event.clear()
        cam.set_acquisition_mode(arv.AcquisitionMode.CONTINUOUS)
        self._thread = threading.Thread(target=self._acquire, name=f"aravis-{self.camera_id}", daemon=True)
        self._thread.start()
        try:
            cam.start_acquisition()
        except GLib.Error as exc:
            self._stop_event.set()
            self._thread.join()
            raise CameraUnavailableError(
                f"camera {self.camera_id}: cannot start acquisition: {gerror_message(exc)}"
            ) from None

    def _acquire(self) -> None:
        """Acquisition thread: pop, copy, push back, queue."""
        arv = self._arv
        stream = self._stream
        success = arv.BufferStatus.SUCCESS
        image_types = {arv.BufferPayloadType.IMAGE}
        for name in ("EXTENDED_CHUNK_DATA", "CHUNK_DATA"):
            if hasattr(arv.BufferPayloadType, name):
                image_types.add(getattr(arv.BufferPayloadType, name))
        fmt = self._format
        assert fmt is not None
        timeout_us = max(1000, int(self.pop_timeout * 1e6))
        probe = self.probe_after if self._cam.is_gv_device() else None
        heard = time.monotonic()
        while not self._stop_event.is_set() and self.lost is None:
            buf = stream.timeout_pop_buffer(timeout_us)
            if buf is None:
                if probe is not None and time.monotonic() - heard > probe:
                    self._probe()
                    heard = time.monotonic()
                continue
            heard = time.monotonic()
            try:
                status = buf.get_status()
                fid = int(buf.get_frame_id())
                if status == success and buf.get_payload_type() in image_types:
                    data = buf.get_data()
                    w, h = int(buf.get_image_width()), int(buf.get_image_height())
                    code = int(buf.get_image_pixel_format())
                    ts = int(buf.get_timestamp())
                    sys_ts = int(buf.get_system_timestamp())
                    x, y = int(buf.get_image_x()), int(buf.get_image_y())
                else:
                    data = None
            finally:
                stream.push_buffer(buf)  # always give the buffer back to the pool
            self._count_dropped(self._ids.see(fid))
            if data is None:
                nick = status.value_nick if hasattr(status, "value_nick") else str(status)
                if status == success:
                    nick = "not-an-image"
                self._count(nick, incomplete=nick not in _ABORTED_STATUSES)
                continue
            try:
                frame = self._make_frame(data, w, h, code, fid, ts, sys_ts, x, y, fmt)
            except Exception:  # noqa: BLE001 - a frame polcam cannot decode is not a good frame
                frame = None
            if frame is None:
                self._count("size-mismatch", incomplete=True)
                continue
            self._deliver(frame)

    def _probe(self) -> None:
        """Ask a silent GigE camera whether it is there (its control channel privilege register)."""
        from gi.repository import GLib

        try:
            self._dev.read_register(0x0A00)
        except GLib.Error as exc:
            self._connection_lost(f"no answer to a register read ({gerror_message(exc)})")

    def _make_frame(self, data: bytes, w: int, h: int, code: int, fid: int, ts: int, sys_ts: int,
                    x: int, y: int, fmt: PixelFormat) -> CapturedFrame | None:
        """A frame from a complete buffer, or None when the bytes do not match the format."""
        if self._format_code is not None and code and code != self._format_code:
            return None
        if len(data) != fmt.frame_bytes(w, h):
            return None
        if fmt.kind == "angles":
            planes = unpack(data, packing=fmt.packing, width=w, height=h, channels=4)
            mosaic = interleave_angles(planes)
        elif fmt.packing == "8":
            mosaic = np.frombuffer(data, dtype=np.uint8).reshape(h, w)
        elif fmt.packing == "16":
            mosaic = np.frombuffer(data, dtype="<u2").reshape(h, w)
        else:
            mosaic = unpack(data, packing=fmt.packing, width=w, height=h)
        meta = dict(self._meta)
        meta.update({"frame_id": fid, "timestamp_ns": ts, "system_timestamp_ns": sys_ts})
        roi = meta.get("roi")
        if roi is None or list(roi[2:]) != [w, h]:
            meta["roi"] = [x, y, w, h]
        return CapturedFrame(
            mosaic=mosaic, layout=self._layout, bit_depth=fmt.bit_depth, metadata=meta, payload=data
        )

    def _stop(self) -> None:
        from gi.repository import GLib

        self._stop_event.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None
        if self._cam is not None and self.lost is None:  # a camera that went away cannot be told
            try:
                self._cam.stop_acquisition()
            except GLib.Error as exc:  # it went away just now
                self._connection_lost(f"no answer to AcquisitionStop ({gerror_message(exc)})")
        self._final_stream_stats = self._backend_stats()
        held = [self._stream] if self._stream is not None else []
        self._stream = None
        if self.lost is not None and held:
            self._release_later(held)  # its finalizer writes to the camera: GVCP timeouts
        self._finished.set()

    def _backend_stats(self) -> dict[str, Any]:
        stream = self._stream
        if stream is None:
            return dict(getattr(self, "_final_stream_stats", {}))
        out: dict[str, Any] = {}
        try:
            for i in range(stream.get_n_infos()):
                name = stream.get_info_name(i)
                if stream.get_info_type(i).name == "guint64":
                    out[name] = int(stream.get_info_uint64(i))
                else:
                    out[name] = float(stream.get_info_double(i))
        except Exception:  # noqa: BLE001 - statistics are informational
            pass
        return out


def _packet_size_option(text: Any) -> int | str:
    """``--packet-size``: a number of bytes or ``"auto"``; :class:`CameraSettingError` otherwise."""
    size = str(text).strip().lower()
    if size != "auto" and not size.isdigit():
        raise CameraSettingError(f"--packet-size {text!r}: expected a number of bytes or 'auto'")
    return "auto" if size == "auto" else int(size)


#: Every device id no other backend's prefix claims, with the GenICam stream's flags.
register_backend(None, AravisCamera, default=True, name="aravis", flags=(
    CameraFlag("--buffers", "n_buffers", "Aravis buffer pool size (default 16)", {"type": int, "default": 16}),
    CameraFlag("--packet-size", "packet_size",
               "GigE packet size in bytes (default 1500; 8192/9000 with jumbo frames end to end; "
               "'auto': Aravis probes the largest size the path carries)", {"default": "1500"},
               convert=_packet_size_option, skip_none=True),
    CameraFlag("--socket-buffer", "socket_buffer_bytes",
               "GigE receive socket buffer (default: Aravis' automatic size)",
               {"type": int, "metavar": "BYTES"}, skip_none=True),
))
