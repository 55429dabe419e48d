"""The type and declared size of an image file, from its header alone, and a bound on the work
its decoding would take.

The service checks an upload's pixel count against its limit before it decodes anything, so a
small file declaring a huge image (a decompression bomb) costs nothing. Only the four formats
the service accepts are recognised: PNG, TIFF (classic, first page), JPEG and BMP.

A file within the pixel limit can still make its decoder work far beyond its size:
``check_decoding_work`` refuses a PNG whose image data inflates beyond what its declared size
needs (libpng inflates the excess too: a 1 MB file of zeros costs seconds) and a JPEG of more
scans than any encoder writes (each progressive scan goes over the whole frame again).
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass

from sdcnet.formats import PNG_SIGNATURE, FormatError

_TIFF_WIDTH, _TIFF_LENGTH = 256, 257
_TIFF_SHORT, _TIFF_LONG = 3, 4
# JPEG start-of-frame markers: C0-CF except DHT (C4), JPG (C8) and DAC (CC).
_JPEG_SOF = {0xC0 + i for i in range(16)} - {0xC4, 0xC8, 0xCC}
_JPEG_STANDALONE = {0x01, *range(0xD0, 0xDA)}  # TEM, RSTn, SOI, EOI: no length field
#: Markers read before the frame header at most. A real file has a handful (APPn, DQT, DHT,
#: COM...); without a bound, megabytes of fill bytes or restart markers would cost seconds of
#: Python per upload.
_JPEG_MAX_MARKERS = 256
_JPEG_FILL = re.compile(rb"\xff+")
#: Scans a JPEG may hold: libjpeg's progressive scripts write 6 (gray) to 10 (colour), plus
#: those of an embedded thumbnail. 0xFF 0xDA appears nowhere else (0xFF is stuffed in scans).
_JPEG_MAX_SCANS = 100
_JPEG_SOS = b"\xff\xda"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # by colour type
_INFLATE_STEP = 2**20  # bytes inflated at a time while the PNG data is measured


class HeaderError(FormatError):
    """The header of an accepted image format is broken (code ``unreadable_file``)."""


class UnknownFormatError(HeaderError):
    """The bytes are none of the accepted image formats."""

    code = "unsupported_media_type"


@dataclass(frozen=True)
class ImageHeader:
    format: str  # "png", "tiff", "jpeg" or "bmp"
    width: int  # pixels
    height: int  # pixels

    @property
    def pixels(self) -> int:
        return self.width * self.height


def sniff_format(data: bytes) -> str | None:
    """'png', 'tiff', 'jpeg', 'bmp' from the file's magic bytes, else None."""
    if data.startswith(PNG_SIGNATURE):
        return "png"
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return "tiff"
    if data.startswith(b"\xff\xd8\xff"):
        return "jpeg"
    if data.startswith(b"BM"):
        return "bmp"
    return None


def read_header(data: bytes) -> ImageHeader:
    """Format and declared size of an image; raises HeaderError."""
    kind = sniff_format(data)
    if kind is None:
        raise UnknownFormatError("not a PNG, TIFF, JPEG or BMP file")
    try:
        width, height = {"png": _png, "tiff": _tiff, "jpeg": _jpeg, "bmp": _bmp}[kind](data)
    except (struct.error, IndexError) as exc:
        raise HeaderError(f"truncated {kind.upper()} header") from exc
    if width <= 0 or height <= 0:
        raise HeaderError(f"{kind.upper()} header declares a {width} x {height} image")
    return ImageHeader(kind, width, height)


def check_decoding_work(data: bytes, header: ImageHeader) -> None:
    """Raise HeaderError when decoding ``data`` would take far more work than ``header``'s
    size needs (see the module doc); cheap next to the decoding itself."""
    try:
        if header.format == "png":
            _check_png_data(data, header)
    except (struct.error, IndexError) as exc:
        raise HeaderError("truncated PNG header") from exc
    if header.format == "jpeg" and data.count(_JPEG_SOS) > _JPEG_MAX_SCANS:
        raise HeaderError(f"JPEG holds more than {_JPEG_MAX_SCANS} scans")


