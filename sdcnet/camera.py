"""Pinhole camera and LIDAR specifications of the paper (Tables 1-2).

Conventions used everywhere in sdcnet:
- camera frame: x right, y down, z forward (optical axis), metres;
- pixel (u, v) = (column, row); the centre of pixel (i, j) sits at coordinates (i, j)
  (OpenCV convention), so the principal point of a W x H image is ((W-1)/2, (H-1)/2);
- depth maps hold camera-frame Z in metres, float32, 0 = no value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CameraSpec:
    """Physical camera of Table 1: focal length and square sensor in millimetres."""

    focal_mm: float = 50.0
    sensor_mm: float = 6.449
    width: int = 1024
    height: int = 1024

    def intrinsics(self) -> Intrinsics:
        """Pinhole intrinsics in pixels, derived from the optics (never typed in twice)."""
        fx = self.focal_mm * self.width / self.sensor_mm
        fy = self.focal_mm * self.height / self.sensor_mm
        return Intrinsics(
            fx, fy, (self.width - 1) / 2, (self.height - 1) / 2, self.width, self.height
        )

    @property
    def fov_deg(self) -> float:
        """Full field of view across the sensor, degrees (7.38 for Table 1)."""
        return math.degrees(2 * math.atan(self.sensor_mm / 2 / self.focal_mm))


@dataclass(frozen=True)
class LidarSpec:
    """Scanning LIDAR of Table 2, co-located and aligned with the camera."""

    max_range_m: float = 280.0
    range_error_m: float = 0.03
    horizontal_step_deg: float = 0.09
    vertical_step_deg: float = 0.13
    dropout: float = 0.02


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels for an image of ``width`` x ``height``."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def scaled(self, width: int, height: int) -> Intrinsics:
        """The same optics seen by a sensor resampled to ``width`` x ``height`` pixels."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
            width,
            height,
        )

    def matrix(self) -> np.ndarray:
        """3 x 3 camera matrix K (float64)."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1]], dtype=np.float64)

    def pixel_rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit-Z ray directions (x/z, y/z, 1) through pixel coordinates, shape (..., 3)."""
        x = (np.asarray(u, dtype=np.float64) - self.cx) / self.fx
        y = (np.asarray(v, dtype=np.float64) - self.cy) / self.fy
        return np.stack([x, y, np.ones_like(x)], axis=-1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (u, v) of camera-frame points (..., 3) with z > 0."""
        z = points[..., 2]
        return self.fx * points[..., 0] / z + self.cx, self.fy * points[..., 1] / z + self.cy

    def as_dict(self) -> dict[str, float | int]:
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "width": self.width,
            "height": self.height,
        }


PAPER_CAMERA = CameraSpec()
PAPER_LIDAR = LidarSpec()

#: Widest field of view intrinsics may give along either side of their frame, degrees: a
#: pinhole camera sees less than 180 (fisheye lenses are refused), sdcnet's cameras 5 to 60;
#: a focal length of a pixel on a frame of a thousand is a mistake of units, not a camera.
MAX_FIELD_OF_VIEW_DEG = 150.0
#: Longest focal length, pixels (the Open Inference Protocol route's bound since it exists):
#: 0.00006 degrees across 1024 pixels.
MAX_FOCAL_PX = 1e9


class IntrinsicsError(ValueError):
    """Intrinsics that cannot describe a frame of their size; the message says which value."""


def check_intrinsics(K: Intrinsics) -> Intrinsics:
    """``K`` when it can describe a ``K.width`` x ``K.height`` frame: every value finite,
    each focal length between the one of a ``MAX_FIELD_OF_VIEW_DEG`` field of view along its
    side and ``MAX_FOCAL_PX``, the principal point within half an image of the image. The one
    check of every route of the service and of camera files; raises ``IntrinsicsError``."""
    for name in ("fx", "fy", "cx", "cy"):
        value = getattr(K, name)
        if not math.isfinite(value):
            raise IntrinsicsError(f"{name} must be a finite number of pixels, got {value}")
    if K.fx <= 0 or K.fy <= 0:
        raise IntrinsicsError(
            f"focal lengths must be positive pixels, got fx {K.fx:g}, fy {K.fy:g}"
        )
    half_angle = math.tan(math.radians(MAX_FIELD_OF_VIEW_DEG / 2))
    for name, focal, side in (("fx", K.fx, K.width), ("fy", K.fy, K.height)):
        shortest = side / 2 / half_angle
        if not shortest <= focal <= MAX_FOCAL_PX:
            raise IntrinsicsError(
                f"{name} {focal:g} px is not a focal length for a side of {side} px: it lies "
                f"between {shortest:.4g} px (a {MAX_FIELD_OF_VIEW_DEG:g} degree field of view) "
                f"and {MAX_FOCAL_PX:g} px"
            )
    w, h = K.width, K.height
    if not (-w / 2 <= K.cx <= 1.5 * w and -h / 2 <= K.cy <= 1.5 * h):
        raise IntrinsicsError(
            f"the principal point ({K.cx:g}, {K.cy:g}) lies far outside the {w} x {h} image: "
            "cx and cy are pixels, about (width - 1) / 2 and (height - 1) / 2"
        )
    return K
