"""LIDAR returns as a list: one row per return, ``(row, column, Z in metres)``, float32.

The dense sparse map (H x W float32, 0 = no return) carries ~150 returns of a 1024 x 1024
frame in 4 MiB; the list carries them in 12 bytes each. Both describe the same thing and
convert exactly both ways:

- rows and columns are integer pixel indices (0-based, row down, column right), stored as
  float32 so that one array holds a return (exact up to 2^24 pixels);
- Z is the camera-frame depth in metres, finite, > 0 and at most ``MAX_DEPTH_M``;
- several returns on one pixel: the nearest (smallest Z) wins it, as
  ``sdcnet.pipeline.resample_sparse`` decides when it moves returns to a coarser grid.

On disk, a CSV file with the header ``row,col,z_m`` and one return per line, e.g.
``examples/<name>.returns.csv``.
"""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

CSV_HEADER = ("row", "col", "z_m")
#: The farthest depth accepted, metres: far beyond any proximity LIDAR's range. A larger value
#: is damage (a flipped bit in a float32 gives 1e30 and more), and its square would overflow
#: the float32 arithmetic of the uncertainty.
MAX_DEPTH_M = 1e5


class ReturnsError(ValueError):
    """Returns that cannot describe a frame; ``code`` names the problem for the service's
    error answers (``wrong_shape``, ``wrong_dtype``, ``invalid_depth``, ``invalid_returns``,
    ``no_returns``)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def scatter_nearest(
    rows: np.ndarray, cols: np.ndarray, z: np.ndarray, shape: tuple[int, int]
) -> np.ndarray:
    """Dense float32 map of ``shape``: ``z`` metres at (``rows``, ``cols``), the smallest where
    several land on one pixel, 0 elsewhere. Indices must lie inside ``shape``."""
    out = np.full(shape, np.inf, np.float32)
    np.minimum.at(out, (rows, cols), z.astype(np.float32))
    out[np.isinf(out)] = 0
    return out


def _first(bad: np.ndarray) -> int:
    """Index of the first return (row of ``bad``) that fails a check."""
    return int(np.flatnonzero(bad.reshape(len(bad), -1).any(axis=1))[0])


def check_returns(returns: np.ndarray, shape: tuple[int, int] | None = None) -> np.ndarray:
    """``returns`` validated, as float32 (N, 3); raises ``ReturnsError`` naming the first
    return that fails.

    N >= 1; every value finite; Z > 0 metres; rows and columns whole, non-negative pixel
    indices. With the frame's ``shape`` (height, width): every return inside it, and N at
    most height x width (more can only be repeats; it bounds the work a request may ask for).
    """
    if not isinstance(returns, np.ndarray) or returns.ndim != 2 or returns.shape[1] != 3:
        got = returns.shape if isinstance(returns, np.ndarray) else type(returns).__name__
        raise ReturnsError("wrong_shape", f"returns must be (N, 3): row, col, z_m; got shape {got}")
    if returns.dtype.kind != "f" or returns.dtype.itemsize not in (4, 8):
        raise ReturnsError(
            "wrong_dtype", f"returns must hold float32 or float64 values, got {returns.dtype}"
        )
    if len(returns) == 0:
        raise ReturnsError("no_returns", "no LIDAR return in the list: nothing to complete from")
    if shape is not None and len(returns) > shape[0] * shape[1]:
        raise ReturnsError(
            "invalid_returns",
            f"{len(returns)} returns for a {shape[1]} x {shape[0]} frame: at most one per "
            "pixel on average",
        )
    if not np.isfinite(returns).all():
        raise ReturnsError(
            "invalid_depth",
            f"returns must be finite numbers; return {_first(~np.isfinite(returns))} is not",
        )
    rows, cols, z = returns.T
    if (z <= 0).any():
        k = _first(z <= 0)
        raise ReturnsError("invalid_depth", f"z_m must be > 0 (metres); return {k} has {z[k]}")
    if (z > MAX_DEPTH_M).any():
        k = _first(z > MAX_DEPTH_M)
        raise ReturnsError(
            "invalid_depth", f"z_m must be <= {MAX_DEPTH_M:.0f} m; return {k} has {z[k]:.3g}"
        )
    pixels = returns[:, :2]
    bad = (pixels != np.round(pixels)) | (pixels < 0)
    if bad.any():
        raise ReturnsError(
            "invalid_returns",
            f"row and col must be pixel indices (whole, >= 0); return {_first(bad)} is not",
        )
    if shape is not None:
        outside = (rows >= shape[0]) | (cols >= shape[1])
        if outside.any():
            k = _first(outside)
            raise ReturnsError(
                "invalid_returns",
                f"return {k} at row {rows[k]:.0f}, col {cols[k]:.0f} is outside the "
                f"{shape[1]} x {shape[0]} image",
            )
    return returns.astype(np.float32, copy=False)


def dense_from_returns(returns: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The dense float32 (H, W) map of ``returns`` (metres, 0 = no return), nearest return
    per pixel; the returns are validated against ``shape`` first (``ReturnsError``)."""
    returns = check_returns(returns, shape)
    rows = returns[:, 0].astype(np.intp)
    cols = returns[:, 1].astype(np.intp)
    return scatter_nearest(rows, cols, returns[:, 2], shape)


