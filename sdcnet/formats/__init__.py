"""Every input and wire format the service and the client both read or write, in one place:
the magic bytes below, and the parsers in the modules of this package. A parser raises
``FormatError`` with a stable ``code``; the service answers it in its error shape
(``sdcnet.service.errors.format_error``), the client raises its own ``InputError``.

- ``sdcnet.formats.image_header``: an image file's type and declared size from its header, and
  a bound on the work its decoding would take (PNG, TIFF, JPEG, BMP);
- ``sdcnet.formats.sparse``: the files that hold a frame's LIDAR returns, one
  ``InputFormat`` each (``sdcnet.formats.npy``, ``.png16``, ``.csv_returns``), in a registry
  the service and the client both read;
- ``sdcnet.formats.v2``: the Open Inference Protocol's binary tensors (header, datatypes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

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


@dataclass(frozen=True)
class Reading:
    """How to read one file of returns: ``field`` starts the messages; ``check_shape(shape)``
    runs on the shape the file declares (its header, or its lines counted) before its values
    are read, and raises to refuse it (a service bounds untrusted files so); ``depth_scale``:
    metres per unit, for a format of units."""

    field: str
    check_shape: Callable[[tuple[int, ...]], None] | None = None
    depth_scale: float | None = None


@dataclass(frozen=True)
class InputFormat:
    """A file format of LIDAR returns. ``carries``: what it holds, ``"map"`` (dense (H, W)
    metres, 0 = no return) and/or ``"list"`` ((N, 3) row, col, z_m), each with a line that
    describes it; ``recognise(data)``: whether the first bytes are this format's;
    ``parse(data, reading)``: float32 metres, raising ``FormatError`` (code
    ``unsupported_media_type`` for bytes that are not this format after all) or
    ``sdcnet.returns.ReturnsError``; ``endings``: its file names' endings; ``scaled``: it
    holds units, times ``depth_scale`` metres per unit."""

    name: str
    carries: dict[str, str]
    recognise: Callable[[bytes], bool]
    parse: Callable[[bytes, Reading], np.ndarray]
    endings: tuple[str, ...]
    scaled: bool = False
