"""A 16-bit PNG of LIDAR returns: a dense map of units, times a depth scale in metres per unit;
its header's size checked, and its decoding work bounded, before it is decoded."""

from __future__ import annotations

import cv2
import numpy as np

from sdcnet.formats import PNG_SIGNATURE, FormatError, InputFormat, Reading
from sdcnet.formats.image_header import check_decoding_work, read_header


def depth_from_png16(image: np.ndarray, depth_scale: float) -> np.ndarray:
    """float32 (H, W) metres of a decoded 16-bit PNG's units times ``depth_scale`` (metres per
    unit); ``FormatError`` ``wrong_dtype`` for an image that is not single-channel 16-bit."""
    if image.dtype != np.uint16 or image.ndim != 2:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise FormatError(
            f"a sparse PNG must be single-channel 16-bit, got {channels}-channel {image.dtype}",
            "wrong_dtype",
        )
    return image.astype(np.float32) * np.float32(depth_scale)


def _parse(data: bytes, reading: Reading) -> np.ndarray:
    if reading.depth_scale is None:
        raise FormatError(
            "a 16-bit PNG sparse map needs depth_scale (metres per unit)",
            "invalid_request",
        )
    try:
        header = read_header(data)
        if reading.check_shape is not None:
            reading.check_shape((header.height, header.width))
        check_decoding_work(data, header)
    except FormatError as exc:
        raise FormatError(f"{reading.field}: {exc}", exc.code) from None
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None or image.shape[:2] != (header.height, header.width):
        raise FormatError(f"{reading.field}: cannot decode the PNG image (truncated or corrupt)")
    return depth_from_png16(image, reading.depth_scale)


FORMAT = InputFormat(
    name="16-bit PNG",
    carries={"map": "a 16-bit PNG with depth_scale (metres per unit)"},
    recognise=lambda data: data.startswith(PNG_SIGNATURE),
    parse=_parse,
    endings=(".sparse.png",),
    scaled=True,
)
