"""The Moon's disc: maria and highlands under Lommel-Seeliger light; it hides the stars."""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtri

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background.config import MOON_RADIUS_KM, MoonConfig
from sdcnet.training.data.background.geometry import cone_box, crop
from sdcnet.training.data.background.grid import FACTOR, Grid, SphereView, sphere_view
from sdcnet.training.data.background.noise import (
    Noise,
    coarse_fbm,
    fine_detail,
    fine_octaves,
    finest_cell_km,
    make_noise,
)

# (gain, largest cell km) of the noise channels: maria, brightness detail; two channels unused.
MOON_SPECTRA = ((0.6, 250.0), (0.85, 250.0), (0.7, 250.0), (0.7, 250.0))


def _moon_radiance(
    cfg: MoonConfig,
    grid: Grid,
    view: SphereView,
    noise: Noise,
    octaves: list[int],
    sun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Radiance and hit mask of the Moon's disc in a crop: maria, Lommel-Seeliger light."""
    coarse = coarse_fbm(noise, view, grid.factor)
    fields = {
        "q": view.q,
        "u": view.chart[0],
        "v": view.chart[1],
        "log_footprint": view.log_footprint,
        "mare": coarse[..., 0],
        "detail": coarse[..., 1],
        "mu_sun": view.normal @ sun,
    }
    fields = {name: field.astype(np.float32) for name, field in fields.items()}
    level = float(ndtri(1.0 - cfg.mare_fraction))
    R2 = MOON_RADIUS_KM**2
    radiance = np.zeros((grid.K.height, grid.K.width), np.float32)
    hit = np.zeros(radiance.shape, bool)
    for r0, rows in grid.strips():
        up = {name: grid.upsample(field, r0, rows) for name, field in fields.items()}
        mare, detail = fine_detail(noise, octaves, up, grid.factor, ((0, 0), (1, 1)))
        mare += up["mare"]
        detail += up["detail"]
        maria = np.clip((mare - level) / 0.3 + 0.5, 0.0, 1.0)
        albedo = cfg.highland_albedo + maria * (cfg.mare_albedo - cfg.highland_albedo)
        albedo *= np.clip(1.0 + 0.25 * detail, 0.3, 2.0)
        mu_view = np.sqrt(np.maximum(R2 - up["q"], 0.0)) * (1.0 / MOON_RADIUS_KM)
        mu_sun = np.maximum(up["mu_sun"], 0.0)
        light = 2 * mu_sun / (mu_sun + mu_view + 1e-6)
        inside = up["q"] < R2
        radiance[r0 : r0 + rows] = np.where(inside, albedo * light, 0.0)
        hit[r0 : r0 + rows] = inside
    return radiance, hit


def render_moon(
    cfg: MoonConfig,
    K: Intrinsics,
    sun: np.ndarray,
    rng: np.random.Generator,
    radiance: np.ndarray,
    transmission: np.ndarray,
) -> None:
    """Paint the Moon's disc over ``radiance`` in the box it covers; it blocks the stars."""
    direction = np.asarray(cfg.direction)
    radius = math.radians(cfg.radius_deg)
    box = cone_box(K, direction, radius)
    if box is None:
        return
    # Bilinear upsampling puts the limb within factor^2 / (8 r) pixels: coarse only for big discs.
    factor = FACTOR if radius * math.sqrt(K.fx * K.fy) >= 32 * FACTOR else 1
    grid = Grid.of(crop(K, box), factor)
    view = sphere_view(grid, direction * MOON_RADIUS_KM / math.sin(radius), MOON_RADIUS_KM)
    noise = make_noise(rng, finest_cell_km(view), MOON_SPECTRA)
    moon, hit = _moon_radiance(cfg, grid, view, noise, fine_octaves(noise, view, factor), sun)
    u0, u1, v0, v1 = box
    radiance[v0:v1, u0:u1] = np.where(hit, moon, radiance[v0:v1, u0:u1])
    transmission[v0:v1, u0:u1] *= ~hit
