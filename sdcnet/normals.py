"""Surface normals of a completed frame: one unit vector per point of its cloud.

A normal from the frame's depth map by central differences of neighbouring pixels sees every
ripple the completion left between the returns, and one taken across a depth edge tilts towards
the line of sight (streaks along the rims of panels and dishes). The normals are estimated
instead on the working grid, from the surface the pipeline answered with
(``Completion.surface``, smoothed between the returns), with one-sided differences
``NORMAL_STEP_PX`` working pixels long: of a pixel's two sides along each axis, the one on the
mask, and of two on the mask, the one whose depth changes less (the side that does not cross an
edge), in closed form from the depth's two derivatives (``normal_directions``). They are then
smoothed by a guided filter (He and Sun) whose guide is the image the network saw
(``guided_normals``): a facet of the spacecraft lit alike is one plane, so within it the
normals are averaged over ``GUIDE_RADIUS_PX``, and where the shading changes (a fold, a
panel's rim) the filter follows the image instead of averaging across; what the surface got
wrong next to a depth edge is pulled towards the rest of its facet. Its fits weigh each pixel
by the inverse of its depth's variance (``fit_weights``, from the answer's sigma on the working
grid): a facet's normal is taken where its surface was measured (next to the returns, inside
the outline), not where the surface was guessed between them. All of it runs on the working
mask's box, a cost bounded by the working budget, and each point takes its working pixel's
normal.

Measured on the eight real spacecraft (mean angle to the true normals, ``make reports``'
frames): 19.2 degrees for the depth map's 3 x 3 central differences, 17.5 for the one-sided
differences, 15.7 guided by the image, 14.8 with the fits weighed by sigma
(docs/development.md, "Measurements").
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.pipeline import Completion, WorkingGrid
from sdcnet.pointcloud import BAND_PIXELS, on_lattice

#: Length of the one-sided differences, in working pixels: 1 follows the completion's
#: ripple, 3 is within 0.1 degree of any longer step on the real spacecraft (docs/development.md).
NORMAL_STEP_PX = 3
#: The guided filter's windows reach this many working pixels from their centre, ...
GUIDE_RADIUS_PX = 8
#: ... its regularisation is this variance of the guide, the image scaled to 0.5 at its
#: median on the mask (so that an 8-bit, a 12-bit and a dim frame are guided alike), ...
GUIDE_EPS = 1e-3
#: ... and its fits are made on a grid this many times coarser (a quarter of the pixels).
GUIDE_SUBSAMPLE = 2


def one_sided_difference(
    depth: np.ndarray, valid: np.ndarray, axis: int, step: int = NORMAL_STEP_PX
) -> np.ndarray:
    """(h, w): each pixel's depth difference (metres) to the pixel ``step`` ahead along
    ``axis`` (0 rows, 1 columns) or from the one as far behind: the side on ``valid`` (h, w
    bool) when only one is, else the side whose depth changes less; 0 where neither exists."""
    head = [slice(None)] * 2
    tail = [slice(None)] * 2
    head[axis], tail[axis] = slice(None, -step), slice(step, None)
    head_, tail_ = tuple(head), tuple(tail)
    ahead = np.zeros_like(depth)
    behind = np.zeros_like(depth)
    np.subtract(depth[tail_], depth[head_], out=ahead[head_])
    behind[tail_] = ahead[head_]
    valid_ahead = np.zeros_like(valid)
    valid_behind = np.zeros_like(valid)
    valid_ahead[head_] = valid[tail_]
    valid_behind[tail_] = valid[head_]
    use_ahead = np.abs(ahead) < np.abs(behind)
    use_ahead = np.where(valid_ahead != valid_behind, valid_ahead, use_ahead)
    return np.where(use_ahead, ahead, behind)


def normal_directions(
    depth: np.ndarray,
    mask: np.ndarray,
    grid: WorkingGrid,
    intrinsics: Intrinsics,
    origin: tuple[int, int] = (0, 0),
    step: int = NORMAL_STEP_PX,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The normals' x, y, z (each (h, w) float32, camera frame, facing the camera, not of unit
    length) of a working grid's depth (h, w metres; or of a window of it whose top-left working
    pixel is ``origin``, (row, column)) on its ``mask`` (h, w bool).

    For the pinhole point P = z ((u - cx) / fx, (v - cy) / fy, 1) of frame pixel (u, v), the
    cross product of dP/du and dP/dv is, up to a positive factor, (fx z_u, fy z_v,
    -(z + (u - cx) z_u + (v - cy) z_v)), which faces the camera wherever z > 0: only the
    depth's derivatives (per frame pixel, from ``one_sided_difference``) are needed."""
    scale_rows, scale_cols = grid.scale
    region = grid.region
    columns = np.arange(origin[1], origin[1] + depth.shape[1], dtype=np.float32)
    rows = np.arange(origin[0], origin[0] + depth.shape[0], dtype=np.float32)
    u = region.x0 + (columns + 0.5) / scale_cols - 0.5 - np.float32(intrinsics.cx)
    v = region.y0 + (rows + 0.5) / scale_rows - 0.5 - np.float32(intrinsics.cy)
    z_u = one_sided_difference(depth, mask, 1, step) * np.float32(scale_cols / step)
    z_v = one_sided_difference(depth, mask, 0, step) * np.float32(scale_rows / step)
    nz = -(depth + u * z_u + v[:, None] * z_v)
    return np.float32(intrinsics.fx) * z_u, np.float32(intrinsics.fy) * z_v, nz


