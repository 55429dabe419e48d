"""The Earth below a chaser in low orbit: land, ocean and its glint, ice, clouds, night
lights, the air over them and the limb's glow; and the shadow it casts on the light from beyond
(stars, the Sun's disc)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtri

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background.config import EARTH_RADIUS_KM, EarthConfig
from sdcnet.training.data.background.grid import FACTOR, Grid, SphereView, sphere_view
from sdcnet.training.data.background.noise import (
    Noise,
    coarse_fbm,
    fine_detail,
    fine_octaves,
    finest_cell_km,
    make_noise,
)

TWILIGHT_SURFACE = 0.012  # softness of the terminator on the ground, in cos(solar zenith)
TWILIGHT_AIR = 0.04  # the air is lit a few degrees past the ground terminator
ICE_EDGE_DEG = 3.0  # width of the polar ice edge, degrees of latitude
CITY_THRESHOLD = 1.6  # aux noise (std) above which land is urban
NIGHT_MU = 0.05  # cities show once the Sun is ~3 deg below the horizon
# (gain, largest cell km) of the noise channels: terrain (coastlines of dimension ~1.25), cloud
# (rough), land albedo (near scale-free, like natural images), aux (city clusters, cloud
# brightness: no continent-sized part).
EARTH_SPECTRA = ((0.6, 1000.0), (0.8, 1000.0), (0.85, 1000.0), (0.8, 100.0))
CLOUD_TEXTURE = 0.6  # relative cloud-top brightness per unit of pixel-scale cloud noise


def _softplus(x: np.ndarray, width: float) -> np.ndarray:
    """max(x, 0) with its corner rounded over ``width``: a soft terminator."""
    return width * np.logaddexp(0.0, x / width)


def _limb_depth(cfg: EarthConfig, altitude_km: np.ndarray) -> np.ndarray:
    """Optical depth along a ray grazing the Earth at a tangent altitude (km).

    Chapman's grazing column of an exponential layer: sqrt(2 pi R H) times its density at the
    tangent point, i.e. vertical depth x 2 sqrt(pi R / (2 H)) x exp(-h / H)."""
    depth = 0.0
    for tau, scale in ((cfg.haze_depth, cfg.haze_scale_km), (cfg.glow_depth, cfg.glow_scale_km)):
        depth = depth + 2 * tau * _grazing_airmass(scale) * np.exp(-altitude_km / scale)
    return depth


def _surface_depth(cfg: EarthConfig, mu_view: np.ndarray) -> np.ndarray:
    """Optical depth from the top of the air down to the surface, seen at cos(emission)."""
    depth = 0.0
    for tau, scale in ((cfg.haze_depth, cfg.haze_scale_km), (cfg.glow_depth, cfg.glow_scale_km)):
        depth = depth + tau / (mu_view + 1.0 / _grazing_airmass(scale))
    return depth


def _grazing_airmass(scale_km: float) -> float:
    return math.sqrt(math.pi * EARTH_RADIUS_KM / (2 * scale_km))


def _glint(
    cfg: EarthConfig, view: SphereView, mu_sun: np.ndarray, ray_sun: np.ndarray
) -> np.ndarray:
    """Sun glint on open water, radiance: Cox-Munk Gaussian slopes, Schlick Fresnel.

    L / (E / pi) = F exp(-tan^2 b / s^2) / (4 s^2 mu_view cos^4 b), b the tilt of the facet
    that mirrors the Sun into the camera (normal along the half vector of Sun and camera).
    Inputs are cosines: Sun-normal, and ray-Sun (ray_sun)."""
    slope2 = 0.003 + 0.00512 * cfg.wind_m_s
    half_norm = np.sqrt(np.maximum(2.0 - 2.0 * ray_sun, 1e-12))  # |sun - ray|
    cos_b = np.clip((mu_sun + view.mu_view) / half_norm, 1e-3, 1.0)
    fresnel = 0.02 + 0.98 * (1.0 - 0.5 * half_norm) ** 5  # cos(view, half) = |sun - ray| / 2
    tan2 = 1.0 / cos_b**2 - 1.0
    glint = fresnel * np.exp(-tan2 / slope2) / (4 * slope2 * np.maximum(view.mu_view, 0.05))
    return glint / cos_b**4 * ((mu_sun > 0) & view.hit)


def _earth_fields(
    cfg: EarthConfig, grid: Grid, view: SphereView, coarse: np.ndarray, sun: np.ndarray
) -> dict[str, np.ndarray]:
    """Smooth per-cell quantities of the Earth, to be upsampled strip by strip."""
    mu_sun = view.normal @ sun
    sin_lat = np.clip(view.normal @ np.asarray(cfg.pole), -1.0, 1.0)
    latitude = np.degrees(np.abs(np.arcsin(sin_lat)))
    albedo_noise, aux = coarse[..., 2], coarse[..., 3]
    night = np.clip(-mu_sun / NIGHT_MU, 0.0, 1.0)
    urban = np.clip((aux - CITY_THRESHOLD) / 0.3, 0.0, 1.0)
    return {
        "q": view.q,
        "u": view.chart[0],
        "v": view.chart[1],
        "log_footprint": view.log_footprint,
        "terrain": coarse[..., 0],
        "cloud": coarse[..., 1],
        "land_albedo": np.clip(cfg.land_albedo * np.exp(0.35 * albedo_noise), 0.05, 0.4),
        "ocean_albedo": cfg.ocean_albedo * np.exp(0.15 * albedo_noise),
        "cloud_albedo": np.minimum(cfg.cloud_albedo * np.exp(0.15 * aux), 0.95),
        "ice": (latitude - cfg.ice_latitude_deg) / ICE_EDGE_DEG + 0.8 * albedo_noise,
        "city": cfg.city_probability * night * urban * view.hit,
        "glint": _glint(cfg, view, mu_sun, grid.rays @ sun),
        "illum": _softplus(mu_sun, TWILIGHT_SURFACE),
        "illum_air": _softplus(mu_sun, TWILIGHT_AIR),
    }


@dataclass(frozen=True)
class _EarthLevels:
    """Per-frame thresholds on the noise fields (in noise std)."""

    land: float
    snow: float
    cloud: float
    coast_width: float  # the finest octave's amplitude: coastlines a pixel or two wide

    @classmethod
    def of(cls, cfg: EarthConfig, noise: Noise) -> _EarthLevels:
        land = float(ndtri(1.0 - cfg.land_fraction))
        cover = float(np.clip(cfg.cloud_cover, 1e-4, 1 - 1e-4))
        return cls(
            land=land,
            snow=land + cfg.snow_level,
            cloud=float(ndtri(1.0 - cover)) - cfg.cloud_softness / 2,
            coast_width=float(noise.amplitude[-1, 0]),
        )


def _earth_surface(
    cfg: EarthConfig,
    levels: _EarthLevels,
    up: dict[str, np.ndarray],
    detail: list[np.ndarray],
    rng: np.random.Generator,
) -> np.ndarray:
    """Radiance leaving the ground and the cloud tops (before the air), one strip."""
    terrain_detail, albedo_detail, cloud_detail = detail
    terrain = up["terrain"] + terrain_detail
    cloud_field = up["cloud"] + cloud_detail
    land = np.clip((terrain - levels.land) / levels.coast_width + 0.5, 0.0, 1.0)
    land_albedo = up["land_albedo"] * (1.0 + 0.35 * albedo_detail)
    albedo = up["ocean_albedo"] + land * (land_albedo - up["ocean_albedo"])
    snow = np.clip((terrain - levels.snow) / levels.coast_width + 0.5, 0.0, 1.0)
    ice = np.maximum(np.clip(up["ice"], 0.0, 1.0), snow)
    albedo += ice * (cfg.ice_albedo - albedo)
    excess = (cloud_field - levels.cloud) / cfg.cloud_softness
    cloud = np.clip(excess, 0.0, 1.0)
    inside = np.clip(0.6 + 0.4 * (cloud_field - levels.cloud), 0.6, 1.0)
    thick = np.minimum(up["cloud_albedo"] * inside * (1.0 + CLOUD_TEXTURE * cloud_detail), 0.95)
    albedo += cloud * (thick - albedo)
    clear_water = (1.0 - land) * (1.0 - ice) * (1.0 - cloud)
    radiance = albedo * up["illum"] + up["glint"] * clear_water
    _add_city_lights(cfg, up["city"] * land * (1.0 - cloud), radiance, rng)
    return radiance


def _add_city_lights(
    cfg: EarthConfig, probability: np.ndarray, radiance: np.ndarray, rng: np.random.Generator
) -> None:
    """Single-pixel lights, each pixel lit with its probability, log-normal radiance."""
    candidates = np.flatnonzero(probability > 0)
    if len(candidates) == 0:
        return
    lit = candidates[rng.random(len(candidates)) < probability.ravel()[candidates]]
    brightness = cfg.city_radiance * np.exp(0.7 * rng.standard_normal(len(lit)))
    radiance.ravel()[lit] += brightness.astype(np.float32)


def _earth_strip(
    cfg: EarthConfig,
    levels: _EarthLevels,
    noise: Noise,
    octaves: list[int],
    up: dict[str, np.ndarray],
    factor: int,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Radiance and star transmission of one strip: surface and air where the ray hits, the
    limb's glow where it grazes, untouched space elsewhere."""
    R2 = EARTH_RADIUS_KM**2
    q = up["q"]
    hit = q < R2
    radiance = np.zeros(q.shape, np.float32)
    transmission = np.ones(q.shape, np.float32)
    if hit.any():
        detail = fine_detail(noise, octaves, up, factor, ((0, 0), (0, 2), (1, 1)))
        surface = _earth_surface(cfg, levels, up, detail, rng)
        mu_view = np.sqrt(np.maximum(R2 - q, 0.0)) * (1.0 / EARTH_RADIUS_KM)
        seen = np.exp(-_surface_depth(cfg, mu_view))
        air = cfg.sky_radiance * up["illum_air"] * (1.0 - seen)
        radiance = np.where(hit, surface * seen + air, 0.0).astype(np.float32)
        transmission[hit] = 0.0
    top = EARTH_RADIUS_KM + 12 * max(cfg.haze_scale_km, cfg.glow_scale_km)
    grazing = ~hit & (q < top**2)
    if grazing.any():
        seen = np.exp(-_limb_depth(cfg, np.sqrt(q[grazing]) - EARTH_RADIUS_KM))
        radiance[grazing] = cfg.sky_radiance * up["illum_air"][grazing] * (1.0 - seen)
        transmission[grazing] = seen
    return radiance, transmission