def _png_data_limit(data: bytes, header: ImageHeader) -> int:
    """Bytes the image data of a PNG inflates to at most: a filter byte and the packed pixels
    per row; Adam7 interlacing's passes add rows (below 3x plus 1 kB for any size)."""
    depth, colour, interlaced = data[24], data[25], data[28]
    if colour not in _PNG_CHANNELS or depth not in (1, 2, 4, 8, 16):
        raise HeaderError(f"PNG header declares bit depth {depth} with colour type {colour}")
    raw = header.height * (1 + -(-header.width * _PNG_CHANNELS[colour] * depth // 8))
    return (3 if interlaced else 1) * raw + 1024


def _check_png_data(data: bytes, header: ImageHeader) -> None:
    limit = _png_data_limit(data, header)
    max_chunks = 4096 + limit // 1024  # encoders write IDAT chunks of 8 kB or more
    view = memoryview(data)
    inflater = zlib.decompressobj()
    inflated, at = 0, len(PNG_SIGNATURE)
    for _ in range(max_chunks):
        if at + 8 > len(data):
            return
        (length,) = struct.unpack_from(">I", data, at)
        kind = data[at + 4 : at + 8]
        if kind == b"IEND":
            return
        if kind == b"IDAT":
            pending = view[at + 8 : at + 8 + length]
            try:
                while pending and inflated <= limit:
                    inflated += len(inflater.decompress(pending, _INFLATE_STEP))
                    pending = inflater.unconsumed_tail
            except zlib.error:
                raise HeaderError("PNG image data is corrupt: it does not inflate") from None
            if inflated > limit:
                raise HeaderError(
                    f"PNG image data inflates beyond the {limit} bytes its declared "
                    f"{header.width} x {header.height} pixels need (a decompression bomb?)"
                )
        at += 12 + length
    raise HeaderError(f"PNG has more than {max_chunks} chunks")


def _png(data: bytes) -> tuple[int, int]:
    if data[12:16] != b"IHDR":
        raise HeaderError("PNG file does not start with an IHDR chunk")
    return struct.unpack(">II", data[16:24])


def _tiff(data: bytes) -> tuple[int, int]:
    order = "<" if data[:2] == b"II" else ">"
    (ifd,) = struct.unpack(order + "I", data[4:8])
    (entries,) = struct.unpack(order + "H", data[ifd : ifd + 2])
    size = {}
    for i in range(entries):
        tag, kind, _, value = struct.unpack(
            order + "HHI4s", data[ifd + 2 + 12 * i : ifd + 14 + 12 * i]
        )
        if tag in (_TIFF_WIDTH, _TIFF_LENGTH):
            if kind not in (_TIFF_SHORT, _TIFF_LONG):
                raise HeaderError("TIFF image size has an unexpected type")
            fmt = order + ("H" if kind == _TIFF_SHORT else "I")
            size[tag] = struct.unpack(fmt, value[: struct.calcsize(fmt)])[0]
    if len(size) != 2:
        raise HeaderError("TIFF first page declares no width and length")
    return size[_TIFF_WIDTH], size[_TIFF_LENGTH]


def _jpeg(data: bytes) -> tuple[int, int]:
    i = 2
    for _ in range(_JPEG_MAX_MARKERS):
        if data[i] != 0xFF:
            raise HeaderError("JPEG marker expected")
        i = _JPEG_FILL.match(data, i).end()  # fill bytes, skipped without a Python loop
        marker = data[i]
        i += 1
        if marker in _JPEG_STANDALONE:
            continue
        (length,) = struct.unpack(">H", data[i : i + 2])
        if marker in _JPEG_SOF:
            height, width = struct.unpack(">HH", data[i + 3 : i + 7])
            return width, height
        if marker == 0xDA:  # start of scan before any frame header
            raise HeaderError("JPEG has no frame header")
        i += length
    raise HeaderError(f"JPEG has no frame header within its first {_JPEG_MAX_MARKERS} markers")


def _bmp(data: bytes) -> tuple[int, int]:
    (dib,) = struct.unpack("<I", data[14:18])
    if dib == 12:  # BITMAPCOREHEADER: unsigned 16-bit sizes
        return struct.unpack("<HH", data[18:22])
    width, height = struct.unpack("<ii", data[18:26])
    return width, abs(height)  # negative height: rows stored top-down
