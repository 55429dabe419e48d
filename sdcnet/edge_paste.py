"""The depth of a shrunk crop's frame pixels along the working grid's depth edges.

Where the working grid shrank the crop (a large spacecraft close to a 2048-px camera: four
frame pixels a working pixel and more), each frame pixel takes the depth of the working pixel
under its centre (``sdcnet.pipeline.nearest_resampled``). Along a depth edge, a boom before
a panel, that working pixel may lie across the edge from the frame pixel: the frame's outline
is finer than the grid's, and the network's depth there is one surface's or between the two.
The classical fill, which copies the nearest return, keeps such edges; on the 2048-px docking
frames the network's answer was worse than the fill's 3 to 10 pixels from a return.

So where the surface steps (``edge_pixels``: its second difference above ``STEP_FOOTPRINTS``
pixel footprints, not where it slopes, however steeply), each
working pixel offers its frame pixels two depths, one of each side of the step: of the 3 x 3
working pixels around it, the nearer and the farther surface's (split at the middle of their
depths) that costs least by

- ``DISTANCE_WEIGHT`` per working pixel from the centre, and
- ``RETURN_WEIGHT`` per step (the spread of the 3 x 3 pixels' depths) between its depth
  and that of the return nearest the working pixel, over 1 + that return's distance in
  working pixels: a return close by says which surface is there, one farther away less so;

and each frame pixel takes the one whose cost plus the difference between its gray and the
frame pixel's own is least (joint bilateral upsampling's guide: a boom lit unlike the panel
behind it), in the guide's units (the gray scaled to 0.5 at the returns' median, so that an
8-bit, a 12-bit and a dim frame weigh alike).

Chosen on the docking-2048 frames (docs/development.md, "Measurements").
"""

from __future__ import annotations

import cv2
import numpy as np

