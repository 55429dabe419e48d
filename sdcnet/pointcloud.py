"""Point clouds from dense depth: back-projection, statistical outlier removal, binary PLY.

Shared by the service (which builds the cloud) and the client (which writes and reads it).
Points are float32 (N, 3) in the camera frame of ``sdcnet.camera`` (x right, y down, z forward),
metres, in row-major pixel order.

Statistical outlier removal (SOR) is the filter the paper applies before showing its clouds
(Fig. 7) and before pose estimation: for every point, the mean distance to its ``k`` nearest
neighbours; points whose mean lies beyond ``mean + std_ratio * std`` of all points are dropped,
and so are points with no neighbour at all. A k-d tree over a million points costs seconds, so
the neighbours are searched on the organised pixel grid instead: the candidates of a pixel are
the valid pixels in the (2r + 1) x (2r + 1) window around it, and the k nearest of those in 3-D
are kept. On a depth image that is a sound stand-in for a true k-nearest search, because two
points that are close in space project to nearby pixels (a pixel holds one visible surface), and
at an occlusion boundary the window still holds enough of the point's own surface for its k
nearest. Like any SOR it also drops points whose neighbours are sparse for the cloud: surfaces
seen at grazing angles (on our renders of clean ground truth, 2-3 % of the foreground).
It is vectorised over the grid: O(N (2r + 1)^2), ~0.3 s for a million points on two cores.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np

from sdcnet.camera import Intrinsics

#: Default grid half-window (pixels), neighbours per point and threshold of the outlier filter.
SOR_RADIUS = 2
SOR_NEIGHBOURS = 8
SOR_STD_RATIO = 2.0

_PLY_DTYPE = np.dtype("<f4")


#: Pixels of a frame processed at a time by ``back_project`` and ``statistical_outliers``:
#: their memory follows this, not the frame (a 4096 x 4096 mask of 16.7M points took gigabytes
#: whole).
BAND_PIXELS = 2**17


def _bands(height: int, width: int, band_pixels: int) -> range:
    """First rows of the bands of whole rows, ``band_pixels`` pixels or fewer each."""
    return range(0, height, max(1, band_pixels // max(width, 1)))


def mask_pixels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols), int64 in row-major order, of the True pixels of a 2-D boolean ``mask``:
    what ``np.nonzero`` gives, from one flat scan (ten times faster on a 2048 x 2048 frame:
    11 ms against 1)."""
    return np.divmod(np.flatnonzero(mask), mask.shape[1])


def back_project(
    depth: np.ndarray,
    mask: np.ndarray,
    intrinsics: Intrinsics,
    band_pixels: int = BAND_PIXELS,
    stride: int = 1,
) -> np.ndarray:
    """(N, 3) float32 camera-frame points (metres) of the ``mask`` pixels with depth > 0 on
    every ``stride``-th row and column from the frame's first (``cloud_stride``), in
    row-major order, computed ``band_pixels`` at a time (beside the points themselves).

    ``depth`` is camera-frame Z in metres (H, W); ``mask`` is a boolean (H, W) selection.
    Only the mask's bounding box is visited, and in each band the points' depths and pixel
    coordinates are selected first and computed on alone (float64, stored as float32): 14 ->
    9.5 ms for a million points of a 2048 x 2048 box, against the whole band computed and then
    selected, and 14 for each point's pixel gathered.
    """
    depth, mask = depth[::stride, ::stride], on_lattice(mask, stride)
    x0, y0, width, height = cv2.boundingRect(mask.view(np.uint8))
    box = (slice(y0, y0 + height), slice(x0, x0 + width))
    depth = depth[box]
    valid = mask[box] & (depth > 0)
    step = _bands(height, width, band_pixels).step
    counts = [int(np.count_nonzero(valid[y : y + step])) for y in range(0, height, step)]
    points = np.empty((sum(counts), 3), np.float32)
    u = np.arange(x0, x0 + width, dtype=np.float64) * stride - intrinsics.cx
    v = np.arange(y0, y0 + height, dtype=np.float64)[:, None] * stride - intrinsics.cy
    at = 0
    for y, count in zip(range(0, height, step), counts, strict=True):
        keep = valid[y : y + step]
        z = depth[y : y + step][keep]
        band = points[at : at + count]
        band[:, 2] = z
        z = z.astype(np.float64)
        band[:, 0] = np.broadcast_to(u, keep.shape)[keep] * z / intrinsics.fx
        band[:, 1] = np.broadcast_to(v[y : y + step], keep.shape)[keep] * z / intrinsics.fy
        at += count
    return points


