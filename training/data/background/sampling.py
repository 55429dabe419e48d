"""Drawing a background for a camera and a Sun: its kind, stars, optics, and where the Earth
or the Moon lies and how it is lit."""

from __future__ import annotations

import math

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background.config import (
    BACKGROUND_KINDS,
    EARTH_RADIUS_KM,
    KIND_WEIGHTS,
    SUN_RADIUS_DEG,
    BackgroundConfig,
    EarthConfig,
    GhostConfig,
    MoonConfig,
    OpticsConfig,
    StarsConfig,
)
from sdcnet.training.data.background.geometry import frame_half_angles, sun_in_view, unit

SUN_KIND_MARGIN_DEG = 10.0  # the `sun` kind needs the Sun this close to the frame, or inside


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def sample_sun_near_view(
    rng: np.random.Generator, K: Intrinsics, margin_deg: float = SUN_KIND_MARGIN_DEG
) -> np.ndarray:
    """A Sun direction (camera frame) inside the frame or up to ``margin_deg`` outside it.

    For scene samplers that want a `sun` background: the image position is uniform over the
    frame widened by the margin (converted to pixels at the focal length)."""
    pad_u = K.fx * math.tan(math.radians(margin_deg))
    pad_v = K.fy * math.tan(math.radians(margin_deg))
    while True:  # the widened rectangle's corners lie farther than the margin: drawn again
        u = rng.uniform(-0.5 - pad_u, K.width - 0.5 + pad_u)
        v = rng.uniform(-0.5 - pad_v, K.height - 0.5 + pad_v)
        sun = unit(K.pixel_rays(u, v))
        if sun_in_view(K, sun, margin_deg):
            return sun


def _eligible_kinds(K: Intrinsics, sun: np.ndarray) -> list[str]:
    """Kinds that fit this Sun: `sun` needs it near the frame; a full Earth would eclipse it."""
    kinds = list(BACKGROUND_KINDS)
    if not sun_in_view(K, sun, SUN_KIND_MARGIN_DEG):
        kinds.remove("sun")
    if sun_in_view(K, sun, 0.0):
        kinds.remove("earth-nadir")
        kinds.remove("earth-oblique")
    return kinds


def sample_background(
    rng: np.random.Generator, K: Intrinsics, sun: np.ndarray, kind: str | None = None
) -> BackgroundConfig:
    """Draw one background for a camera and Sun (unit vector, camera frame).

    ``kind`` None draws one with ``KIND_WEIGHTS`` among the kinds that fit the Sun (see
    ``_eligible_kinds``). The `sun` kind needs the Sun within ``SUN_KIND_MARGIN_DEG`` of the
    frame (``sample_sun_near_view`` draws such a direction): the Sun is the caller's."""
    sun = unit(sun)
    if kind is None:
        kinds = _eligible_kinds(K, sun)
        weights = np.array([KIND_WEIGHTS[BACKGROUND_KINDS.index(k)] for k in kinds])
        kind = kinds[rng.choice(len(kinds), p=weights / weights.sum())]
    if kind not in BACKGROUND_KINDS:
        raise ValueError(f"unknown background kind {kind!r}; expected one of {BACKGROUND_KINDS}")
    if kind == "sun" and not sun_in_view(K, sun, SUN_KIND_MARGIN_DEG):
        raise ValueError(f"kind 'sun' needs the Sun within {SUN_KIND_MARGIN_DEG} deg of the frame")
    stars = _sample_stars(rng)
    optics = _sample_optics(rng)
    earth = _sample_earth(rng, K, sun, kind) if kind.startswith("earth") else None
    moon = _sample_moon(rng, K, sun) if kind == "moon" else None
    return BackgroundConfig(kind, stars, optics, earth, moon)


def _sample_stars(rng: np.random.Generator) -> StarsConfig:
    low = _log_uniform(rng, 0.002, 0.02)
    return StarsConfig(
        density_per_mpx=_log_uniform(rng, 20.0, 600.0),
        brightness_min=low,
        brightness_max=max(_log_uniform(rng, 0.1, 5.0), 5 * low),
        fraction_2x2=float(rng.uniform(0.0, 0.05)),
    )


def _sample_optics(rng: np.random.Generator) -> OpticsConfig:
    ghosts = tuple(
        GhostConfig(
            position=float(rng.uniform(-1.5, 0.7)),
            radius=float(rng.uniform(0.01, 0.12)),
            ring_width=float(rng.uniform(0.1, 0.3)) if rng.random() < 0.3 else 0.0,
            softness=float(rng.uniform(0.1, 0.5)),
            radiance=_log_uniform(rng, 0.003, 0.3),
        )
        for _ in range(int(rng.integers(2, 7)))
    )
    return OpticsConfig(
        halo_radiance=_log_uniform(rng, 10.0, 1000.0),
        halo_width_deg=float(rng.uniform(0.05, 0.5)),
        glare_radiance=_log_uniform(rng, 0.003, 0.5),
        glare_exponent=float(rng.uniform(2.0, 3.0)),
        ghosts=ghosts,
    )


def _altitude_limit_km(half_angle_deg: float) -> float:
    """Highest altitude from which the Earth's disc still covers a cone of this half-angle."""
    return EARTH_RADIUS_KM / math.sin(math.radians(min(half_angle_deg, 89.0))) - EARTH_RADIUS_KM


