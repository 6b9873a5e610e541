"""Sensor layouts of division-of-focal-plane polarization cameras, and pixel formats.

A *layout* says, for every pixel of a raw mosaic, which polarizer angle and
(for colour sensors) which colour filter sits over it.  Two families exist:

``mono:A,B,C,D``
    A 2x2 polarizer cell, its four angles in degrees given row by row
    (``A B`` on row 0, ``C D`` on row 1).  ``imx250mzr`` is ``mono:90,45,135,0``.
``color:A,B,C,D:BAYER``
    The same 2x2 polarizer cell under one colour filter; the 2x2 cells form
    a Bayer pattern ``BAYER`` (``RGGB``, ``BGGR``, ``GRBG`` or ``GBRG``, read row by
    row over cells), so the period is 4 pixels.  ``imx250myr`` is
    ``color:90,45,135,0:RGGB``.

Region-of-interest offsets and sensor mirroring (GenICam ``ReverseX`` /
``ReverseY``) change the phase of the pattern; :meth:`Layout.for_readout` derives the
layout of the delivered image from the sensor layout.  Mirroring an image also
mirrors polarizer orientations (45 and 135 degrees trade places), so the angle
labels of a mirrored layout are those seen in the *image* frame and AoLP
computed from it is measured in the image frame.

The pixel-format registry maps GenICam ``PixelFormat`` names, together with the
``DeviceVendorName``, to bit depth, packing and layout; vendor-specific codes
with bit 31 set mean different things at different vendors, so formats are
never identified by number alone.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from polcam.errors import LayoutError, PixelFormatError

__all__ = [
    "ANGLES",
    "BAYER_PATTERNS",
    "LAYOUTS",
    "Layout",
    "PixelFormat",
    "PIXEL_FORMATS",
    "VENDOR_ALIASES",
    "parse_layout",
    "pixel_format",
    "supported_pixel_formats",
    "vendor_key",
]

#: Polarizer angles in degrees, in the order of every polcam stack.
ANGLES: tuple[int, int, int, int] = (0, 45, 90, 135)

#: Bayer orders polcam accepts, read row by row from the top-left (cell).
BAYER_PATTERNS: tuple[str, ...] = ("RGGB", "BGGR", "GRBG", "GBRG")

_CHANNEL = {"R": 0, "G": 1, "B": 2}

#: Named sensor layouts.
LAYOUTS: dict[str, str] = {
    "imx250mzr": "mono:90,45,135,0",
    "imx250myr": "color:90,45,135,0:RGGB",
}


@dataclass(frozen=True)
class Layout:
    """The polarizer and colour-filter pattern of a raw mosaic.

    Parameters
    ----------
    angles
        The 2x2 polarizer cell, row by row, in degrees; a permutation of
        (0, 45, 90, 135).
    bayer
        ``None`` for a monochrome sensor, else the Bayer order of the 2x2
        cells (one of :data:`BAYER_PATTERNS`).
    """

    angles: tuple[int, int, int, int]
    bayer: str | None = None
    _angle_cell: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        angles = tuple(int(a) for a in self.angles)
        if len(angles) != 4 or sorted(angles) != sorted(ANGLES):
            raise LayoutError(
                f"polarizer cell angles {self.angles!r} are not a permutation of {ANGLES}"
            )
        object.__setattr__(self, "angles", angles)
        if self.bayer is not None:
            bayer = str(self.bayer).upper()
            if bayer not in BAYER_PATTERNS:
                raise LayoutError(
                    f"Bayer order {self.bayer!r} is not one of {', '.join(BAYER_PATTERNS)}"
                )
            object.__setattr__(self, "bayer", bayer)
        cell = np.array([ANGLES.index(a) for a in angles], dtype=np.intp).reshape(2, 2)
        object.__setattr__(self, "_angle_cell", cell)

    # ------------------------------------------------------------------ naming
    @property
    def is_color(self) -> bool:
        """True for a colour-polarization sensor."""
        return self.bayer is not None

    @property
    def period(self) -> int:
        """Period of the pattern in pixels: 2 (mono) or 4 (colour)."""
        return 4 if self.is_color else 2

    @property
    def name(self) -> str:
        """Canonical spelled-out name, e.g. ``color:90,45,135,0:RGGB``."""
        cell = ",".join(str(a) for a in self.angles)
        return f"color:{cell}:{self.bayer}" if self.is_color else f"mono:{cell}"

    @property
    def short_name(self) -> str:
        """The named alias (``imx250mzr``, ...) if there is one, else :attr:`name`."""
        for alias, spelled in LAYOUTS.items():
            if spelled == self.name:
                return alias
        return self.name

    def __str__(self) -> str:
        return self.short_name

    # ------------------------------------------------------------------- maps
    def angle_index(self, height: int, width: int) -> np.ndarray:
        """Index into :data:`ANGLES` of every pixel.

        Returns
        -------
        numpy.ndarray
            (height, width) int array with values in {0, 1, 2, 3}.
        """
        reps = (-(-height // 2), -(-width // 2))
        return np.tile(self._angle_cell, reps)[:height, :width]

    def channel_index(self, height: int, width: int) -> np.ndarray:
        """Colour channel (0 = R, 1 = G, 2 = B) of every pixel; all zero for mono.

        Returns
        -------
        numpy.ndarray
            (height, width) int array.
        """
        if not self.is_color:
            return np.zeros((height, width), dtype=np.intp)
        assert self.bayer is not None
        cells = np.array([_CHANNEL[c] for c in self.bayer], dtype=np.intp).reshape(2, 2)
        pattern = np.repeat(np.repeat(cells, 2, axis=0), 2, axis=1)  # 4x4
        reps = (-(-height // 4), -(-width // 4))
        return np.tile(pattern, reps)[:height, :width]

    # -------------------------------------------------------------- geometry
    def shifted(self, dx: int, dy: int) -> Layout:
        """Layout of a crop that starts ``dx`` columns and ``dy`` rows into this one.

        Raises
        ------
        LayoutError
            For a colour layout and an odd offset: the crop would split the
            2x2 polarizer cells between two colour filters.
        """
        if self.is_color and (dx % 2 or dy % 2):
            raise LayoutError(
                f"ROI offset ({dx}, {dy}) on colour layout {self.short_name}: "
                "expected even offsets (an odd offset splits a polarizer cell across colour filters)"
            )
        angles = tuple(self.angles[((dy + r) % 2) * 2 + (dx + c) % 2] for r in range(2) for c in range(2))
        bayer = None
        if self.bayer is not None:
            cx, cy = (dx // 2) % 2, (dy // 2) % 2
            bayer = "".join(self.bayer[((cy + r) % 2) * 2 + (cx + c) % 2] for r in range(2) for c in range(2))
        return Layout(angles, bayer)  # type: ignore[arg-type]

    def mirrored(self, *, x: bool = False, y: bool = False, width: int = 0, height: int = 0) -> Layout:
        """Layout of this mosaic flipped left-right (``x``) and/or top-bottom (``y``).

        ``width`` / ``height`` are the size of the flipped image: its last
        column becomes the first, so the phase depends on them.  Mirroring once
        maps each polarizer angle a to (180 - a) mod 180 in the image frame.
        """
        lay: Layout = self
        if x:
            lay = lay.shifted(width - lay.period, 0) if width % lay.period else lay
            lay = lay._flip(axis=1)
        if y:
            lay = lay.shifted(0, height - lay.period) if height % lay.period else lay
            lay = lay._flip(axis=0)
        return lay

    def _flip(self, *, axis: int) -> Layout:
        # flip a pattern whose size is a multiple of the period: pixel c -> period-1-c
        cell = np.array(self.angles).reshape(2, 2)
        cell = np.flip(cell, axis=axis)
        angles = tuple(int((180 - a) % 180) for a in cell.ravel())
        bayer = None
        if self.bayer is not None:
            b = np.array(list(self.bayer)).reshape(2, 2)
            bayer = "".join(np.flip(b, axis=axis).ravel())
        return Layout(angles, bayer)  # type: ignore[arg-type]

    def for_readout(
        self,
        *,
        offset_x: int = 0,
        offset_y: int = 0,
        width: int = 0,
        height: int = 0,
        reverse_x: bool = False,
        reverse_y: bool = False,
    ) -> Layout:
        """Layout of the image a camera delivers from this *sensor* layout.

        The image pixel (r, c) comes from the sensor pixel
        ``(offset_y + r', offset_x + c')`` with ``c' = width - 1 - c`` when
        ``reverse_x`` (likewise rows), i.e. the ROI is cut on the sensor and then
        mirrored, as GenICam cameras do.

        Parameters
        ----------
        offset_x, offset_y
            ROI offset on the sensor, pixels.
        width, height
            ROI size, pixels (only needed when mirroring).
        reverse_x, reverse_y
            GenICam ReverseX / ReverseY.
        """
        lay = self.shifted(offset_x, offset_y)
        return lay.mirrored(x=reverse_x, y=reverse_y, width=width, height=height)


_LAYOUT_RE = re.compile(
    r"^(?P<kind>mono|color|colour):(?P<cell>\d+,\d+,\d+,\d+)(?::(?P<bayer>[A-Za-z]{4}))?$"
)


def parse_layout(spec: str | Layout) -> Layout:
    """Parse a layout name.

    Parameters
    ----------
    spec
        ``imx250mzr``, ``imx250myr``, ``mono:90,45,135,0``,
        ``color:90,45,135,0:RGGB``, or a :class:`Layout` (returned as is).

    Raises
    ------
    LayoutError
        For anything else; the message lists the accepted forms.
    """
    if isinstance(spec, Layout):
        return spec
    text = str(spec).strip()
    text = LAYOUTS.get(text.lower(), text)
    m = _LAYOUT_RE.match(text)
    if not m:
        raise LayoutError(
            f"layout {spec!r} not understood; expected one of {', '.join(LAYOUTS)}, "
            "'mono:A,B,C,D' or 'color:A,B,C,D:BAYER' (2x2 polarizer cell row by row, "
            "Bayer order of the cells)"
        )
    angles = tuple(int(a) for a in m.group("cell").split(","))
    kind = m.group("kind")
    bayer = m.group("bayer")
    if kind == "mono":
        if bayer:
            raise LayoutError(f"layout {spec!r}: a mono layout takes no Bayer order")
        return Layout(angles)  # type: ignore[arg-type]
    if not bayer:
        raise LayoutError(f"layout {spec!r}: a colour layout needs a Bayer order, e.g. ':RGGB'")
    return Layout(angles, bayer)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------
# Pixel formats
# ---------------------------------------------------------------------------

#: Packings understood by :func:`polcam.io.packing.unpack`.
PACKINGS = ("8", "16", "10p", "12p", "12packed", "10packed")


@dataclass(frozen=True)
class PixelFormat:
    """What a GenICam pixel format means.

    Attributes
    ----------
    name
        The PixelFormat name as the camera reports it.
    vendor
        Vendor it belongs to (``"*"`` for the GenICam standard names).
    bit_depth
        Significant bits per pixel.
    packing
        One of :data:`PACKINGS`: ``8`` one byte a pixel, ``16`` little-endian
        16-bit words, ``10p``/``12p`` PFNC LSB-first bit packing,
        ``12packed``/``10packed`` GigE Vision legacy packing.
    kind
        ``polar-mono``/``polar-color``: the raw polarization mosaic (its
        layout in :attr:`layout`); ``plain-mono``/``plain-bayer``: a sensor
        mosaic the camera does not label, the layout must be given
        (``--layout``); ``angles``: four half-resolution angle planes in order
        0, 45, 90, 135, interleaved per pixel; ``derived``: Stokes, DoLP or AoLP
        computed in the camera (not a raw mosaic, refused for processing).
    layout
        For ``polar-*`` kinds: the layout name (the Bayer phase taken from the
        format's name where it carries one).
    code
        The 32-bit PixelFormat value, informational only.
    """

    name: str
    vendor: str
    bit_depth: int
    packing: str
    kind: str
    layout: str | None = None
    code: int | None = None

    @property
    def bytes_per_pixel_num(self) -> tuple[int, int]:
        """(bytes, pixels) per packing group, e.g. (3, 2) for 12p."""
        return {"8": (1, 1), "16": (2, 1), "10p": (5, 4), "12p": (3, 2),
                "12packed": (3, 2), "10packed": (3, 2)}[self.packing]

    def frame_bytes(self, width: int, height: int) -> int:
        """Bytes of a frame of ``width`` x ``height`` pixels in this format."""
        channels = 4 if self.kind == "angles" else 1
        b, p = self.bytes_per_pixel_num
        n = width * height * channels
        return -(-n * b // p)


def _standard() -> list[PixelFormat]:
    fmts = [
        PixelFormat("Mono8", "*", 8, "8", "plain-mono", code=0x01080001),
        PixelFormat("Mono10", "*", 10, "16", "plain-mono", code=0x01100003),
        PixelFormat("Mono10p", "*", 10, "10p", "plain-mono", code=0x010A0046),
        PixelFormat("Mono10Packed", "*", 10, "10packed", "plain-mono", code=0x010C0004),
        PixelFormat("Mono12", "*", 12, "16", "plain-mono", code=0x01100005),
        PixelFormat("Mono12p", "*", 12, "12p", "plain-mono", code=0x010C0047),
        PixelFormat("Mono12Packed", "*", 12, "12packed", "plain-mono", code=0x010C0006),
        PixelFormat("Mono16", "*", 16, "16", "plain-mono", code=0x01100007),
    ]
    for order in ("RG", "BG", "GR", "GB"):
        fmts += [
            PixelFormat(f"Bayer{order}8", "*", 8, "8", "plain-bayer"),
            PixelFormat(f"Bayer{order}10", "*", 10, "16", "plain-bayer"),
            PixelFormat(f"Bayer{order}10p", "*", 10, "10p", "plain-bayer"),
            PixelFormat(f"Bayer{order}12", "*", 12, "16", "plain-bayer"),
            PixelFormat(f"Bayer{order}12p", "*", 12, "12p", "plain-bayer"),
            PixelFormat(f"Bayer{order}12Packed", "*", 12, "12packed", "plain-bayer"),
            PixelFormat(f"Bayer{order}16", "*", 16, "16", "plain-bayer"),
        ]
    return fmts


_BAYER_OF = {"RG": "RGGB", "BG": "BGGR", "GR": "GRBG", "GB": "GBRG"}
_MZR = LAYOUTS["imx250mzr"]


def _cfpa(order: str) -> str:
    return f"color:90,45,135,0:{_BAYER_OF[order]}"


def _vendors() -> list[PixelFormat]:
    lucid = "LUCID Vision Labs"
    flir = "FLIR"
    tis = "The Imaging Source Europe GmbH"
    fmts = [
        # LUCID Vision Labs (Arena, Phoenix/Triton polarization models)
        PixelFormat("PolarizeMono8", lucid, 8, "8", "polar-mono", _MZR, 0x81080001),
        PixelFormat("PolarizeMono12", lucid, 12, "16", "polar-mono", _MZR),
        PixelFormat("PolarizeMono12p", lucid, 12, "12p", "polar-mono", _MZR),
        PixelFormat("PolarizeMono12Packed", lucid, 12, "12packed", "polar-mono", _MZR),
        PixelFormat("PolarizeMono16", lucid, 16, "16", "polar-mono", _MZR),
        PixelFormat("PolarizedAngles_0d_45d_90d_135d_Mono8", lucid, 8, "8", "angles"),
        PixelFormat("PolarizedAngles_0d_45d_90d_135d_Mono12p", lucid, 12, "12p", "angles"),
        PixelFormat("PolarizedAngles_0d_45d_90d_135d_Mono16", lucid, 16, "16", "angles"),
        PixelFormat("PolarizedAngles_0d_45d_90d_135d_BayerRG8", lucid, 8, "8", "angles"),
        PixelFormat("PolarizedAngles_0d_45d_90d_135d_BayerRG12p", lucid, 12, "12p", "angles"),
        PixelFormat("PolarizedAngles_0d_45d_90d_135d_BayerRG16", lucid, 16, "16", "angles"),
        PixelFormat("PolarizedStokes_S0_S1_S2_S3_Mono8", lucid, 8, "8", "derived"),
        PixelFormat("PolarizedStokes_S0_S1_S2_Mono8", lucid, 8, "8", "derived"),
        PixelFormat("PolarizedDolp_Mono8", lucid, 8, "8", "derived"),
        PixelFormat("PolarizedAolp_Mono8", lucid, 8, "8", "derived"),
        PixelFormat("PolarizedDolpAolp_Mono8", lucid, 8, "8", "derived"),
        # FLIR / Teledyne (Blackfly S BFS-*-51S5P / 51S5PC)
        PixelFormat("Polarized8", flir, 8, "8", "polar-mono", _MZR),
        PixelFormat("Polarized10p", flir, 10, "10p", "polar-mono", _MZR),
        PixelFormat("Polarized12p", flir, 12, "12p", "polar-mono", _MZR),
        PixelFormat("Polarized16", flir, 16, "16", "polar-mono", _MZR),
        PixelFormat("BayerRGPolarized8", flir, 8, "8", "polar-color", _cfpa("RG")),
        PixelFormat("BayerRGPolarized10p", flir, 10, "10p", "polar-color", _cfpa("RG")),
        PixelFormat("BayerRGPolarized12p", flir, 12, "12p", "polar-color", _cfpa("RG")),
        PixelFormat("BayerRGPolarized16", flir, 16, "16", "polar-color", _cfpa("RG")),
        # The Imaging Source (DZK/DYK 33UX250 polarization models)
        PixelFormat("PolarizedMono8", tis, 8, "8", "polar-mono", _MZR, 0x8108000A),
        PixelFormat("PolarizedMono12p", tis, 12, "12p", "polar-mono", _MZR),
        PixelFormat("PolarizedMono16", tis, 16, "16", "polar-mono", _MZR),
        PixelFormat("PolarizedBayerBG8", tis, 8, "8", "polar-color", _cfpa("BG")),
        PixelFormat("PolarizedBayerBG12p", tis, 12, "12p", "polar-color", _cfpa("BG")),
        PixelFormat("PolarizedBayerBG16", tis, 16, "16", "polar-color", _cfpa("BG")),
    ]
    return fmts


#: Every pixel format polcam knows: (vendor or "*", name) -> PixelFormat.
PIXEL_FORMATS: dict[tuple[str, str], PixelFormat] = {
    (f.vendor, f.name): f for f in _standard() + _vendors()
}

#: Vendor names as cameras report DeviceVendorName (lower case), folded to one registry key.
VENDOR_ALIASES: dict[str, str] = {
    "lucid": "LUCID Vision Labs",
    "lucid vision labs": "LUCID Vision Labs",
    "lucid vision labs inc.": "LUCID Vision Labs",
    "flir": "FLIR",
    "flir systems": "FLIR",
    "teledyne flir": "FLIR",
    "teledyne flir llc": "FLIR",
    "point grey research": "FLIR",
    "the imaging source": "The Imaging Source Europe GmbH",
    "the imaging source europe gmbh": "The Imaging Source Europe GmbH",
    "baumer": "Baumer",
    "baumer optronic": "Baumer",
    "basler": "Basler",
}


def vendor_key(vendor: str | None) -> str | None:
    """The registry's vendor key for a camera's DeviceVendorName (None: no vendor given)."""
    if not vendor:
        return None
    v = vendor.strip().lower()
    if v in VENDOR_ALIASES:
        return VENDOR_ALIASES[v]
    for alias, key in VENDOR_ALIASES.items():
        if v.startswith(alias):
            return key
    return vendor.strip()


def pixel_format(name: str, vendor: str | None = None) -> PixelFormat:
    """Look up a pixel format by its name and the camera's vendor.

    Vendor-specific names are only found with their vendor (FLIR's
    ``Polarized8`` is not LUCID's); standard GenICam names (Mono8, BayerRG12p,
    ...) are found for every vendor.

    Raises
    ------
    PixelFormatError
        Unknown name for that vendor; the message lists the supported names.
    """
    key = vendor_key(vendor)
    if key is not None and (key, name) in PIXEL_FORMATS:
        return PIXEL_FORMATS[(key, name)]
    if ("*", name) in PIXEL_FORMATS:
        return PIXEL_FORMATS[("*", name)]
    if key is None:
        matches = [f for (v, n), f in PIXEL_FORMATS.items() if n == name]
        if len(matches) == 1:
            return matches[0]
        if matches:
            vendors = ", ".join(sorted(f.vendor for f in matches))
            raise PixelFormatError(
                f"pixel format {name!r} means different things at {vendors}: give the vendor"
            )
    owners = sorted({v for (v, n) in PIXEL_FORMATS if n == name})
    hint = f" (known for {', '.join(owners)})" if owners else ""
    raise PixelFormatError(
        f"pixel format {name!r} for vendor {vendor!r} is not supported{hint}; "
        f"supported: {', '.join(supported_pixel_formats(vendor))}"
    )


def supported_pixel_formats(vendor: str | None = None) -> list[str]:
    """Names of the pixel formats polcam reads, for one vendor or all."""
    key = vendor_key(vendor)
    return sorted({n for (v, n) in PIXEL_FORMATS if key is None or v in ("*", key)})


def layout_for_format(fmt: PixelFormat, layout: str | Layout | None = None) -> Layout:
    """The sensor layout of frames in format ``fmt``.

    ``layout`` (the user's ``--layout``) overrides the format's own and is
    required for plain Mono/Bayer formats.
    """
    if layout is not None:
        lay = parse_layout(layout)
        if fmt.kind == "plain-mono" and lay.is_color:
            raise LayoutError(
                f"layout {lay} is colour but pixel format {fmt.name} is monochrome"
            )
        return lay
    if fmt.kind in ("polar-mono", "polar-color"):
        assert fmt.layout is not None
        return parse_layout(fmt.layout)
    if fmt.kind == "angles":
        # re-interleaved by the reader into a 2x2 cell: 0 45 / 135 90
        if "Bayer" in fmt.name:
            order = fmt.name.split("Bayer")[1][:2]
            return parse_layout(f"color:0,45,135,90:{_BAYER_OF[order]}")
        return parse_layout("mono:0,45,135,90")
    if fmt.kind == "derived":
        raise PixelFormatError(
            f"pixel format {fmt.name} carries values computed in the camera, not a raw mosaic; "
            "capture a raw polarization format instead"
        )
    raise LayoutError(
        f"pixel format {fmt.name} does not say where the polarizers are: give --layout "
        f"({', '.join(LAYOUTS)}, 'mono:A,B,C,D' or 'color:A,B,C,D:BAYER')"
    )
