"""The Sun: its limb-darkened disc, and its light scattered inside the lens (halo, veiling
glare, ghosts), which falls on the spacecraft too."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background.config import SUN_RADIUS_DEG, BackgroundConfig, OpticsConfig
from sdcnet.training.data.background.earth import earth_transmission
from sdcnet.training.data.background.geometry import angle_to_frame_deg, cone_box
from sdcnet.training.data.background.grid import FACTOR, Grid

# A disc of radius r (rad) of radiance L gives irradiance L * pi r^2; the unit radiance is that
# irradiance / pi (a white Lambertian surface), so the mean disc radiance is 1 / r^2 (~46 000).
SUN_DISC_RADIANCE = 1.0 / math.radians(SUN_RADIUS_DEG) ** 2
SUN_LIMB_DARKENING = 0.6  # linear law I(mu) = 1 - u (1 - mu)
GLARE_REACH_DEG = 60.0  # veiling glare tapers to nothing when the Sun is this far off the frame
GLARE_REFERENCE_DEG = 5.0  # the glare strength is its radiance at this angle from the Sun


def _sun_visibility(config: BackgroundConfig, sun: np.ndarray) -> float:
    """Share of the Sun's light reaching the camera past the Earth and the Moon."""
    seen = 1.0
    if config.earth is not None:
        seen *= earth_transmission(config.earth, sun)
    if config.moon is not None:
        moon = config.moon
        if sun @ np.asarray(moon.direction) > math.cos(math.radians(moon.radius_deg)):
            seen = 0.0
    return seen


def _glare(optics: OpticsConfig, theta_deg: np.ndarray, floor_deg: float) -> np.ndarray:
    """Veiling glare: power law in the angle to the Sun (deg), flat inside ``floor_deg``."""
    ratio = np.maximum(theta_deg, floor_deg) / GLARE_REFERENCE_DEG
    return optics.glare_radiance * ratio**-optics.glare_exponent


def _halo(optics: OpticsConfig, theta_deg: np.ndarray, floor_deg: float) -> np.ndarray:
    """Bloom around the disc: exponential in the angle from its edge, flat inside ``floor_deg``."""
    beyond = np.maximum(theta_deg, floor_deg) - SUN_RADIUS_DEG
    return optics.halo_radiance * np.exp(-beyond / optics.halo_width_deg)


@dataclass(frozen=True)
class _StrayLayout:
    """How the Sun's stray light splits between the coarse grid and the pixels near the Sun.

    The coarse grid carries the glare (and the halo if it is wide enough to be resolved),
    flattened inside ``floor_deg``; the pixels within ``reach_deg`` get the disc and the rest."""

    floor_deg: float
    reach_deg: float
    halo_on_grid: bool

    @classmethod
    def of(cls, optics: OpticsConfig, K: Intrinsics) -> _StrayLayout:
        cell_deg = FACTOR * math.degrees(1.0 / math.sqrt(K.fx * K.fy))
        floor = max(SUN_RADIUS_DEG, 3 * cell_deg)
        on_grid = optics.halo_width_deg >= 2 * cell_deg
        fade_out = math.log(max(optics.halo_radiance, 1.0) / 1e-3) * optics.halo_width_deg
        reach = floor if on_grid else max(floor, SUN_RADIUS_DEG + fade_out)
        return cls(floor, reach, on_grid)

    def coarse(self, optics: OpticsConfig, theta_deg: np.ndarray) -> np.ndarray:
        stray = _glare(optics, theta_deg, self.floor_deg)
        return stray + _halo(optics, theta_deg, self.floor_deg) if self.halo_on_grid else stray


def _add_stray_light(
    optics: OpticsConfig,
    layout: _StrayLayout,
    K: Intrinsics,
    sun: np.ndarray,
    gain: float,
    radiance: np.ndarray,
) -> None:
    """The smooth part of the glare (and halo), from the coarse grid, over the whole frame."""
    grid = Grid.of(K, FACTOR)
    theta = np.degrees(np.arccos(np.clip(grid.rays @ sun, -1.0, 1.0)))
    low = (gain * layout.coarse(optics, theta)).astype(np.float32)
    for r0, rows in grid.strips():
        radiance[r0 : r0 + rows] += grid.upsample(low, r0, rows)