#: A cloud holds at most this many points (``sdc-serve --max-points``): a larger mask's cloud
#: takes every k-th pixel of its rows and columns (``cloud_stride``). The points' own work
#: (back-projection and normals, about 20 ms a million on 2 threads) then stays within a
#: frame's budget however large its mask: a 2048 x 2048 frame at docking range holds 1-2M
#: (docs/development.md, "Measurements"). The depth map, mask and sigma stay whole.
MAX_POINTS = 2**19


def cloud_stride(pixels: np.ndarray, max_points: int) -> int:
    """The smallest stride k (pixels) such that the True pixels of ``pixels`` (bool (H, W))
    on every k-th row and column from the frame's first (``on_lattice``) number at most
    ``max_points`` (>= 1)."""
    stride = max(1, math.ceil(math.sqrt(np.count_nonzero(pixels) / max_points)))
    while np.count_nonzero(pixels[::stride, ::stride]) > max_points:
        stride += 1
    return stride


def on_lattice(image: np.ndarray, stride: int) -> np.ndarray:
    """``image``'s pixels on every ``stride``-th row and column from its first, contiguous,
    for OpenCV, which takes no strided columns; ``image`` itself at stride 1."""
    return image if stride == 1 else np.ascontiguousarray(image[::stride, ::stride])


#: Without ``max_sigma``, a cloud to register keeps the points whose sigma is within this
#: quantile of the frame's: leaving the 10 % most uncertain out (flying pixels between
#: surfaces, far from any return) cuts the depth's MAE of the rest by 30 % or more, and the
#: model's sigma is calibrated for that (docs/service.md). ``POST /pose`` and ``sdc-eval
#: pose`` both register such clouds.
POSE_SIGMA_QUANTILE = 0.9


def trusted_pixels(
    valid: np.ndarray, sigma: np.ndarray | None, max_sigma: float | None, quantile: float | None
) -> tuple[np.ndarray, float | None]:
    """The ``valid`` pixels (H, W) whose sigma (metres) is within the limit, and the limit:
    ``max_sigma`` when given, else, with a ``quantile`` (0..1), that quantile of the valid
    pixels' sigma (the frame's own scale: 0.9 leaves the 10 % most uncertain out), else none
    (every valid pixel; also without a sigma)."""
    if sigma is None:
        return valid, None
    limit = max_sigma
    if limit is None and quantile is not None and valid.any():
        limit = float(np.quantile(sigma[valid], quantile))
    return (valid if limit is None else valid & (sigma <= limit)), limit


