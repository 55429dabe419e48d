"""Rigid poses of a known target in the camera frame: rotation matrices, quaternions, errors.

A pose (R, t) maps target coordinates to camera coordinates, ``p_camera = R p_target + t``:
the camera frame of ``sdcnet.camera`` (x right, y down, z forward), metres. Quaternions are
(w, x, y, z) with w >= 0 (the same rotation as -q, given once).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

#: How far from orthonormal (max |R^T R - I|) a rotation matrix given by a client may be.
ORTHONORMAL_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Pose:
    """``p_camera = R p_target + t``; R (3, 3) float64 rotation, t (3,) float64 metres."""

    R: np.ndarray
    t: np.ndarray

    @classmethod
    def from_matrix(cls, T: np.ndarray) -> Pose:
        """From a 4 x 4 homogeneous transform (target -> camera)."""
        return cls(np.array(T[:3, :3], np.float64), np.array(T[:3, 3], np.float64))

    def matrix(self) -> np.ndarray:
        """4 x 4 homogeneous transform, target -> camera."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.t
        return T

    def inverse(self) -> Pose:
        return Pose(self.R.T, -self.R.T @ self.t)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) target-frame points in the camera frame."""
        return points @ self.R.T + self.t

    def quaternion_wxyz(self) -> np.ndarray:
        return quaternion_from_matrix(self.R)

    def as_dict(self) -> dict[str, list]:
        """JSON form: ``R`` (3 x 3), ``t`` (3, metres), ``quaternion_wxyz`` (4)."""
        return {
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "quaternion_wxyz": self.quaternion_wxyz().tolist(),
        }


def extrapolate(previous: Pose, latest: Pose) -> Pose:
    """The next pose at constant velocity: the camera-frame motion from ``previous`` to
    ``latest`` applied once more (frames equally spaced in time). A tracker's ``init``."""
    step = latest.matrix() @ np.linalg.inv(previous.matrix())
    return Pose.from_matrix(step @ latest.matrix())


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (numerically stable branch
    on the largest diagonal term)."""
    m = np.asarray(R, np.float64)
    trace = np.trace(m)
    if trace > 0:
        s = 2 * np.sqrt(trace + 1)
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + m[i, i] - m[j, j] - m[k, k])
        q = np.empty(4)
        q[0] = (m[k, j] - m[j, k]) / s
        q[1 + i] = s / 4
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + k] = (m[k, i] + m[i, k]) / s
    q = np.asarray(q, np.float64)
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z); it is normalised first."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def axis_angle(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """Rotation by ``angle_rad`` about the unit ``axis`` (Rodrigues)."""
    x, y, z = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle of the rotation between two rotation matrices, degrees in [0, 180]."""
    cos = (np.trace(np.asarray(Ra).T @ np.asarray(Rb)) - 1) / 2
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def pose_errors(estimate: Pose, truth: Pose) -> tuple[float, float]:
    """(rotation error in degrees, translation error in metres) of ``estimate``."""
    return rotation_angle_deg(estimate.R, truth.R), float(np.linalg.norm(estimate.t - truth.t))


def parse_pose(value: Mapping[str, Any]) -> Pose:
    """A pose from its JSON form: ``t`` (3 numbers, metres) and either ``R`` (3 x 3, a
    rotation matrix) or ``quaternion_wxyz`` (4 numbers, normalised here). ``R`` wins when
    both are given. Raises ValueError naming what is wrong."""
    if not isinstance(value, Mapping):
        raise ValueError("a pose is a JSON object with 't' and 'R' or 'quaternion_wxyz'")
    t = _numbers(value.get("t"), (3,), "t")
    if "R" in value:
        R = _numbers(value["R"], (3, 3), "R")
        error = float(np.max(np.abs(R.T @ R - np.eye(3))))
        if error > ORTHONORMAL_TOLERANCE or np.linalg.det(R) < 0:
            raise ValueError(
                f"'R' is not a rotation matrix (max |R^T R - I| {error:.2g}, "
                f"determinant {np.linalg.det(R):.3g})"
            )
        u, _, vt = np.linalg.svd(R)  # the nearest exact rotation
        return Pose(u @ vt, t)
    if "quaternion_wxyz" in value:
        q = _numbers(value["quaternion_wxyz"], (4,), "quaternion_wxyz")
        if np.linalg.norm(q) < 1e-6:
            raise ValueError("'quaternion_wxyz' is zero")
        return Pose(matrix_from_quaternion(q), t)
    raise ValueError("a pose needs 'R' (3 x 3) or 'quaternion_wxyz' (4) beside 't'")


def _numbers(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``value`` as a float64 array of ``shape``: nested lists of JSON numbers only (no
    strings, booleans or nulls), finite."""
    if value is None:
        raise ValueError(f"'{name}' is missing")

    def leaves(v: Any) -> list:
        return [x for item in v for x in leaves(item)] if isinstance(v, list | tuple) else [v]

    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in leaves(value)):
        raise ValueError(f"'{name}' must hold numbers only")
    try:
        array = np.array(value, dtype=np.float64)
    except ValueError:  # ragged nesting
        raise ValueError(f"'{name}' must have shape {list(shape)}") from None
    if array.shape != shape:
        raise ValueError(f"'{name}' must have shape {list(shape)}, got {list(array.shape)}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"'{name}' holds NaN or infinite values")
    return array