def check_dense_depths(sparse: np.ndarray) -> None:
    """A dense map's depths (metres, 0 = no return): finite, >= 0 and at most
    ``MAX_DEPTH_M``, else ``ReturnsError`` ("invalid_depth") saying how many are not. A valid
    map costs one finiteness pass and two reductions; the counts are made only to refuse."""
    finite = np.isfinite(sparse)
    if not finite.all():
        _refuse_depths(~finite, "NaN or infinite values")
    if sparse.size and sparse.min() < 0:
        _refuse_depths(sparse < 0, "negative depths: metres >= 0, 0 = no return")
    if sparse.size and float(sparse.max()) > MAX_DEPTH_M:  # a float16 map cannot hold the limit
        _refuse_depths(sparse > MAX_DEPTH_M, f"depths beyond {MAX_DEPTH_M:.0f} m")


def _refuse_depths(bad: np.ndarray, what: str) -> None:
    raise ReturnsError("invalid_depth", f"the sparse map has {int(np.count_nonzero(bad))} {what}")


def return_pixels(sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the returns of a sparse map (metres, 0 = none), row-major: OpenCV's scan,
    several times faster than ``np.nonzero`` on a 2048 x 2048 frame."""
    found = cv2.findNonZero(cv2.compare(sparse, 0, cv2.CMP_GT))
    if found is None:
        return np.empty(0, np.intp), np.empty(0, np.intp)
    xy = found.reshape(-1, 2)
    return xy[:, 1].astype(np.intp), xy[:, 0].astype(np.intp)


#: Fewer returns (or returns on one line) give no spacing.
MIN_RETURNS_FOR_SPACING = 3


def return_spacing(rows: np.ndarray, cols: np.ndarray) -> float | None:
    """Typical distance between neighbouring returns, pixels: the square root of the area of
    the returns' convex hull per return (a grid of spacing a x b gives sqrt(a b)); None for
    fewer than ``MIN_RETURNS_FOR_SPACING`` returns or returns on one line."""
    if len(rows) < MIN_RETURNS_FOR_SPACING:
        return None
    area = cv2.contourArea(cv2.convexHull(row_ends(rows, cols)))
    return math.sqrt(area / len(rows)) if area > 0 else None


def row_ends(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """The leftmost and rightmost of the pixels (``rows``, ``cols``) in each of their rows, as
    (x, y) float32 points: they have the same convex hull as all of them, and a dense LIDAR's
    128k returns take 13 ms to hull where their 3k row ends take 1.6."""
    if np.any(rows[1:] < rows[:-1]):  # row-major order, as return_pixels gives them
        order = np.argsort(rows, kind="stable")
        rows, cols = rows[order], cols[order]
    starts = np.flatnonzero(np.diff(rows, prepend=rows[0] - 1))
    ends = (np.minimum.reduceat(cols, starts), np.maximum.reduceat(cols, starts))
    ys = np.concatenate([rows[starts], rows[starts]])
    return np.stack([np.concatenate(ends), ys], 1).astype(np.float32)


def returns_from_dense(sparse: np.ndarray) -> np.ndarray:
    """The returns of a dense map (H, W, metres, 0 = no return) as float32 (N, 3), in
    row-major order; ``dense_from_returns(returns, sparse.shape)`` gives the map back exactly
    (as float32). Raises ``ReturnsError`` for depths ``check_dense_depths`` refuses."""
    if sparse.ndim != 2 or sparse.dtype.kind != "f":
        raise ReturnsError(
            "wrong_shape", f"a dense map is a float (H, W) array, got {sparse.dtype} {sparse.shape}"
        )
    check_dense_depths(sparse)
    if sparse.dtype not in (np.float32, np.float64):  # float16, byte-swapped, long double
        sparse = sparse.astype(np.float64)
    rows, cols = return_pixels(sparse)  # 1.7 ms on a 2048 x 2048 map; np.nonzero took 20-24
    returns = np.empty((len(rows), 3), np.float32)
    returns[:, 0] = rows
    returns[:, 1] = cols
    returns[:, 2] = sparse[rows, cols]
    return returns


#: Bytes of CSV text parsed at a time: numpy's parser holds the interpreter for the whole of a
#: call, so a long file is parsed in blocks (about 60,000 returns each), between which a
#: service's other threads and event loop run.
CSV_BLOCK_BYTES = 2**20


def parse_returns_csv(
    data: bytes | str,
    source: str = "returns CSV",
    check_shape: Callable[[tuple[int, ...]], None] | None = None,
) -> np.ndarray:
    """float32 (N, 3) returns of CSV text (UTF-8 bytes, or a string): the header
    ``row,col,z_m``, then one return per line (blank lines skipped). Checked as
    ``check_returns`` without a frame. Its lines are counted before anything is parsed, and
    ``check_shape((lines, 3))`` runs (it raises to refuse so many); then it is parsed
    ``CSV_BLOCK_BYTES`` at a time. Every error (``ReturnsError``; code ``not_text`` for bytes
    that are not UTF-8) starts with ``source`` and names the line or return at fault."""
    if isinstance(data, str):
        data = data.encode()
    first, _, body = data.removeprefix(b"\xef\xbb\xbf").partition(b"\n")
    header = tuple(cell.strip() for cell in _text(first, 1, source).split(","))
    if header != CSV_HEADER:
        raise ReturnsError(
            "invalid_returns",
            f"{source}: the first line must be the header {','.join(CSV_HEADER)}",
        )
    lines = body.count(b"\n") + (1 if body and not body.endswith(b"\n") else 0)
    if check_shape is not None:
        check_shape((lines, 3))
    blocks, line = [np.empty((0, 3))], 2
    for block in _blocks(body):
        blocks.append(_parse_block(block, line, source))
        line += block.count(b"\n")
    values = np.concatenate(blocks)
    if len(values) == 0:
        raise ReturnsError("no_returns", f"{source}: no LIDAR return after the header")
    try:
        return check_returns(values)
    except ReturnsError as exc:
        raise ReturnsError(exc.code, f"{source}: {exc}") from None


def _blocks(body: bytes) -> Iterator[bytes]:
    """``body`` in pieces of about ``CSV_BLOCK_BYTES``, each of whole lines."""
    at = 0
    while at < len(body):
        end = body.find(b"\n", at + CSV_BLOCK_BYTES)
        end = len(body) if end == -1 else end + 1
        yield body[at:end]
        at = end


def _text(data: bytes, line: int, source: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise ReturnsError("not_text", f"{source}: not UTF-8 text from line {line}") from None


def _parse_block(block: bytes, first_line: int, source: str) -> np.ndarray:
    """The (n, 3) float64 returns of whole CSV lines, the first of them line ``first_line``."""
    text = _text(block, first_line, source)
    try:
        values = np.loadtxt(io.StringIO(text), delimiter=",", ndmin=2, dtype=np.float64)
    except ValueError:  # numpy's C parser: fast; the slow scan below only names a bad line
        raise ReturnsError("invalid_returns", f"{source}: {_bad_line(text, first_line)}") from None
    if values.size == 0:
        return np.empty((0, 3))
    if values.shape[1] != 3:
        raise ReturnsError("invalid_returns", f"{source}: {_bad_line(text, first_line)}")
    return values


def _bad_line(text: str, first_line: int) -> str:
    """Which line of ``text`` is not three numbers, and why."""
    for number, line in enumerate(text.splitlines(), start=first_line):
        if not line.strip():
            continue
        fields = line.split(",")
        problem = (
            f"{len(fields)} values"
            if len(fields) != 3
            else next((f"{f.strip()!r} is not a number" for f in fields if not _number(f)), None)
        )
        if problem:
            return f"line {number}: expected row,col,z_m numbers, got {line[:80]!r} ({problem})"
    return "expected row,col,z_m numbers on every line"


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def read_returns_csv(path: str | Path) -> np.ndarray:
    """float32 (N, 3) returns of a CSV file (``parse_returns_csv``; errors start with the
    file's path); ``OSError`` if it cannot be read."""
    path = Path(path)
    return parse_returns_csv(path.read_bytes(), str(path))


def write_returns_csv(path: str | Path, returns: np.ndarray) -> None:
    """Write ``returns`` as a CSV file (header ``row,col,z_m``); Z with float32's 9
    significant digits, so that ``read_returns_csv`` reads back the same float32 values."""
    returns = check_returns(returns)
    lines = [",".join(CSV_HEADER)]
    lines += [f"{int(r)},{int(c)},{float(z):.9g}" for r, c, z in returns]
    Path(path).write_text("\n".join(lines) + "\n")