def point_pixels(points: np.ndarray, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols), int64, of the pixels ``back_project`` made (N, 3) camera-frame points
    (metres, z > 0) from: their projections, rounded. Exact for float32 points of frames up
    to tens of thousands of pixels a side (a projection lands within 0.01 px of its pixel)."""
    points = np.asarray(points, np.float64)
    z = points[:, 2]
    cols = np.rint(points[:, 0] * intrinsics.fx / z + intrinsics.cx).astype(np.int64)
    rows = np.rint(points[:, 1] * intrinsics.fy / z + intrinsics.cy).astype(np.int64)
    return rows, cols


def statistical_outliers(
    depth: np.ndarray,
    mask: np.ndarray,
    intrinsics: Intrinsics,
    radius: int = SOR_RADIUS,
    neighbours: int = SOR_NEIGHBOURS,
    std_ratio: float = SOR_STD_RATIO,
    band_pixels: int = BAND_PIXELS,
) -> np.ndarray:
    """Boolean (H, W): the pixels of ``mask & (depth > 0)`` that the outlier filter keeps.

    A point's score is the mean 3-D distance (metres) to its ``neighbours`` nearest valid pixels
    within ``radius`` pixels on the grid (fewer where fewer exist); points
    scoring above ``mean + std_ratio * std`` over all points, or with no neighbour, are outliers.
    The scores are computed for bands of rows of about ``band_pixels`` pixels at a time: the
    memory beyond the answer is that of a band and of one score per point.
    """
    if radius < 1 or neighbours < 1:
        raise ValueError("radius and neighbours must be at least 1")
    valid = mask & (depth > 0)
    keep = np.zeros_like(valid)
    occupied_rows = np.flatnonzero(valid.any(axis=1))
    if len(occupied_rows) == 0:
        return keep
    occupied_cols = np.flatnonzero(valid.any(axis=0))
    # Each band of rows [a, b) is scored on a grid of its rows and the radius around them, by
    # the valid pixels' columns padded by the radius (w wide from x0).
    x0 = int(occupied_cols[0]) - radius
    w = int(occupied_cols[-1]) + radius + 1 - x0
    step = max(1, band_pixels // w)
    bands = range(int(occupied_rows[0]), int(occupied_rows[-1]) + 1, step)
    scores, counts = [], []
    for a in bands:
        rows, cols = mask_pixels(valid[a : a + step])
        box = (a - radius, a + step + radius, x0, w)
        score, count = _band_scores(
            valid, depth, rows + a, cols, box, intrinsics, radius, neighbours
        )
        scores.append(score)
        counts.append(count.astype(np.uint8))
    score, count = np.concatenate(scores), np.concatenate(counts)
    scored = score[count > 0]
    if len(scored) == 0:
        return keep
    limit = scored.mean() + std_ratio * scored.std()
    kept = (count > 0) & (score <= limit)
    at = 0
    for a in bands:  # the same pixels, in the same order
        rows, cols = mask_pixels(valid[a : a + step])
        chosen = kept[at : at + len(rows)]
        keep[rows[chosen] + a, cols[chosen]] = True
        at += len(rows)
    return keep


def _band_scores(
    valid: np.ndarray,
    depth: np.ndarray,
    rows: np.ndarray,
    cols: np.ndarray,
    grid_box: tuple[int, int, int, int],
    intrinsics: Intrinsics,
    radius: int,
    neighbours: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Mean distance (metres) of the points at ``rows``, ``cols`` to their ``neighbours``
    nearest ``valid`` pixels within ``radius``, and how many there were, on the grid of the
    frame's rows ``top`` to ``bottom`` and the ``w`` columns from ``left`` (``grid_box``,
    pixels, maybe outside the frame), where every neighbour of the points lies. The grid is
    flattened, so that a neighbour is an index offset: the one at +offset of pixel p is
    p + offset, the one at -offset is pixel p - offset's neighbour at +offset, so half the
    offsets give all distances."""
    top, bottom, left, w = grid_box
    r = radius
    n = (bottom - top) * w
    grid = np.zeros((4, n + r * w + r), np.float32)  # x, y, z (metres), valid; zero padding
    first_row, first_col = max(top, 0), max(left, 0)
    ys, xs = mask_pixels(valid[first_row:bottom, first_col : left + w])
    ys, xs = ys + first_row, xs + first_col
    z = depth[ys, xs].astype(np.float32)
    where = (ys - top) * w + (xs - left)
    grid[0, where] = (xs - intrinsics.cx) / intrinsics.fx * z
    grid[1, where] = (ys - intrinsics.cy) / intrinsics.fy * z
    grid[2, where] = z
    grid[3, where] = 1
    index = (rows - top) * w + (cols - left)
    here = grid[:, :n]
    half = [dy * w + dx for dy in range(r + 1) for dx in range(-r, r + 1) if dy or dx > 0]
    distances = np.empty((len(index), 2 * len(half)), np.float32)
    for i, offset in enumerate(half):
        there = grid[:, offset : offset + n]
        delta = there[:3] - here[:3]
        dist = np.sqrt(np.einsum("ij,ij->j", delta, delta))
        dist[(there[3] == 0) | (here[3] == 0)] = np.inf
        distances[:, 2 * i] = dist[index]
        distances[:, 2 * i + 1] = dist[index - offset]
    nearest = np.sort(distances, axis=1)[:, :neighbours]
    found = np.isfinite(nearest)
    count = found.sum(axis=1)
    score = np.where(found, nearest, 0).sum(axis=1) / np.maximum(count, 1)
    return score, count


#: The coordinates every vertex of sdcnet's PLY files starts with (float32, metres).
XYZ = ("x", "y", "z")


def ply_header(
    count: int,
    comments: tuple[str, ...] | list[str] = (),
    properties: tuple[str, ...] = (),
) -> bytes:
    """The header of a binary little-endian PLY of ``count`` vertices: float32 x, y, z
    (metres), then one float32 per name of ``properties`` (e.g. ``sigma``, metres). The file
    is this, then the vertices' bytes (``ply_vertices``); readers that ignore properties they
    do not know read the x, y, z of such a file as of one without them."""
    lines = ["ply", "format binary_little_endian 1.0"]
    for comment in comments:
        if "\n" in comment or "\r" in comment:
            raise ValueError("a PLY comment must be one line")
        lines.append(f"comment {comment}")
    names = (*XYZ, *properties)
    for name in properties:
        if not name.isidentifier() or names.count(name) > 1:
            raise ValueError(f"{name!r} cannot be a PLY property: a new identifier is needed")
    lines.append(f"element vertex {count}")
    lines += [f"property float {name}" for name in names]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii")