def _add_disc(
    optics: OpticsConfig,
    layout: _StrayLayout,
    K: Intrinsics,
    sun: np.ndarray,
    gain: float,
    radiance: np.ndarray,
    transmission: np.ndarray,
) -> None:
    """Per pixel near the Sun: the limb-darkened disc (behind bodies and air) and the steep
    parts of halo and glare that the coarse grid left out."""
    box = cone_box(K, sun, math.radians(layout.reach_deg))
    if box is None:
        return
    u0, u1, v0, v1 = box
    x = (np.arange(u0, u1) - K.cx) / K.fx
    y = (np.arange(v0, v1) - K.cy) / K.fy
    cos_theta = ((x * sun[0])[None, :] + (y * sun[1])[:, None] + sun[2]) / np.sqrt(
        (x**2)[None, :] + (y**2)[:, None] + 1.0
    )
    theta = np.degrees(np.arccos(np.clip(cos_theta, -1.0, 1.0)))
    pixel_deg = math.degrees(1.0 / math.sqrt(K.fx * K.fy))
    cover = np.clip((SUN_RADIUS_DEG - theta) / pixel_deg + 0.5, 0.0, 1.0)
    mu = np.sqrt(np.clip(1.0 - (theta / SUN_RADIUS_DEG) ** 2, 0.0, 1.0))
    limb = (1 - SUN_LIMB_DARKENING * (1 - mu)) / (1 - SUN_LIMB_DARKENING / 3)
    disc = SUN_DISC_RADIANCE * limb * cover * transmission[v0:v1, u0:u1]
    exact = _glare(optics, theta, SUN_RADIUS_DEG) + _halo(optics, theta, SUN_RADIUS_DEG)
    radiance[v0:v1, u0:u1] += (disc + gain * (exact - layout.coarse(optics, theta))).astype(
        np.float32
    )


def _add_ghosts(
    optics: OpticsConfig, K: Intrinsics, sun: np.ndarray, gain: float, radiance: np.ndarray
) -> None:
    """Soft discs and rings along the line from the Sun's image through the principal point."""
    su, sv = K.project(sun)
    diagonal = math.hypot(K.width, K.height)
    for ghost in optics.ghosts:
        cu = K.cx + ghost.position * (su - K.cx)
        cv = K.cy + ghost.position * (sv - K.cy)
        r = ghost.radius * diagonal
        soft = max(ghost.softness * r, 0.5)
        reach = r + soft
        u0, u1 = int(max(math.floor(cu - reach), 0)), int(min(math.ceil(cu + reach) + 1, K.width))
        v0, v1 = int(max(math.floor(cv - reach), 0)), int(min(math.ceil(cv + reach) + 1, K.height))
        if u1 <= u0 or v1 <= v0:
            continue
        du = np.arange(u0, u1, dtype=np.float32) - np.float32(cu)
        dv = np.arange(v0, v1, dtype=np.float32) - np.float32(cv)
        d = np.hypot(du[None, :], dv[:, None])
        ring = ghost.ring_width > 0
        edge = ghost.ring_width * r / 2 - np.abs(d - r) if ring else r - d
        profile = np.clip(edge / soft + 0.5, 0.0, 1.0)
        radiance[v0:v1, u0:u1] += np.float32(gain * ghost.radiance) * profile


def add_sun(
    config: BackgroundConfig,
    K: Intrinsics,
    sun: np.ndarray,
    radiance: np.ndarray,
    transmission: np.ndarray,
) -> np.ndarray | None:
    """The Sun's disc (into ``radiance``, behind everything), and its halo, veiling glare and
    ghosts, when it is near enough to the frame: returned apart (None when there are none),
    since they are light scattered inside the lens and fall on the spacecraft too."""
    off_frame = angle_to_frame_deg(K, sun)
    visible = _sun_visibility(config, sun)
    if off_frame >= GLARE_REACH_DEG or visible <= 0:
        return None
    gain = visible * min((GLARE_REACH_DEG - off_frame) / 10.0, 1.0)
    layout = _StrayLayout.of(config.optics, K)
    stray = np.zeros_like(radiance)
    _add_stray_light(config.optics, layout, K, sun, gain, stray)
    if sun[2] > 0:
        _add_disc(config.optics, layout, K, sun, gain, radiance, transmission)
        _add_ghosts(config.optics, K, sun, gain * math.exp(-off_frame / 5.0), stray)
    return stray