def unit_vectors(vectors: tuple[np.ndarray, ...]) -> tuple[np.ndarray, ...]:
    """The x, y, z (each (h, w) float32) of ``vectors``' directions, of unit length."""
    x, y, z = vectors
    length = np.sqrt(x * x + y * y + z * z) + np.float32(1e-30)
    return x / length, y / length, z / length


def fit_weights(mask: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
    """(h, w) float32: each pixel's weight in the guided filter's fits, 0 off ``mask`` (h, w
    bool); on it 1 without ``sigma`` (h, w metres, the depth's uncertainty), else the inverse
    of its variance relative to the mask's median pixel's, (median / sigma)^2, so that the
    weighted sums stay near the unweighted ones in float32 (the fits do not change with a
    scale common to every weight)."""
    if sigma is None or not mask.any():
        return mask.astype(np.float32)
    # the median of every fourth row and column's: a sixteenth of the cost, as good a scale
    sample = sigma[::4, ::4][mask[::4, ::4]]
    typical = np.float32(max(float(np.median(sample if sample.size else sigma[mask])), 1e-9))
    floor = np.maximum(sigma, np.float32(1e-9) * typical)
    relative = np.divide(typical, floor, out=np.zeros_like(floor), where=mask)
    return relative * relative


def guided_normals(
    directions: tuple[np.ndarray, ...],
    gray: np.ndarray,
    mask: np.ndarray,
    sigma: np.ndarray | None = None,
    radius: int = GUIDE_RADIUS_PX,
    eps: float = GUIDE_EPS,
) -> tuple[np.ndarray, ...]:
    """The normals' x, y, z (each (h, w) float32, not of unit length) of ``directions`` on
    ``mask`` (h, w bool), smoothed by a guided filter whose guide is ``gray`` (h, w, the image
    on the same grid): in each window, each coordinate of the unit normals as a linear function
    of the gray level, fitted on the mask's pixels alone (the sky beside the spacecraft does
    not count), each weighed by the inverse of its depth's variance (``fit_weights`` of
    ``sigma``, h, w metres; alike without it), and the fits of the windows holding a pixel
    averaged there. The fits are made on a grid ``GUIDE_SUBSAMPLE`` times coarser and applied
    to the full grid's gray level (the fast guided filter: the same windows at a quarter of
    the pixels)."""
    median = float(np.median(gray[mask])) if mask.any() else 1.0
    guide = gray.astype(np.float32) * np.float32(0.5 / max(median, 1e-3))
    size = (
        max(1, -(-mask.shape[1] // GUIDE_SUBSAMPLE)),
        max(1, -(-mask.shape[0] // GUIDE_SUBSAMPLE)),
    )
    window = (2 * (radius // GUIDE_SUBSAMPLE) + 1,) * 2

    def coarse(values: np.ndarray) -> np.ndarray:
        return cv2.resize(values, size, interpolation=cv2.INTER_AREA)

    def sums(values: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(values, -1, window, normalize=False)

    weight = fit_weights(mask, sigma)
    share = coarse(weight)  # the weights' share of each coarse pixel
    present = share + np.float32(1e-6)
    small_guide = coarse(guide * weight) / present
    count = sums(share) + np.float32(1e-6)
    mean_guide = sums(small_guide * share) / count
    variance = sums(small_guide * small_guide * share) / count - mean_guide * mean_guide
    full = (mask.shape[1], mask.shape[0])
    out = []
    for values in unit_vectors(directions):
        small = coarse(values * weight) / present
        mean_values = sums(small * share) / count
        covariance = sums(small_guide * small * share) / count - mean_guide * mean_values
        slope = covariance / (variance + np.float32(eps))
        offset = mean_values - slope * mean_guide
        slope = cv2.resize(cv2.blur(slope, window), full, interpolation=cv2.INTER_LINEAR)
        offset = cv2.resize(cv2.blur(offset, window), full, interpolation=cv2.INTER_LINEAR)
        out.append(slope * guide + offset)
    return tuple(out)


def working_lookup(grid: WorkingGrid, frame_size: int, axis: int, first: int, size: int):
    """For each frame row (``axis`` 0) or column (1) of a frame ``frame_size`` pixels along it,
    the index (int32) of the working row or column it falls in, counted from ``first`` and
    clipped to the ``size`` from there: a table, so that a million points cost two lookups."""
    scale = grid.scale[axis]
    start = (grid.region.y0, grid.region.x0)[axis]
    frame = np.arange(frame_size, dtype=np.float64)
    working = np.floor((frame - start + 0.5) * scale).astype(np.int32) - first
    return np.clip(working, 0, size - 1)


@dataclass(frozen=True)
class WorkingNormals:
    """A completed frame's unit normals on the working mask's box, grown by a step (``unit``:
    (h * w, 3) float32, row-major), and for each frame row and column the box's row and column
    it falls in (``rows``, ``cols``: int32 tables, ``working_lookup``)."""

    unit: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    width: int

    @classmethod
    def of(cls, completion: Completion, intrinsics: Intrinsics) -> WorkingNormals:
        """The normals of ``completion``'s surface on its working mask's box."""
        mask = completion.working_mask
        x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
        y0, x0 = max(y - NORMAL_STEP_PX, 0), max(x - NORMAL_STEP_PX, 0)
        box = np.s_[y0 : y + h + NORMAL_STEP_PX, x0 : x + w + NORMAL_STEP_PX]
        depth = completion.surface[box]
        directions = normal_directions(depth, mask[box], completion.grid, intrinsics, (y0, x0))
        sigma = None if completion.working_sigma is None else completion.working_sigma[box]
        guided = guided_normals(directions, completion.working_gray[box], mask[box], sigma)
        unit = np.stack(unit_vectors(guided), axis=-1).reshape(-1, 3)
        height, width = completion.mask.shape
        rows = working_lookup(completion.grid, height, 0, y0, depth.shape[0])
        cols = working_lookup(completion.grid, width, 1, x0, depth.shape[1])
        return cls(unit, rows, cols, depth.shape[1])

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 3) float32: the normals at frame pixels ``rows``, ``cols``, each its working
        pixel's (a pixel beyond the box takes the nearest of the box's)."""
        return self.unit[self.rows[rows] * np.int32(self.width) + self.cols[cols]]


def normals_at(
    completion: Completion, rows: np.ndarray, cols: np.ndarray, intrinsics: Intrinsics
) -> np.ndarray:
    """(N, 3) float32 unit normals, camera frame, facing the camera, of a completed frame at
    its pixels ``rows``, ``cols`` (frame pixels): each the normal of the working pixel it falls
    in, on the second look's grid beyond the first crop where the frame had one
    (``Completion.beyond``)."""
    normals = WorkingNormals.of(completion, intrinsics).at(rows, cols)
    if completion.beyond is not None:
        outside = ~completion.grid.region.holds(rows, cols)
        beyond = WorkingNormals.of(completion.beyond, intrinsics)
        normals[outside] = beyond.at(rows[outside], cols[outside])
    return normals


def cloud_normals(
    completion: Completion,
    pixels: np.ndarray,
    intrinsics: Intrinsics,
    band_pixels: int = BAND_PIXELS,
    stride: int = 1,
) -> np.ndarray:
    """(N, 3) float32 unit normals of a completed frame at the True pixels of ``pixels`` (H, W
    bool) on every ``stride``-th row and column from the frame's first, in row-major order:
    those of the points ``back_project`` makes of them (pixels of depth > 0). Found
    ``band_pixels`` at a time, so that beside the answer a million points cost a band's
    indices, and taken straight into the answer (``np.take`` into its rows: 15 -> 7 ms for a
    million points, against an indexed copy then a second one). A frame with a second look
    (``Completion.beyond``) takes ``normals_at``'s two grids, pixel by pixel."""
    pixels = on_lattice(pixels, stride)
    if completion.beyond is not None:
        rows, cols = np.nonzero(pixels)  # on the lattice: frame pixels ``stride`` times these
        return normals_at(completion, rows * stride, cols * stride, intrinsics)
    normals = WorkingNormals.of(completion, intrinsics)
    x0, y0, width, height = cv2.boundingRect(pixels.view(np.uint8))
    out = np.empty((int(np.count_nonzero(pixels)), 3), np.float32)
    step = max(1, band_pixels // max(width, 1))
    at = 0
    rows, columns = normals.rows[::stride], normals.cols[::stride][x0 : x0 + width]
    for y in range(y0, y0 + height, step):
        chosen = pixels[y : y + step, x0 : x0 + width]
        # each pixel of the band's index into the box's normals, then the chosen ones'
        index = (rows[y : y + step, None] * np.int32(normals.width) + columns)[chosen]
        np.take(normals.unit, index, axis=0, out=out[at : at + len(index)])
        at += len(index)
    return out


def normal_map(completion: Completion, intrinsics: Intrinsics) -> np.ndarray:
    """(H, W, 3) float32: the normals of a completed frame on its mask, 0 off it."""
    out = np.zeros((*completion.mask.shape, 3), np.float32)
    rows, cols = np.nonzero(completion.mask)
    out[rows, cols] = normals_at(completion, rows, cols, intrinsics)
    return out
