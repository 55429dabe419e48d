"""Small geometry of directions and the frame (camera frame x right, y down, z forward):
orthonormal bases, angles to the frame, the pixel box of a cone of directions."""

from __future__ import annotations

import math

import numpy as np

from sdcnet.camera import Intrinsics


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` to an orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = unit(np.cross(axis, helper))
    return a, np.cross(axis, a)


def frame_half_angles(K: Intrinsics) -> tuple[float, float]:
    """Angles (deg) from the optical axis to the nearest frame edge and the farthest corner."""
    u0, u1, v0, v1 = -0.5, K.width - 0.5, -0.5, K.height - 0.5
    edges = K.pixel_rays(np.array([u0, u1, K.cx, K.cx]), np.array([K.cy, K.cy, v0, v1]))
    corners = K.pixel_rays(np.array([u0, u1, u0, u1]), np.array([v0, v0, v1, v1]))

    def off_axis(rays):
        return np.degrees(np.arctan(np.hypot(rays[:, 0], rays[:, 1])))

    return float(off_axis(edges).min()), float(off_axis(corners).max())


def angle_to_frame_deg(K: Intrinsics, direction: np.ndarray) -> float:
    """Angle (deg) from a direction to the nearest ray of the frame; 0 if it projects inside."""
    d = unit(direction)
    if d[2] > 0:
        u, v = K.project(d)
        if -0.5 <= u <= K.width - 0.5 and -0.5 <= v <= K.height - 0.5:
            return 0.0
    s = np.linspace(0.0, 1.0, 257)
    us = np.concatenate([s * K.width, s * K.width, np.zeros(257), np.full(257, 1.0 * K.width)])
    vs = np.concatenate([np.zeros(257), np.full(257, 1.0 * K.height), s * K.height, s * K.height])
    rays = unit(K.pixel_rays(us - 0.5, vs - 0.5))
    return float(np.degrees(np.arccos(np.clip((rays @ d).max(), -1.0, 1.0))))


def sun_in_view(K: Intrinsics, sun: np.ndarray, margin_deg: float = 0.0) -> bool:
    """Whether the Sun's direction projects inside the frame or within ``margin_deg`` of it."""
    return angle_to_frame_deg(K, sun) <= margin_deg


def cone_box(
    K: Intrinsics, direction: np.ndarray, radius_rad: float, margin_px: int = 2
) -> tuple[int, int, int, int] | None:
    """Pixel box (u0, u1, v0, v1) holding the image of a cone of directions, or None if empty."""
    a, b = basis(direction)
    phi = np.linspace(0.0, 2 * np.pi, 96, endpoint=False)[:, None]
    rim = math.cos(radius_rad) * direction + math.sin(radius_rad) * (
        np.cos(phi) * a + np.sin(phi) * b
    )
    if np.any(rim[:, 2] <= 1e-6):
        return 0, K.width, 0, K.height
    u, v = K.project(rim)
    u0 = int(np.clip(np.floor(u.min()) - margin_px, 0, K.width))
    u1 = int(np.clip(np.ceil(u.max()) + margin_px + 1, 0, K.width))
    v0 = int(np.clip(np.floor(v.min()) - margin_px, 0, K.height))
    v1 = int(np.clip(np.ceil(v.max()) + margin_px + 1, 0, K.height))
    return (u0, u1, v0, v1) if u1 > u0 and v1 > v0 else None


def crop(K: Intrinsics, box: tuple[int, int, int, int]) -> Intrinsics:
    u0, u1, v0, v1 = box
    return Intrinsics(K.fx, K.fy, K.cx - u0, K.cy - v0, u1 - u0, v1 - v0)
