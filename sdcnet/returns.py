"""LIDAR returns as a list, one per return: (row, column, Z), pixel indices of the frame and
camera-frame Z in metres; and the dense map (H x W float32 metres, 0 = no return) that the
service takes.

On disk a list is a CSV file with the header ``row,col,z_m`` and one return per line, e.g.
``examples/<name>.returns.csv``: a 1024 x 1024 frame's ~150 returns in a few kB instead of a
4 MiB dense ``.npy``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

HEADER = ("row", "col", "z_m")


def check_returns(returns: np.ndarray, shape: tuple[int, int] | None = None) -> None:
    """``ValueError`` unless ``returns`` is (N, 3) of whole, non-negative pixel indices and
    finite Z > 0, inside a frame of ``shape`` (rows, columns) when given."""
    if returns.ndim != 2 or returns.shape[1] != 3:
        raise ValueError(f"returns must be (N, 3): row, col, z_m; got shape {returns.shape}")
    if not np.isfinite(returns).all():
        raise ValueError(f"returns must be finite numbers; return {_first(~np.isfinite(returns))}")
    rows, cols, z = returns.T
    if (z <= 0).any():
        raise ValueError(f"z_m must be > 0 (metres); return {_first(z <= 0)} has {z[z <= 0][0]}")
    indices = returns[:, :2]
    if (indices != np.round(indices)).any() or (indices < 0).any():
        bad = (indices != np.round(indices)).any(axis=1) | (indices < 0).any(axis=1)
        raise ValueError(f"row and col must be pixel indices (whole, >= 0); return {_first(bad)}")
    if shape is not None:
        outside = (rows >= shape[0]) | (cols >= shape[1])
        if outside.any():
            k = _first(outside)
            raise ValueError(
                f"return {k} at row {rows[k]:.0f}, col {cols[k]:.0f} is outside the "
                f"{shape[1]} x {shape[0]} image"
            )


def _first(bad: np.ndarray) -> int:
    """Index of the first return (row of ``bad``) that fails a check."""
    return int(np.nonzero(bad.reshape(len(bad), -1).any(axis=1))[0][0])


def read_returns_csv(path: str | Path) -> np.ndarray:
    """The (N, 3) float32 returns of a ``row,col,z_m`` CSV file, checked (``check_returns``);
    ``ValueError`` naming the file and line for anything else, ``OSError`` if unreadable."""
    path = Path(path)
    lines = path.read_text().splitlines()
    if not lines or tuple(h.strip() for h in lines[0].split(",")) != HEADER:
        raise ValueError(f"{path}: the first line must be the header {','.join(HEADER)}")
    values = []
    for number, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        fields = line.split(",")
        try:
            if len(fields) != 3:
                raise ValueError(f"{len(fields)} values")
            values.append([float(f) for f in fields])
        except ValueError as exc:
            raise ValueError(
                f"{path} line {number}: expected row,col,z_m numbers, got {line!r} ({exc})"
            ) from None
    returns = np.array(values, np.float32).reshape(-1, 3)
    try:
        check_returns(returns)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    return returns


def write_returns_csv(path: str | Path, returns: np.ndarray) -> None:
    """Write (N, 3) returns as ``row,col,z_m`` lines (Z to the millimetre)."""
    check_returns(returns)
    lines = [",".join(HEADER)]
    lines += [f"{r:.0f},{c:.0f},{z:.3f}" for r, c, z in returns]
    Path(path).write_text("\n".join(lines) + "\n")


def returns_of(sparse: np.ndarray) -> np.ndarray:
    """The (N, 3) float32 returns of a dense map (H x W metres, 0 = none), row by row."""
    rows, cols = np.nonzero(sparse > 0)
    return np.stack([rows, cols, sparse[rows, cols]], axis=1).astype(np.float32)


def dense_from_returns(returns: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The (H, W) float32 map in metres (0 = no return) of ``shape``; where two returns share
    a pixel the nearest wins. ``ValueError`` for returns ``check_returns`` refuses."""
    returns = np.asarray(returns, np.float32)
    check_returns(returns, shape)
    dense = np.full(shape, np.inf, np.float32)
    rows, cols = returns[:, 0].astype(int), returns[:, 1].astype(int)
    np.minimum.at(dense, (rows, cols), returns[:, 2])
    dense[np.isinf(dense)] = 0
    return dense
