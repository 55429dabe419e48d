"""A CSV text file of LIDAR returns (``sdcnet.returns.parse_returns_csv``): the header
``row,col,z_m``, one return per line; its lines counted before they are parsed, a block at a
time. Any bytes no other format recognises are tried as one (text is checked as it is
parsed), so it comes last in ``sdcnet.formats.sparse.FORMATS``."""

from __future__ import annotations

import numpy as np

from sdcnet.formats import FormatError, InputFormat, Reading
from sdcnet.returns import ReturnsError, parse_returns_csv


def _parse(data: bytes, reading: Reading) -> np.ndarray:
    try:
        return parse_returns_csv(data, reading.field, reading.check_shape)
    except ReturnsError as exc:
        if exc.code == "not_text":
            raise FormatError(str(exc), "unsupported_media_type") from None
        raise


FORMAT = InputFormat(
    name="CSV",
    carries={"list": "a CSV text file (UTF-8) with the header row,col,z_m"},
    recognise=lambda data: True,
    parse=_parse,
    endings=(".csv",),
)
