"""The coarse grid that carries the smooth quantities, and a sphere (the Earth, the Moon) seen
on it.

Geometry is exact per pixel (camera frame x right, y down, z forward, km): ray-sphere for the
Earth and the Moon, angles for the Sun. Smooth quantities (surface chart coordinates, lighting,
pixel footprint, the coarse texture octaves) are computed on a grid ``FACTOR`` times coarser and
upsampled bilinearly; the octaves near the pixel scale, the limb and the disc edges are evaluated
per pixel, in row strips so that memory stays at a few full-frame arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background.geometry import basis, unit

FACTOR = 4  # coarse grid: one cell per FACTOR x FACTOR pixels
STRIP_PIXELS = 65536  # full-resolution work goes in strips of rows, 256 kB per float32 array


@dataclass(frozen=True)
class Grid:
    """Cells ``factor`` times coarser than the pixels, one cell of padding all round.

    Cell (i, j) sits at pixel coordinates (factor (j - 1) + (factor - 1) / 2, same for i), the
    sampling that ``cv2.resize`` assumes, so ``upsample`` lands on the pixel centres."""

    K: Intrinsics
    factor: int
    rays: np.ndarray  # (h, w, 3) unit directions
    pixel_rad: np.ndarray  # (h, w) angular size of one full-resolution pixel, radians

    @classmethod
    def of(cls, K: Intrinsics, factor: int) -> Grid:
        nu, nv = -(-K.width // factor) + 2, -(-K.height // factor) + 2
        u = factor * (np.arange(nu) - 1.0) + (factor - 1) / 2
        v = factor * (np.arange(nv) - 1.0) + (factor - 1) / 2
        rays = K.pixel_rays(*np.meshgrid(u, v))
        length = np.linalg.norm(rays, axis=-1)
        return cls(K, factor, rays / length[..., None], length**-1.5 / math.sqrt(K.fx * K.fy))

    def upsample(self, low: np.ndarray, r0: int, rows: int) -> np.ndarray:
        """Full-resolution rows r0 .. r0 + rows (r0 a multiple of factor) of a coarse field.

        Bilinear, as ``cv2.resize`` would do it, but only the rows asked for: pixel (x, y)
        samples the block at ((x + 0.5) / f + 0.5, same for y)."""
        f = self.factor
        block = low[r0 // f : r0 // f + -(-rows // f) + 2]
        shift = 0.5 + 0.5 / f
        M = np.array([[1.0 / f, 0.0, shift], [0.0, 1.0 / f, shift]])
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        return cv2.warpAffine(block, M, (self.K.width, rows), flags=flags)

    def strips(self):
        """(r0, rows) of the full-resolution strips: a multiple of factor rows, about
        STRIP_PIXELS pixels, so that their temporary arrays are recycled, not page-faulted."""
        step = max(STRIP_PIXELS // self.K.width // self.factor, 1) * self.factor
        for r0 in range(0, self.K.height, step):
            yield r0, min(step, self.K.height - r0)


@dataclass(frozen=True)
class SphereView:
    """A sphere seen on the coarse grid: per cell, the surface (or the closest approach) point.

    ``q`` is the squared distance from the centre to the ray (D^2 + b^2 for rays pointing away),
    smooth across the limb so that it upsamples to the exact per-pixel hit test q < R^2."""

    hit: np.ndarray  # (h, w) bool
    q: np.ndarray  # (h, w) km^2
    normal: np.ndarray  # (h, w, 3) at the hit, or at the closest approach for a miss
    mu_view: np.ndarray  # (h, w) cos of the emission angle, floored at 0.02
    log_footprint: np.ndarray  # (h, w) log2 of the pixel footprint on the surface, km
    chart: tuple[np.ndarray, np.ndarray]  # (h, w) orthographic surface coordinates, km


def sphere_view(grid: Grid, centre_km: np.ndarray, radius_km: float) -> SphereView:
    b = grid.rays @ centre_km
    d2 = float(centre_km @ centre_km)
    q = np.where(b > 0, d2 - b**2, d2 + b**2)
    hit = q < radius_km**2
    t = np.where(hit, b - np.sqrt(np.maximum(radius_km**2 - q, 0.0)), np.maximum(np.abs(b), 1e-3))
    normal = unit(t[..., None] * grid.rays - centre_km)
    mu_view = np.clip(-np.sum(normal * grid.rays, axis=-1), 0.02, 1.0)
    footprint = t * grid.pixel_rad / np.sqrt(mu_view)
    e1, e2 = basis(unit(-centre_km))
    middle = normal[normal.shape[0] // 2, normal.shape[1] // 2]
    chart = tuple((radius_km * (normal @ e - middle @ e)).astype(np.float32) for e in (e1, e2))
    return SphereView(
        hit,
        q.astype(np.float32),
        normal,
        mu_view,
        np.log2(footprint).astype(np.float32),
        chart,
    )
