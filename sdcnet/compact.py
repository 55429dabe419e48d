"""Compact layouts of an answer's depth and mask, and the way back to full-frame arrays.

A 1024 x 1024 answer is 4 MiB of float32 depth and 1 MiB of mask, nearly all zeros: the
network sees only the region its LIDAR returns bound (``sdcnet.pipeline.Region``), the mask is
0 outside it, and the depth is 0 off the mask. The service sends, where a client asks for it:

- **region**: the arrays cut to the spacecraft's region, the smallest window that holds the
  mask (``mask_window``), with its offset (row ``y0``, column ``x0``); everything outside it
  is 0 by construction, so pasting them into zeros gives the full frame back exactly;
- **bits**: the mask as ``numpy.packbits`` of its row-major pixels (8 per byte, first pixel in
  the high bit): exact;
- **fp16**: depth as float16 residuals above an offset (the nearest depth, metres), -1 where
  the depth is 0 (a residual is never negative; NaN would not survive JSON). Lossy: a
  residual r is kept to 2^-11 of r, so depths within 32 m of the nearest come back within
  8 mm (within 16 mm up to 64 m deep; a spacecraft is < 30 m).

The service (``sdcnet.service``) makes these layouts, the client (``sdcnet.client``) undoes
them; both use this module, so the two ends cannot disagree.
"""

from __future__ import annotations

import numpy as np


def mask_window(mask: np.ndarray, y0: int = 0, x0: int = 0) -> tuple[int, int, int, int]:
    """(y0, x0, height, width) of the smallest window of ``mask`` holding all its True
    pixels, offset by (``y0``, ``x0``) (where ``mask`` lies in a larger frame); an empty
    mask gives an empty window at the offset."""
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return y0, x0, 0, 0
    return (
        y0 + int(rows[0]),
        x0 + int(cols[0]),
        int(rows[-1] - rows[0]) + 1,
        int(cols[-1] - cols[0]) + 1,
    )


def crop(array: np.ndarray, y0: int, x0: int, height: int, width: int) -> np.ndarray:
    """The ``height`` x ``width`` window of ``array`` whose top-left pixel is (y0, x0)."""
    return array[y0 : y0 + height, x0 : x0 + width]


def paste(window: np.ndarray, y0: int, x0: int, shape: tuple[int, int]) -> np.ndarray:
    """A zero array of ``shape`` with ``window`` at (y0, x0): the inverse of ``crop`` for an
    array that is 0 outside the window. Raises ``ValueError`` if it does not fit."""
    height, width = window.shape[:2]
    if y0 < 0 or x0 < 0 or y0 + height > shape[0] or x0 + width > shape[1]:
        raise ValueError(
            f"a {height} x {width} window at ({y0}, {x0}) does not fit a {shape} frame"
        )
    full = np.zeros(shape, window.dtype)
    full[y0 : y0 + height, x0 : x0 + width] = window
    return full


def pack_mask(mask: np.ndarray) -> np.ndarray:
    """uint8 bytes of a (h, w) mask, 8 pixels each (row-major, first pixel in the high bit)."""
    return np.packbits(np.asarray(mask, bool), axis=None)


def unpack_mask(bits: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The bool (h, w) mask of ``pack_mask``'s bytes. Raises ``ValueError`` when the byte
    count does not match ``shape``."""
    pixels = shape[0] * shape[1]
    if bits.size != -(-pixels // 8):
        raise ValueError(f"{bits.size} mask bytes cannot hold {shape[0]} x {shape[1]} pixels")
    return np.unpackbits(bits, count=pixels).reshape(shape).astype(bool)


#: The float16 residual of a pixel without depth.
NO_DEPTH = -1.0


def fp16_residuals(depth: np.ndarray) -> tuple[np.ndarray, float]:
    """float16 residuals of a float32 depth map above its nearest non-zero depth (metres),
    ``NO_DEPTH`` where the depth is 0, and that offset (0.0 when there is no depth at all)."""
    present = depth != 0
    offset = np.float32(depth[present].min()) if present.any() else np.float32(0)
    residuals = np.full(depth.shape, NO_DEPTH, np.float16)
    residuals[present] = (depth[present] - offset).astype(np.float16)
    return residuals, float(offset)


def depth_from_fp16(residuals: np.ndarray, offset: float) -> np.ndarray:
    """float32 depth (metres, 0 where the residual is ``NO_DEPTH``) of ``fp16_residuals``."""
    depth = np.float32(offset) + residuals.astype(np.float32)
    depth[residuals < 0] = 0
    return depth