def _earth_axis_angle(rng: np.random.Generator, K: Intrinsics, kind: str, rho: float) -> float:
    """Angle (deg) between the optical axis and the Earth's centre for the kind of view.

    ``rho`` is the Earth's angular radius; ``rho - angle`` is how far the axis points below the
    horizon."""
    inscribed, corner = frame_half_angles(K)
    if kind == "earth-nadir":
        return float(rng.uniform(0.0, max(min(20.0, rho - corner - 1.0), 0.0)))
    if kind == "earth-oblique":
        low = max(0.7 * corner, 0.5)
        return rho - _log_uniform(rng, low, max(rho - 20.0, low * 1.0001))
    return rho - float(rng.uniform(-0.8, 0.8)) * inscribed


def _axis_normal(nadir: np.ndarray, distance_km: float) -> np.ndarray:
    """Earth normals (n, 3) where the optical axis meets the surface, or passes closest to it."""
    centre = distance_km * nadir
    b = centre[:, 2]
    q = distance_km**2 - b**2
    t = np.where(q < EARTH_RADIUS_KM**2, b - np.sqrt(np.maximum(EARTH_RADIUS_KM**2 - q, 0)), b)
    point = np.zeros_like(centre)
    point[:, 2] = t
    return unit(point - centre)


def _earth_direction(
    rng: np.random.Generator,
    alpha_deg: float,
    rho_deg: float,
    altitude_km: float,
    sun: np.ndarray,
) -> np.ndarray:
    """Earth centre direction at ``alpha_deg`` from the axis, its azimuth set by the lighting.

    A target cos(solar zenith) at the viewed point is drawn (day 70 %, twilight 12 %, night
    18 %) and the azimuth that comes closest is kept, preferring those where the Earth does not
    eclipse the Sun (the chaser and its target are sunlit)."""
    lighting = rng.choice(3, p=[0.7, 0.12, 0.18])
    target = rng.uniform(*[(0.1, 1.0), (-0.12, 0.12), (-1.0, -0.12)][lighting])
    phi = rng.uniform(0, 2 * np.pi) + np.linspace(0, 2 * np.pi, 180, endpoint=False)
    a = math.radians(alpha_deg)
    nadir = np.stack([math.sin(a) * np.cos(phi), math.sin(a) * np.sin(phi)], axis=1)
    nadir = np.column_stack([nadir, np.full(len(phi), math.cos(a))])
    mu = _axis_normal(nadir, EARTH_RADIUS_KM + altitude_km) @ sun
    eclipse = nadir @ sun > math.cos(math.radians(rho_deg + SUN_RADIUS_DEG + 0.5))
    return nadir[np.argmin(np.abs(mu - target) + 10.0 * eclipse)]


def _sample_earth(
    rng: np.random.Generator, K: Intrinsics, sun: np.ndarray, kind: str
) -> EarthConfig:
    altitude = float(rng.uniform(300.0, 1200.0))
    if kind == "earth-nadir":
        corner = frame_half_angles(K)[1]
        altitude = float(np.clip(altitude, 300.0, max(_altitude_limit_km(corner + 1.0), 300.0)))
    rho = math.degrees(math.asin(EARTH_RADIUS_KM / (EARTH_RADIUS_KM + altitude)))
    alpha = _earth_axis_angle(rng, K, kind, rho)
    nadir = _earth_direction(rng, alpha, rho, altitude, sun)
    return EarthConfig(
        altitude_km=altitude,
        nadir=tuple(float(x) for x in nadir),
        pole=tuple(float(x) for x in unit(rng.normal(size=3))),
        land_fraction=float(rng.uniform(0.1, 0.6)),
        land_albedo=float(rng.uniform(0.1, 0.25)),
        ocean_albedo=float(rng.uniform(0.03, 0.08)),
        ice_albedo=float(rng.uniform(0.6, 0.85)),
        ice_latitude_deg=float(rng.uniform(50.0, 80.0)),
        snow_level=float(rng.uniform(1.0, 3.0)),
        cloud_cover=float(rng.uniform(0.0, 0.9)),
        cloud_albedo=float(rng.uniform(0.5, 0.9)),
        cloud_softness=float(rng.uniform(0.05, 0.5)),
        wind_m_s=float(rng.uniform(1.0, 12.0)),
        haze_depth=float(rng.uniform(0.05, 0.25)),
        haze_scale_km=float(rng.uniform(7.0, 10.0)),
        glow_depth=_log_uniform(rng, 0.005, 0.03),
        glow_scale_km=float(rng.uniform(12.0, 25.0)),
        sky_radiance=float(rng.uniform(0.15, 0.45)),
        city_probability=float(rng.uniform(0.05, 0.5)),
        city_radiance=_log_uniform(rng, 0.05, 0.5),
    )


def _sample_moon(rng: np.random.Generator, K: Intrinsics, sun: np.ndarray) -> MoonConfig:
    """A Moon whose disc lands at least partly in the frame, not in front of the Sun."""
    radius = _log_uniform(rng, 0.25, 3.0)
    pad_u = 0.7 * K.fx * math.tan(math.radians(radius))
    pad_v = 0.7 * K.fy * math.tan(math.radians(radius))
    for _ in range(32):
        u = rng.uniform(-0.5 - pad_u, K.width - 0.5 + pad_u)
        v = rng.uniform(-0.5 - pad_v, K.height - 0.5 + pad_v)
        direction = unit(K.pixel_rays(u, v))
        if direction @ sun < math.cos(math.radians(radius + SUN_RADIUS_DEG + 0.2)):
            break
    return MoonConfig(
        direction=tuple(float(x) for x in direction),
        radius_deg=radius,
        highland_albedo=float(rng.uniform(0.11, 0.16)),
        mare_albedo=float(rng.uniform(0.06, 0.09)),
        mare_fraction=float(rng.uniform(0.1, 0.5)),
    )
