"""Random viewing conditions of one sample: attitude, distance, sun (paper sec. IV)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SceneConfig:
    """Ranges the scenes are drawn from; defaults are the paper's."""

    min_distance_m: float = 50.0
    max_distance_m: float = 250.0
    max_sun_angle_deg: float = 70.0  # between the sun and the viewing direction, at the target
    max_offset_deg: float = 1.2  # target centre off the optical axis, per axis


@dataclass(frozen=True)
class Scene:
    """Pose of the spacecraft in the camera frame (x right, y down, z forward) and the sun."""

    rotation: np.ndarray  # 3 x 3, object frame -> camera frame
    translation: np.ndarray  # (3,) metres, object centre in the camera frame
    sun: np.ndarray  # (3,) unit vector towards the sun, camera frame
    sun_angle_deg: float  # angle between the sun and the direction target -> camera

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(self.translation))

    def metadata(self) -> dict:
        return {
            "distance_m": round(self.distance_m, 4),
            "sun_angle_deg": round(self.sun_angle_deg, 3),
            "rotation": np.round(self.rotation, 6).tolist(),
            "translation_m": np.round(self.translation, 4).tolist(),
            "sun_direction": np.round(self.sun, 6).tolist(),
        }


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed rotation matrix (from a uniform unit quaternion)."""
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _orthonormal_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(axis, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(axis, a)


def sample_scene(rng: np.random.Generator, config: SceneConfig = SceneConfig()) -> Scene:
    """Distance uniform in range, attitude uniform, sun uniform in the allowed cone."""
    distance = rng.uniform(config.min_distance_m, config.max_distance_m)
    ox, oy = np.tan(np.radians(rng.uniform(-config.max_offset_deg, config.max_offset_deg, size=2)))
    direction = np.array([ox, oy, 1.0])
    translation = distance * direction / np.linalg.norm(direction)
    to_camera = -translation / distance
    cos_max = np.cos(np.radians(config.max_sun_angle_deg))
    cos_t = rng.uniform(cos_max, 1.0)  # uniform over the cone's solid angle
    phi = rng.uniform(0, 2 * np.pi)
    a, b = _orthonormal_basis(to_camera)
    sin_t = np.sqrt(1 - cos_t**2)
    sun = cos_t * to_camera + sin_t * (np.cos(phi) * a + np.sin(phi) * b)
    return Scene(random_rotation(rng), translation, sun, float(np.degrees(np.arccos(cos_t))))
