"""LIDAR simulation (Table 2): a co-located beam grid projected into the camera image.

Beams step 0.09 deg in azimuth and 0.13 deg in elevation over the camera's field of view,
with a random phase per frame. Each return's range carries noise within the range error;
returns beyond the maximum range and a small random fraction (dropout) are lost. Shadowed
surfaces return like lit ones. Each return lands on its nearest pixel as camera-frame Z.
"""

from __future__ import annotations

import numpy as np

from sdcnet.camera import Intrinsics, LidarSpec
from sdcnet.training.data.raycast import RayCaster


def beam_directions(spec: LidarSpec, K: Intrinsics, rng: np.random.Generator) -> np.ndarray:
    """Unit beam directions (N, 3) covering the camera's field of view, random grid phase."""
    half_u = np.degrees(np.arctan(max(K.cx + 0.5, K.width - 0.5 - K.cx) / K.fx))
    half_v = np.degrees(np.arctan(max(K.cy + 0.5, K.height - 0.5 - K.cy) / K.fy))
    h, v = spec.horizontal_step_deg, spec.vertical_step_deg
    az = np.arange(-half_u + rng.uniform(0, h), half_u, h)
    el = np.arange(-half_v + rng.uniform(0, v), half_v, v)
    az, el = np.radians(np.meshgrid(az, el))
    d = np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], axis=-1)
    return d.reshape(-1, 3)


def scan(caster: RayCaster, spec: LidarSpec, K: Intrinsics, rng: np.random.Generator) -> np.ndarray:
    """Sparse depth map (H, W) float32: camera-frame Z in metres of each return, 0 elsewhere."""
    directions = beam_directions(spec, K, rng)
    faces, distance = caster.closest(np.zeros_like(directions), directions)
    noise = np.clip(
        rng.normal(0, spec.range_error_m / 3, len(distance)),
        -0.99 * spec.range_error_m,
        0.99 * spec.range_error_m,
    )
    measured = distance + noise
    keep = (
        (faces >= 0) & (measured <= spec.max_range_m) & (rng.random(len(distance)) >= spec.dropout)
    )
    points = directions[keep] * measured[keep, None]
    u, v = K.project(points)
    u, v = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
    inside = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
    sparse = np.full((K.height, K.width), np.inf, np.float32)
    np.minimum.at(sparse, (v[inside], u[inside]), points[inside, 2].astype(np.float32))
    sparse[np.isinf(sparse)] = 0
    return sparse
