"""Stray LIDAR returns: returns alone in the sky, far from the spacecraft's.

A real LIDAR's frame holds returns that are not the target's: a flash array's dark counts
and solar background, a scanner's multipath and dust. One such return in the sky, far from
the spacecraft, makes the crop the network sees (``sdcnet.pipeline.spacecraft_region``, the
returns' box) many times larger and so many times coarser, and the pre-fill spreads it into a
blob of its own that it then vouches for. On the robustness suite's frames with 3 returns
added at random pixels off the spacecraft (``benchmarks.stray_returns``), IOU fell up to 10.2
points (wide-multibeam 81.1 -> 70.9, earth 90.7 -> 81.7); with the strays left out here, at
most 2.5 (docs/development.md, "Measurements").

Returns join one group when a chain of returns links them, each within ``STRAY_SPACINGS``
return spacings of the next (on a grid of cells: within 1.5 times that at most,
``return_groups``); the returns of a group of fewer than ``MIN_GROUP_RETURNS`` are strays. The
spacing (``sdcnet.returns.return_spacing``) is measured on the largest group of returns at a
coarse scale (``main_group``) so that the strays themselves do not widen it, and it follows the
LIDAR's pattern, so the same rule holds for a scanning grid, a multi-beam's rows and a flash
array. A frame with fewer than ``MIN_RETURNS_TO_JUDGE`` returns, or where more than
``MAX_STRAY_SHARE`` of them would be strays (a pattern too sparse to judge), keeps every
return: there strays cannot be told from a small part's returns. A part of the spacecraft hit
by one or two returns far from every other is taken for strays.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from sdcnet.returns import return_pixels, return_spacing

#: Returns this many return spacings apart (or nearer) join one group.
STRAY_SPACINGS = 4.0
#: Frames with fewer returns keep them all: a few returns cannot tell a stray from a part.
MIN_RETURNS_TO_JUDGE = 20
#: Where more than this share of the returns would be strays, every return is kept.
MAX_STRAY_SHARE = 0.5
#: Returns in a group of fewer (joined within ``STRAY_SPACINGS`` of each other) are strays.
MIN_GROUP_RETURNS = 3
#: The groups of ``main_group``: returns in cells of 1/``GROUP_CELLS`` of the frame's longer
#: side, cells that touch joined.
GROUP_CELLS = 32
#: The strays' groups are found on at most this many cells a side.
MAX_CELLS = 512


def return_groups(
    rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int], cell: int, reach_cells: int
) -> tuple[np.ndarray, np.ndarray]:
    """The groups of the returns at pixel ``rows``, ``cols`` of a frame of ``shape``: the frame
    cut into square cells of ``cell`` pixels, two returns in one group when a chain of returns
    joins them whose cells lie at most ``2 * reach_cells + 1`` cells apart (each cell holding
    returns grown by ``reach_cells``, then 8-connected). Returns each return's group label and
    the returns in each group (indexed by label)."""
    cell_rows, cell_cols = rows // cell, cols // cell
    height, width = shape[0] // cell + 1, shape[1] // cell + 1
    counts = np.bincount(cell_rows * width + cell_cols, minlength=height * width)
    occupied = (counts > 0).astype(np.uint8).reshape(height, width)
    if reach_cells:
        side = 2 * reach_cells + 1
        occupied = cv2.dilate(occupied, np.ones((side, side), np.uint8))
    n, labels = cv2.connectedComponents(occupied, connectivity=8)
    per_group = np.bincount(labels.ravel(), weights=counts, minlength=n).astype(np.int64)
    return labels[cell_rows, cell_cols], per_group


def main_group(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """bool per return (pixel ``rows``, ``cols`` of a frame of ``shape``): whether it belongs
    to the group holding the most returns, in cells of 1/``GROUP_CELLS`` of the frame's
    longer side that touch (``return_groups``). Strays far from the spacecraft fall in groups
    of their own."""
    labels, per_group = return_groups(rows, cols, shape, max(1, max(shape) // GROUP_CELLS), 0)
    return labels == int(np.argmax(per_group))


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
    # cells of a quarter of the reach (at most MAX_CELLS a side): every return within the
    # reach of another joins it, none beyond 1.5 times the reach
    reach = STRAY_SPACINGS * spacing
    cell = max(1, int(reach // 4), math.ceil(max(shape) / MAX_CELLS))
    labels, per_group = return_groups(rows, cols, shape, cell, math.ceil((reach / cell - 1) / 2))
    strays = per_group[labels] < MIN_GROUP_RETURNS
    if np.count_nonzero(strays) > MAX_STRAY_SHARE * len(rows):
        return none
    return strays


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
