"""Pinhole camera and LIDAR specifications of the paper (Tables 1-2).

Conventions used everywhere in sdcnet:
- camera frame: x right, y down, z forward (optical axis), metres;
- pixel (u, v) = (column, row); the centre of pixel (i, j) sits at coordinates (i, j)
  (OpenCV convention), so the principal point of a W x H image is ((W-1)/2, (H-1)/2);
- depth maps hold camera-frame Z in metres, float32, 0 = no value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, TypeVar

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


#: The names of the four pinhole values (pixels), the same wherever they travel: form fields,
#: JSON keys, the Open Inference Protocol's parameters, camera files, command-line flags.
PINHOLE_FIELDS = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels for an image of ``width`` x ``height``."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @classmethod
    def from_matrix(cls, K: np.ndarray, width: int, height: int) -> Intrinsics:
        """The intrinsics of a 3 x 3 camera matrix (its skew, if any, is not kept)."""
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), width, height)

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

    def pinhole_dict(self) -> dict[str, float]:
        """fx, fy, cx, cy by name: what the service's answers carry beside the frame's size,
        and what a request sends to give them all."""
        return {name: getattr(self, name) for name in PINHOLE_FIELDS}

    def as_dict(self) -> dict[str, float | int]:
        """Every field by name (JSON: model metadata, dataset samples, camera descriptions);
        ``Intrinsics(**d)`` reads it back."""
        return {**self.pinhole_dict(), "width": self.width, "height": self.height}

    def describe(self, decimals: int = 3) -> str:
        """The four values as text for logs and file headers, ``decimals`` places of a pixel:
        "fx 2000.000 fy 2000.000 cx 127.500 cy 127.500"."""
        return " ".join(
            f"{name} {value:.{decimals}f}" for name, value in self.pinhole_dict().items()
        )


#: What ``GivenIntrinsics.over`` fills in: whole intrinsics, or other given values.
_Base = TypeVar("_Base", Intrinsics, "GivenIntrinsics")


@dataclass(frozen=True)
class GivenIntrinsics:
    """The pinhole values (pixels) a request gives, each optional: a value left out is the
    default's (the service's camera, else its model's, at the frame's size), value by value,
    but for a focal length given alone (``over``)."""

    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None

    @classmethod
    def from_dict(cls, values: Mapping[str, Any]) -> GivenIntrinsics:
        """The values of ``PINHOLE_FIELDS`` in a form, JSON object, manifest line or parsed
        command line (``vars(args)``) that are there and not None, as floats; other keys are
        ignored. Raises ``ValueError`` or ``TypeError`` for a value that is not a number."""
        given = {name: values.get(name) for name in PINHOLE_FIELDS}
        return cls(**{name: float(value) for name, value in given.items() if value is not None})

    def pinhole_dict(self) -> dict[str, float]:
        """The values given, by name: a form's fields, the v2 request's parameters."""
        given = {name: getattr(self, name) for name in PINHOLE_FIELDS}
        return {name: value for name, value in given.items() if value is not None}

    @property
    def whole(self) -> bool:
        """All four are given: a camera's complete intrinsics, which need no default."""
        return len(self.pinhole_dict()) == len(PINHOLE_FIELDS)

    def over(self, base: _Base) -> _Base:
        """``base`` with each value given here in place of its own; a focal length given
        without the other keeps ``base``'s pixel aspect ratio (fy / fx, 1 for square pixels):
        "fx 1400" describes a lens, and the default's other focal length, another lens's,
        would stretch the cloud along one axis by their ratio (5.7 against the paper's camera
        on a 1024 px frame)."""
        given = self.pinhole_dict()
        known = base.fx is not None and base.fy is not None
        if known and "fx" in given and "fy" not in given:
            given["fy"] = given["fx"] * base.fy / base.fx
        elif known and "fy" in given and "fx" not in given:
            given["fx"] = given["fy"] * base.fx / base.fy
        return replace(base, **given)


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
    for name, value in K.pinhole_dict().items():
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
