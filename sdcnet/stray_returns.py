"""Stray LIDAR returns: returns alone in the sky, far from the spacecraft's.

A real LIDAR's frame holds returns that are not the target's: a flash array's dark counts
and solar background, a scanner's multipath and dust. One such return in the sky, far from
the spacecraft, makes the crop the network sees (``sdcnet.pipeline.spacecraft_region``, the
returns' box) many times larger and so many times coarser, and the pre-fill spreads it into a
blob of its own that it then vouches for. On the robustness suite's frames with 3 returns
added at random sky pixels (a scratch script through ``sdcnet.pipeline.complete``), IOU fell
1.3-14 points (earth 90.7 -> 82.7, narrow-far 90.3 -> 76.3, flash 81.3 -> 69.1); left out as
strays here, 0.2-3.6 points (docs/development.md, "Measurements").

A return is a stray when no other return lies within ``STRAY_SPACINGS`` return spacings of it
(a square window, in pixels), the spacing (``sdcnet.returns.return_spacing``) measured on
the largest group of returns (``main_group``) so that the strays themselves do not widen it.
The spacing follows the LIDAR's pattern, so the same rule holds for a scanning grid, a
multi-beam's rows and a flash array. A frame with fewer than ``MIN_RETURNS_TO_JUDGE``
returns, or where more than ``MAX_STRAY_SHARE`` of them would be strays (a pattern too sparse
to judge), keeps every return: there the strays cannot be told from a small part's returns.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from sdcnet.returns import return_pixels, return_spacing

#: A return with no other within this many return spacings (a square window) is a stray.
STRAY_SPACINGS = 4.0
#: Frames with fewer returns keep them all: a few returns cannot tell a stray from a part.
MIN_RETURNS_TO_JUDGE = 20
#: Where more than this share of the returns would be strays, every return is kept.
MAX_STRAY_SHARE = 0.5
#: The groups of ``main_group``: returns in cells of 1/``GROUP_CELLS`` of the frame's longer
#: side, cells that touch joined.
GROUP_CELLS = 32


def main_group(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """bool per return (pixel ``rows``, ``cols`` of a frame of ``shape``): whether it belongs
    to the group holding the most returns, the frame cut into square cells of
    1/``GROUP_CELLS`` of its longer side and the cells holding returns joined where they touch
    (8-connected). Strays far from the spacecraft fall in groups of their own."""
    cell = max(1, max(shape) // GROUP_CELLS)
    cell_rows, cell_cols = rows // cell, cols // cell
    height, width = shape[0] // cell + 1, shape[1] // cell + 1
    ids = cell_rows * width + cell_cols
    counts = np.bincount(ids, minlength=height * width).reshape(height, width)
    n, labels = cv2.connectedComponents((counts > 0).astype(np.uint8), connectivity=8)
    per_group = np.bincount(labels.ravel(), weights=counts.ravel(), minlength=n)
    per_group[0] = 0  # the cells without returns
    return labels[cell_rows, cell_cols] == int(np.argmax(per_group))


def neighbours_within(
    rows: np.ndarray, cols: np.ndarray, half_px: float, shape: tuple[int, int]
) -> np.ndarray:
    """The returns (the return's own included) in a square window of about ``half_px`` pixels
    each side of each return (pixel ``rows``, ``cols`` of a frame of ``shape``), int per return.
    Counted on cells of a quarter of the window's half-size, so that a dense LIDAR's frame
    costs a coarse grid's filter: the window holds every return within ``half_px`` and none
    beyond 1.25 times it."""
    cell = max(1, int(half_px // 4))
    cell_rows, cell_cols = rows // cell, cols // cell
    height, width = shape[0] // cell + 1, shape[1] // cell + 1
    counts = np.bincount(cell_rows * width + cell_cols, minlength=height * width)
    side = 2 * math.ceil(half_px / cell) + 1
    window = cv2.boxFilter(
        counts.reshape(height, width).astype(np.float32),
        -1,
        (side, side),
        normalize=False,
        borderType=cv2.BORDER_CONSTANT,
    )
    return np.rint(window[cell_rows, cell_cols]).astype(np.int64)


def stray_returns(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """bool per return (pixel ``rows``, ``cols`` of a frame of ``shape``): whether it is a
    stray (the module's rule); all False where the frame's returns cannot be judged."""
    none = np.zeros(len(rows), bool)
    if len(rows) < MIN_RETURNS_TO_JUDGE:
        return none
    group = main_group(rows, cols, shape)
    spacing = return_spacing(rows[group], cols[group])
    if spacing is None:
        return none
    alone = neighbours_within(rows, cols, STRAY_SPACINGS * spacing, shape) < 2
    if np.count_nonzero(alone) > MAX_STRAY_SHARE * len(rows):
        return none
    return alone


def without_strays(sparse: np.ndarray) -> tuple[np.ndarray, int]:
    """``sparse`` (H, W metres, 0 where no return) without its stray returns
    (``stray_returns``), and how many were left out; ``sparse`` itself where none was."""
    rows, cols = return_pixels(sparse)
    strays = stray_returns(rows, cols, sparse.shape)
    count = int(np.count_nonzero(strays))
    if not count:
        return sparse, 0
    kept = sparse.copy()
    kept[rows[strays], cols[strays]] = 0
    return kept, count