def ply_vertices(points: np.ndarray, properties: tuple[np.ndarray, ...] = ()) -> np.ndarray:
    """(N, 3 + k) little-endian float32 rows: each point's x, y, z (metres) then its value of
    each of the k ``properties`` ((N,) arrays, in ``ply_header``'s order): the vertex data of
    a PLY. Raises ``ValueError`` for points that are not (N, 3) or properties not (N,)."""
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    for values in properties:
        if np.shape(values) != (len(points),):
            raise ValueError(f"a property must hold one value per point, got {np.shape(values)}")
    rows = np.empty((len(points), 3 + len(properties)), _PLY_DTYPE)
    rows[:, :3] = points
    for k, values in enumerate(properties):
        rows[:, 3 + k] = values
    return rows


def ply_bytes(
    points: np.ndarray,
    comments: tuple[str, ...] | list[str] = (),
    properties: dict[str, np.ndarray] | None = None,
) -> bytes:
    """Binary little-endian PLY of (N, 3) points (float32 x, y, z; metres) and, per point, the
    float32 values of ``properties`` (name -> (N,) array, e.g. ``{"sigma": ...}``)."""
    properties = properties or {}
    vertices = ply_vertices(points, tuple(properties.values()))
    return ply_header(len(vertices), comments, tuple(properties)) + vertices.tobytes()


def write_ply(
    path: str | Path,
    points: np.ndarray,
    comments: tuple[str, ...] = (),
    properties: dict[str, np.ndarray] | None = None,
) -> Path:
    """Write ``points`` (and their ``properties``, as ``ply_bytes``) as a binary PLY file;
    returns its path."""
    path = Path(path)
    path.write_bytes(ply_bytes(points, comments, properties))
    return path


@dataclass(frozen=True)
class PlyCloud:
    """A PLY file's points (N, 3) float32 metres, its header comments and the values of its
    other vertex properties (name -> (N,) float32), in the file's order."""

    points: np.ndarray
    comments: list[str]
    properties: dict[str, np.ndarray]


def read_ply(source: str | Path | bytes | BinaryIO) -> PlyCloud:
    """The cloud of a binary little-endian PLY with one vertex element of float x, y, z and
    any further float properties: the layout ``ply_bytes`` writes. Raises ValueError for
    anything else."""
    if isinstance(source, bytes):
        stream: BinaryIO = io.BytesIO(source)
    elif isinstance(source, str | Path):
        stream = io.BytesIO(Path(source).read_bytes())
    else:
        stream = source
    if stream.readline().rstrip(b"\r\n") != b"ply":
        raise ValueError("not a PLY file: it does not start with 'ply'")
    comments: list[str] = []
    fields: list[str] = []
    count = None
    while True:
        raw = stream.readline()
        if not raw:
            raise ValueError("PLY header has no end_header")
        line = raw.decode("ascii", errors="replace").strip()
        keyword, _, rest = line.partition(" ")
        if keyword == "end_header":
            break
        if keyword == "comment":
            comments.append(rest)
        elif keyword == "format":
            if rest.split()[:1] != ["binary_little_endian"]:
                raise ValueError(f"unsupported PLY format {rest!r}: binary_little_endian only")
        elif keyword == "element":
            name, _, size = rest.partition(" ")
            if name != "vertex" or count is not None:
                raise ValueError(f"unsupported PLY element {rest!r}: one vertex element only")
            count = int(size)
        elif keyword == "property":
            fields.append(rest)
        elif keyword != "obj_info":
            raise ValueError(f"unexpected PLY header line {line!r}")
    kinds = [field.partition(" ")[0] for field in fields]
    names = [field.partition(" ")[2] for field in fields]
    unique = len(set(names)) == len(names)
    if count is None or names[:3] != list(XYZ) or set(kinds) != {"float"} or not unique:
        raise ValueError(f"unsupported PLY layout: vertex {count} with properties {fields}")
    width = len(fields) * _PLY_DTYPE.itemsize
    data = stream.read(count * width)
    if len(data) != count * width:
        raise ValueError(f"PLY data is truncated: {count} vertices announced")
    vertices = np.frombuffer(data, _PLY_DTYPE).reshape(count, len(fields)).astype(np.float32)
    extra = {name: vertices[:, 3 + k].copy() for k, name in enumerate(names[3:])}
    return PlyCloud(np.ascontiguousarray(vertices[:, :3]), comments, extra)
