"""The type and declared size of an image file, from its header alone.

The service checks an upload's pixel count against its limit before it decodes anything, so a
small file declaring a huge image (a decompression bomb) costs nothing. Only the four formats
the service accepts are recognised: PNG, TIFF (classic, first page), JPEG and BMP.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_TIFF_WIDTH, _TIFF_LENGTH = 256, 257
_TIFF_SHORT, _TIFF_LONG = 3, 4
# JPEG start-of-frame markers: C0-CF except DHT (C4), JPG (C8) and DAC (CC).
_JPEG_SOF = {0xC0 + i for i in range(16)} - {0xC4, 0xC8, 0xCC}
_JPEG_STANDALONE = {0x01, *range(0xD0, 0xDA)}  # TEM, RSTn, SOI, EOI: no length field


class HeaderError(ValueError):
    """The header of an accepted image format is broken."""


class UnknownFormatError(HeaderError):
    """The bytes are none of the accepted image formats."""


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
    while True:
        if data[i] != 0xFF:
            raise HeaderError("JPEG marker expected")
        while data[i] == 0xFF:  # fill bytes
            i += 1
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


def _bmp(data: bytes) -> tuple[int, int]:
    (dib,) = struct.unpack("<I", data[14:18])
    if dib == 12:  # BITMAPCOREHEADER: unsigned 16-bit sizes
        return struct.unpack("<HH", data[18:22])
    width, height = struct.unpack("<ii", data[18:26])
    return width, abs(height)  # negative height: rows stored top-down
