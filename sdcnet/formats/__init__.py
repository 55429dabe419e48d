"""Every input and wire format the service and the client both read or write, in one place:
the magic bytes below, and the parsers in the modules of this package. A parser raises
``FormatError`` with a stable ``code``; the service answers it in its error shape
(``sdcnet.service.errors.format_error``), the client raises its own ``InputError``.

- ``sdcnet.formats.image_header``: an image file's type and declared size from its header, and
  a bound on the work its decoding would take (PNG, TIFF, JPEG, BMP);
- ``sdcnet.formats.npy``: ``.npy`` bytes of floats, read in place, never unpickled;
- ``sdcnet.formats.sparse``: which file holds the LIDAR returns (``.npy``, 16-bit PNG, CSV)
  and a 16-bit PNG's units as metres;
- ``sdcnet.formats.v2``: the Open Inference Protocol's binary tensors (header, datatypes).

The CSV of returns is parsed by ``sdcnet.returns.parse_returns_csv``, beside the other
conversions of returns.
"""

from __future__ import annotations

NPY_MAGIC = b"\x93NUMPY"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class FormatError(ValueError):
    """Bytes that are not the format they must be. ``code`` names the problem for the
    service's error answers: ``unsupported_media_type`` (not a format taken here),
    ``unreadable_file`` (the format, broken), ``pickle_not_allowed``, ``wrong_dtype``,
    ``wrong_shape``, ``invalid_request`` (the format with an option it does not take)."""

    code = "unreadable_file"

    def __init__(self, message: str, code: str | None = None):
        super().__init__(message)
        if code is not None:
            self.code = code
