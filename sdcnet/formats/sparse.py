"""The files that carry a frame's LIDAR returns: a ``.npy`` (a dense map in metres, or an
(N, 3) list), a 16-bit PNG dense map (units times a depth scale in metres per unit) or a CSV
list (``sdcnet.returns.parse_returns_csv``), told apart by their first bytes."""

from __future__ import annotations

from typing import Literal

import numpy as np

from sdcnet.formats import NPY_MAGIC, PNG_SIGNATURE, FormatError

SparseFormat = Literal["npy", "png", "csv"]


def sparse_format(data: bytes) -> SparseFormat:
    """ "npy" or "png" from the file's magic bytes, else "csv" (text, checked as it is
    parsed)."""
    if data.startswith(NPY_MAGIC):
        return "npy"
    if data.startswith(PNG_SIGNATURE):
        return "png"
    return "csv"


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