def render_earth(
    cfg: EarthConfig,
    K: Intrinsics,
    sun: np.ndarray,
    rng: np.random.Generator,
    radiance: np.ndarray,
    transmission: np.ndarray,
) -> None:
    """Write the Earth (surface, clouds, air, limb glow) into ``radiance``, and its shadow on
    the light from beyond (stars, the Sun's disc) into ``transmission``."""
    grid = Grid.of(K, FACTOR)
    centre = (EARTH_RADIUS_KM + cfg.altitude_km) * np.asarray(cfg.nadir)
    view = sphere_view(grid, centre, EARTH_RADIUS_KM)
    noise = make_noise(rng, finest_cell_km(view), EARTH_SPECTRA)
    fields = _earth_fields(cfg, grid, view, coarse_fbm(noise, view, FACTOR), sun)
    fields = {name: field.astype(np.float32) for name, field in fields.items()}
    octaves = fine_octaves(noise, view, FACTOR)
    levels = _EarthLevels.of(cfg, noise)
    for r0, rows in grid.strips():
        up = {name: grid.upsample(field, r0, rows) for name, field in fields.items()}
        strip, seen = _earth_strip(cfg, levels, noise, octaves, up, FACTOR, rng)
        radiance[r0 : r0 + rows] = strip
        transmission[r0 : r0 + rows] *= seen


def earth_transmission(cfg: EarthConfig, direction: np.ndarray) -> float:
    """Share of light from far beyond the Earth that reaches the camera along a direction."""
    centre = (EARTH_RADIUS_KM + cfg.altitude_km) * np.asarray(cfg.nadir)
    b = float(direction @ centre)
    if b <= 0:
        return 1.0
    altitude = math.sqrt(max(float(centre @ centre) - b * b, 0.0)) - EARTH_RADIUS_KM
    return 0.0 if altitude < 0 else float(np.exp(-_limb_depth(cfg, altitude)))