#: A step: the surface's second difference above this many pixel footprints ...
STEP_FOOTPRINTS = 4.0
#: Cost of a candidate per working pixel between its centre and the working pixel's ...
DISTANCE_WEIGHT = 0.05
#: ... and per step (the 3 x 3 pixels' spread) between its depth and the nearest return's
#: (module docstring).
RETURN_WEIGHT = 1.0
#: Most working pixels of a frame's steps drawn at the frame's pixels (the strongest steps):
#: a bound on the cost (the suite's frames have up to about 15,000, but one `any` frame of a
#: dense LIDAR 62,693 with the diagonals counted).
MAX_EDGE_PIXELS = 16384
#: The 3 x 3 candidates, (row, column) offsets in working pixels, and their distances.
OFFSETS = np.array([(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
OFFSET_PX = np.hypot(OFFSETS[:, 0], OFFSETS[:, 1]).astype(np.float32)
#: The axes a step is looked for along, rows and columns, as kernels of the second
#: difference (the diagonals too: the same answers within 1 mm a band on docking-2048, 1.6 ms
#: more a frame at the median).
STEP_KERNELS = (
    np.array([[1, -2, 1]], np.float32),
    np.array([[1], [-2], [1]], np.float32),
)


def edge_pixels(
    surface: np.ndarray, mask: np.ndarray, edge_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """The rows and columns (E,) of the mask's working pixels where ``surface`` (h, w) float32
    metres steps: its second difference along a row or a column (both neighbours on the
    mask) above ``edge_m`` metres. A plane, however steep, has none. At most
    ``MAX_EDGE_PIXELS``: those of the largest steps."""
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    on = mask[y : y + h, x : x + w].view(np.uint8)
    depth = surface[y : y + h, x : x + w]
    found = np.zeros_like(on)
    seconds = []
    for kernel in STEP_KERNELS:
        second = cv2.absdiff(cv2.filter2D(depth, -1, kernel, borderType=cv2.BORDER_REPLICATE), 0)
        # both neighbours on the mask: the mask eroded by the axis's three pixels
        inside = cv2.erode(on, (kernel != 0).astype(np.uint8), borderValue=0)
        cv2.bitwise_or(found, cv2.compare(second, edge_m, cv2.CMP_GT) & inside, dst=found)
        seconds.append((second, inside))
    rows, cols = np.nonzero(found)
    if len(rows) > MAX_EDGE_PIXELS:
        strength = np.max([step[rows, cols] * inside[rows, cols] for step, inside in seconds], 0)
        strongest = np.argpartition(strength, -MAX_EDGE_PIXELS)[-MAX_EDGE_PIXELS:]
        rows, cols = rows[strongest], cols[strongest]
    return rows + y, cols + x


def two_sides(
    rows: np.ndarray,
    cols: np.ndarray,
    surface: np.ndarray,
    mask: np.ndarray,
    guide: np.ndarray,
    return_depth: np.ndarray,
    return_px: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the working pixels at ``rows``, ``cols`` (E,), the nearer and the farther side's
    candidate (module docstring): depth (metres), guide gray and cost, (2, E) float32 each,
    the nearer side's first. ``return_depth`` and ``return_px`` (h, w): the depth (metres) of
    the return nearest each working pixel and its distance (working pixels).

    The 3 x 3 candidates lie along the first axis, (9, E): each step below is then a pass
    over E values per candidate, where reductions along a last axis of 9 (``np.min`` with
    ``where``, ``np.argmin``) cost a call per pixel: 7.1 -> 4.0 ms for 16,384 edge pixels."""
    height, width = surface.shape
    at = rows * width + cols
    # (9, E) flat indices of the 3 x 3 around each, those past the grid's side on it
    candidates = np.clip(rows + OFFSETS[:, :1], 0, height - 1) * width
    candidates += np.clip(cols + OFFSETS[:, 1:], 0, width - 1)
    depth = surface.ravel().take(candidates)
    on = mask.ravel().take(candidates)
    nearest = np.where(on, depth, np.inf).min(axis=0)
    farthest = np.where(on, depth, -np.inf).max(axis=0)
    # the return's term in units of the step, fading with the return's distance
    weight = np.float32(RETURN_WEIGHT) / ((farthest - nearest) * (1.0 + return_px.ravel()[at]))
    cost = np.abs(depth - return_depth.ravel()[at])
    cost *= weight
    cost += (DISTANCE_WEIGHT * OFFSET_PX)[:, None]
    nearer = depth <= 0.5 * (nearest + farthest)
    picks = np.stack(
        [
            first_least(np.where(nearer & on, cost, np.inf)),
            first_least(np.where(nearer | ~on, np.inf, cost)),
        ]
    )
    chosen = np.take_along_axis(candidates, picks, 0)
    return (
        surface.ravel().take(chosen),
        guide.ravel().take(chosen),
        np.take_along_axis(cost, picks, 0),
    )


def first_least(values: np.ndarray) -> np.ndarray:
    """(E,) intp: for each column of ``values`` (K, E), the first row holding its least value
    (``np.argmin`` along the first axis for values without NaN, at a pass per row rather than
    a reduction along a short axis)."""
    least = values[0].copy()
    index = np.zeros(values.shape[1], np.intp)
    for row in range(1, len(values)):
        np.copyto(index, row, where=values[row] < least)
        np.minimum(least, values[row], out=least)
    return index


def frame_pixels_under(
    rows: np.ndarray, cols: np.ndarray, frame_rows: np.ndarray, frame_cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame pixels under the working pixels at ``rows``, ``cols`` (E,): their rows and
    columns in the window and the index (0..E-1) of the working pixel each lies under.
    ``frame_rows`` (H,) and ``frame_cols`` (W,), non-decreasing: the working row and column
    under each of the window's rows and columns."""
    first_row, row_count = frame_run(frame_rows, rows)
    first_col, col_count = frame_run(frame_cols, cols)
    span_y, span_x = int(row_count.max(initial=0)), int(col_count.max(initial=0))
    dy = np.arange(span_y)[None, :, None]
    dx = np.arange(span_x)[None, None, :]
    inside = (dy < row_count[:, None, None]) & (dx < col_count[:, None, None])
    owner, iy, ix = np.nonzero(inside)
    return first_row[owner] + iy, first_col[owner] + ix, owner


def frame_run(frame_index: np.ndarray, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each working row (or column) of ``index`` (E,), the first of the window's rows
    (columns) under it and how many: ``frame_index`` (H,), non-decreasing, the working row
    under each of the window's. Looked up in a table of every working row's first (a search
    per working row, in order, rather than one per pixel of ``index``, in no order: 1.8 ->
    0.05 ms for 16,384 edge pixels' columns)."""
    firsts = np.searchsorted(frame_index, np.arange(int(index.max(initial=-1)) + 2), "left")
    first = firsts[index]
    return first, firsts[index + 1] - first


def paste_across_edges(
    depth: np.ndarray,
    frame_rows: np.ndarray,
    frame_cols: np.ndarray,
    frame_gray: np.ndarray,
    frame_gain: float,
    surface: np.ndarray,
    mask: np.ndarray,
    guide: np.ndarray,
    return_depth: np.ndarray,
    return_px: np.ndarray,
    footprint_m: float,
) -> None:
    """Set ``depth`` (H, W) float32 metres, a shrunk crop's frame pixels (or a window of them)
    pasted by nearest neighbour, along the working grid's depth edges (module docstring), in
    place. ``frame_rows`` (H,) and ``frame_cols`` (W,): the working row and column under each
    of its rows and columns; ``frame_gray`` (H, W), the frame's pixels (any dtype), and
    ``frame_gain``, what turns them into the guide's units, in which ``guide`` (h, w) float32
    is the working grid's gray; ``surface`` (h, w) float32 metres and ``mask`` (h, w) bool:
    what was pasted; ``return_depth`` and ``return_px`` (h, w): the depth (metres) of the
    return nearest each working pixel and its distance (working pixels:
    ``sdcnet.anchoring.nearest_return``); ``footprint_m`` a working pixel's footprint in
    metres. Frame pixels off the mask (``depth`` 0) stay so."""
    rows, cols = edge_pixels(surface, mask, STEP_FOOTPRINTS * footprint_m)
    if not len(rows):
        return
    side_depth, side_guide, side_cost = two_sides(
        rows, cols, surface, mask, guide, return_depth, return_px
    )
    ys, xs, owner = frame_pixels_under(rows, cols, frame_rows, frame_cols)
    on = depth[ys, xs] > 0
    ys, xs, owner = ys[on], xs[on], owner[on]
    own_guide = frame_gray[ys, xs] * np.float32(frame_gain)
    near = side_cost[0, owner] + np.abs(side_guide[0, owner] - own_guide)
    far = side_cost[1, owner] + np.abs(side_guide[1, owner] - own_guide)
    depth[ys, xs] = np.where(far < near, side_depth[1, owner], side_depth[0, owner])
