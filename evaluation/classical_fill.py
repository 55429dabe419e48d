"""The classical morphological fill: the baseline every depth figure is compared against.

IP-Basic-like (Ku et al. 2018): depth is inverted so that near surfaces win every max, then
dilated, closed twice (gaps, then holes) and smoothed over the filled pixels; the mask is the
filled pixels. Its kernels follow the returns' spacing, measured on each frame
(``return_spacing``): on the paper's LIDAR (returns ~18 px apart vertically, ~12.5 px
horizontally) it works at a quarter of the resolution with the kernels tuned there (dilate
5 x 3, close 5 x 5, fill holes 9 x 9, blur 3), and on another LIDAR with the same kernels
measured in return spacings, so that it stays a fair baseline on a flash array or a 16-beam
sensor. It never looks at the image.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.spatial import cKDTree

INVERT_M = 1000.0  # depths are inverted as INVERT_M - d: valid depths stay positive
#: Kernels in return spacings (rows, columns): the paper's LIDAR's tuned working-resolution
#: kernels times its factor (4) over its spacing (18, 12.5) px.
DILATE = (20 / 18, 12 / 12.5)
CLOSE = (20 / 18, 20 / 12.5)
HOLES = (36 / 18, 36 / 12.5)
#: Working resolution: the factor that puts the smaller spacing about this many pixels apart.
SPACING_AT_WORK_PX = 3.1
#: Neighbours searched for the nearest along and across the rows: enough for rows 30 times
#: farther apart than the returns along them.
NEIGHBOURS = 64


def return_spacing(rows: np.ndarray, cols: np.ndarray) -> tuple[float, float]:
    """Typical distance (pixels) between neighbouring returns along the columns and along the
    rows: (vertical, horizontal). Among each return's ``NEIGHBOURS`` nearest, the nearest
    that lies more across than along a row is its vertical neighbour, the nearest more along
    its horizontal one, whether rows are straight (a scanner, a flash array) or curved (a
    rotating multi-beam sensor) and however much denser along the rows; the median over the
    returns that have one. NaN for fewer than 2 returns."""
    if len(rows) < 2:
        return float("nan"), float("nan")
    points = np.stack([rows, cols], 1).astype(np.float64)
    k = min(NEIGHBOURS, len(points) - 1) + 1
    distance, index = cKDTree(points).query(points, k=k)
    step = points[index[:, 1:]] - points[:, None, :]  # (N, k - 1, 2): dy, dx
    vertical = np.abs(step[..., 0]) > np.abs(step[..., 1])
    spacing = []
    for along in (vertical, ~vertical):
        d = np.where(along, distance[:, 1:], np.inf).min(axis=1)
        d = d[np.isfinite(d)]
        spacing.append(float(np.median(d)) if d.size else float("nan"))
    return spacing[0], spacing[1]


def _odd(pixels: float) -> int:
    return max(1, 2 * round((pixels - 1) / 2) + 1)


def _kernel(spacings: tuple[float, float], per_spacing: tuple[float, float], factor: int):
    """A rectangle (rows, columns) of ``per_spacing`` return spacings at the working factor."""
    size = [_odd(s * k / factor) for s, k in zip(spacings, per_spacing, strict=True)]
    return cv2.getStructuringElement(cv2.MORPH_RECT, (size[1], size[0]))


def _near_wins_downsample(sparse: np.ndarray, factor: int) -> np.ndarray:
    """Inverted depth (INVERT_M - d, 0 = none) at 1/``factor`` resolution, the nearest return
    of each block winning; the map is padded with zeros to whole blocks."""
    H, W = sparse.shape
    pad = ((0, -H % factor), (0, -W % factor))
    inverted = np.where(sparse > 0, INVERT_M - sparse, 0).astype(np.float32)
    blocks = np.pad(inverted, pad).reshape(
        (H + pad[0][1]) // factor, factor, (W + pad[1][1]) // factor, factor
    )
    return blocks.max(axis=(1, 3))


def classical_fill(sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) float32 metres, 0 = unfilled, and mask (H, W) bool of a sparse map (metres,
    0 = no return), kernels following the returns' spacing."""
    rows, cols = np.nonzero(sparse > 0)
    if len(rows) == 0:
        return np.zeros(sparse.shape, np.float32), np.zeros(sparse.shape, bool)
    spacings = return_spacing(rows, cols)
    if not all(math.isfinite(s) for s in spacings):  # a lone return, or returns on one line
        known = [s for s in spacings if math.isfinite(s)]
        spacings = (known[0], known[0]) if known else (1.0, 1.0)
    factor = max(1, round(min(spacings) / SPACING_AT_WORK_PX))
    x = _near_wins_downsample(sparse, factor)
    x = cv2.dilate(x, _kernel(spacings, DILATE, factor))
    for per_spacing in (CLOSE, HOLES):
        kernel = _kernel(spacings, per_spacing, factor)
        x = cv2.erode(cv2.dilate(x, kernel), kernel)
    valid = (x > 0).astype(np.float32)
    total = cv2.blur(x, (3, 3), borderType=cv2.BORDER_CONSTANT)
    count = cv2.blur(valid, (3, 3), borderType=cv2.BORDER_CONSTANT)
    filled = np.where(valid > 0, INVERT_M - total / np.maximum(count, 1e-6), 0).astype(np.float32)
    H, W = sparse.shape
    depth = np.repeat(np.repeat(filled, factor, 0), factor, 1)[:H, :W]
    return np.ascontiguousarray(depth), depth > 0
