"""Random viewing conditions of one sample: attitude, distance, sun (paper sec. IV)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from sdcnet.camera import Intrinsics


@dataclass(frozen=True)
class SceneConfig:
    """Ranges the scenes are drawn from; defaults are the paper's."""

    min_distance_m: float = 50.0
    max_distance_m: float = 250.0
    log_distance: bool = False  # distance log-uniform (docking to far: each octave alike)
    clearance_m: float = 1.0  # the camera stays this far outside the spacecraft's bounding sphere
    max_offset_deg: float = 1.2  # target centre off the optical axis, per axis ...
    offset_of_fov: float = 0.0  # ... or, when > 0, this fraction of each half field of view
    min_sun_angle_deg: float = 0.0  # between the sun and the viewing direction, at the target
    max_sun_angle_deg: float = 70.0


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

    def with_sun(self, sun: np.ndarray) -> Scene:
        """The same scene lit from ``sun`` (unit vector, camera frame)."""
        to_camera = -self.translation / self.distance_m
        angle = float(np.degrees(np.arccos(np.clip(np.dot(sun, to_camera), -1.0, 1.0))))
        return replace(self, sun=np.asarray(sun, float), sun_angle_deg=angle)

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


def sample_scene(
    rng: np.random.Generator,
    config: SceneConfig = SceneConfig(),
    K: Intrinsics | None = None,
    radius_m: float = 0.0,
) -> Scene:
    """Distance in range (never closer than the spacecraft's bounding ``radius_m`` plus the
    clearance), attitude uniform, target centre off the axis within the configured offset (a
    fraction of camera ``K``'s field of view when ``offset_of_fov`` is set), sun uniform over
    the solid angle between the configured angles from the viewing direction."""
    near = max(config.min_distance_m, radius_m + config.clearance_m)
    far = max(config.max_distance_m, near)
    if config.log_distance:
        distance = float(np.exp(rng.uniform(np.log(near), np.log(far))))
    else:
        distance = rng.uniform(near, far)
    if config.offset_of_fov > 0 and K is not None:
        half = np.array([(K.width / 2) / K.fx, (K.height / 2) / K.fy])
        ox, oy = config.offset_of_fov * half * rng.uniform(-1, 1, size=2)
    else:
        ox, oy = np.tan(np.radians(rng.uniform(-config.max_offset_deg, config.max_offset_deg, 2)))
    direction = np.array([ox, oy, 1.0])
    translation = distance * direction / np.linalg.norm(direction)
    to_camera = -translation / distance
    cos_min = np.cos(np.radians(config.min_sun_angle_deg))
    cos_max = np.cos(np.radians(config.max_sun_angle_deg))
    cos_t = rng.uniform(cos_max, cos_min)  # uniform over the cone's solid angle
    phi = rng.uniform(0, 2 * np.pi)
    a, b = _orthonormal_basis(to_camera)
    sin_t = np.sqrt(1 - cos_t**2)
    sun = cos_t * to_camera + sin_t * (np.cos(phi) * a + np.sin(phi) * b)
    return Scene(random_rotation(rng), translation, sun, float(np.degrees(np.arccos(cos_t))))
