"""Where a LIDAR's beams are worth casting: the camera's field of view, widened for the
parallax of a LIDAR mounted off the camera, cut to the projection of the object's bounding box;
as a window of tangents (x/z, y/z) that each LIDAR kind fills with its own pattern."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sdcnet.camera import Intrinsics

#: Nearest object depth (m) assumed when widening the camera's field of view for parallax.
NEAREST_M = 2.0


@dataclass(frozen=True)
class TanWindow:
    """Directions (x, y, z) from the LIDAR with z > 0 and x/z in [x0, x1], y/z in [y0, y1]."""

    x0: float
    x1: float
    y0: float
    y1: float

    def contains(self, d: np.ndarray) -> np.ndarray:
        z = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = d[:, 0] / z, d[:, 1] / z
        return (z > 0) & (x >= self.x0) & (x <= self.x1) & (y >= self.y0) & (y <= self.y1)

    def corner_rays(self) -> np.ndarray:
        return np.array([[x, y, 1.0] for x in (self.x0, self.x1) for y in (self.y0, self.y1)])


def camera_fov_deg(K: Intrinsics) -> tuple[float, float]:
    """Full horizontal and vertical field of view of the camera, degrees."""
    x0, x1, y0, y1 = _camera_tangents(K)
    return (
        math.degrees(math.atan(x1) - math.atan(x0)),
        math.degrees(math.atan(y1) - math.atan(y0)),
    )


def _camera_tangents(K: Intrinsics) -> tuple[float, float, float, float]:
    """x/z and y/z of the image's outer pixel edges."""
    return (
        (-0.5 - K.cx) / K.fx,
        (K.width - 0.5 - K.cx) / K.fx,
        (-0.5 - K.cy) / K.fy,
        (K.height - 0.5 - K.cy) / K.fy,
    )


def lidar_window(
    K: Intrinsics, origin: np.ndarray, corners: np.ndarray | None = None
) -> TanWindow | None:
    """Directions from ``origin`` worth casting: the camera's field of view, widened for the
    parallax of objects at ``NEAREST_M`` or beyond (beyond the nearest of ``corners``, the
    camera-frame corners of the object's bounding box, when given), cut to the box's
    projection. None when nothing is left."""
    x0, x1, y0, y1 = _camera_tangents(K)
    ox, oy, oz = np.abs(origin)
    near = NEAREST_M
    box = None
    if corners is not None:
        rel = np.asarray(corners, float) - origin
        if np.all(rel[:, 2] <= 0):
            return None  # behind the LIDAR
        if np.all(rel[:, 2] > 1e-6):
            near = max(near, float(rel[:, 2].min()))
            bx, by = rel[:, 0] / rel[:, 2], rel[:, 1] / rel[:, 2]
            box = (bx.min(), bx.max(), by.min(), by.max())
    mx = (ox + max(abs(x0), abs(x1)) * oz) / near
    my = (oy + max(abs(y0), abs(y1)) * oz) / near
    w = [x0 - mx, x1 + mx, y0 - my, y1 + my]
    if box is not None:
        w = [max(w[0], box[0]), min(w[1], box[1]), max(w[2], box[2]), min(w[3], box[3])]
    if w[0] > w[1] or w[2] > w[3]:
        return None
    return TanWindow(*(float(v) for v in w))
