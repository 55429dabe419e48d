"""What the camera sees behind the spacecraft: stars, the Earth, the Moon and the Sun.

The output is linear radiance on the camera's pixel grid, in the project's unit: 1.0 is a white
Lambertian surface lit by the Sun at normal incidence (a lit spacecraft panel). There is no PSF,
noise or quantisation here: the camera simulation applies them to spacecraft plus background.

Geometry is exact per pixel (camera frame x right, y down, z forward, km): ray-sphere for the
Earth and the Moon, angles for the Sun. Smooth quantities (surface chart coordinates, lighting,
pixel footprint, the coarse texture octaves) are computed on a grid ``FACTOR`` times coarser and
upsampled bilinearly; the octaves near the pixel scale, the limb and the disc edges are evaluated
per pixel, in row strips so that memory stays at a few full-frame arrays.

Textures are fractal value noise (fBm): a random periodic tile made from the generator, sampled
with ``cv2.remap`` in a chart of the surface (km), one remap per octave. Each octave fades out
where it falls below the local pixel footprint, so nothing aliases and nothing is wasted.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.special import ndtri

from sdcnet.camera import Intrinsics

BACKGROUND_KINDS = ("stars", "earth-nadir", "earth-oblique", "earth-limb", "moon", "sun")
KIND_WEIGHTS = (0.35, 0.2, 0.15, 0.15, 0.07, 0.08)

EARTH_RADIUS_KM = 6371.0
MOON_RADIUS_KM = 1737.4
SUN_RADIUS_DEG = 0.267
# A disc of radius r (rad) of radiance L gives irradiance L * pi r^2; the unit radiance is that
# irradiance / pi (a white Lambertian surface), so the mean disc radiance is 1 / r^2 (~46 000).
SUN_DISC_RADIANCE = 1.0 / math.radians(SUN_RADIUS_DEG) ** 2
SUN_LIMB_DARKENING = 0.6  # linear law I(mu) = 1 - u (1 - mu)
SUN_KIND_MARGIN_DEG = 10.0  # the `sun` kind needs the Sun this close to the frame, or inside
GLARE_REACH_DEG = 60.0  # veiling glare tapers to nothing when the Sun is this far off the frame
GLARE_REFERENCE_DEG = 5.0  # the glare strength is its radiance at this angle from the Sun

FACTOR = 4  # coarse grid: one cell per FACTOR x FACTOR pixels
STRIP_PIXELS = 65536  # full-resolution work goes in strips of rows, 256 kB per float32 array
TILE = 256  # noise tile, cells per side
FULL_RES_OCTAVES = 3  # octaves evaluated per pixel (the rest on the coarse grid)

TWILIGHT_SURFACE = 0.012  # softness of the terminator on the ground, in cos(solar zenith)
TWILIGHT_AIR = 0.04  # the air is lit a few degrees past the ground terminator
ICE_EDGE_DEG = 3.0  # width of the polar ice edge, degrees of latitude
CITY_THRESHOLD = 1.6  # aux noise (std) above which land is urban
NIGHT_MU = 0.05  # cities show once the Sun is ~3 deg below the horizon
# (gain, largest cell km) of the noise channels. Earth: terrain (coastlines of dimension ~1.25),
# cloud (rough), land albedo (near scale-free, like natural images), aux (city clusters, cloud
# brightness: no continent-sized part). Moon: maria, brightness detail; two channels unused.
EARTH_SPECTRA = ((0.6, 1000.0), (0.8, 1000.0), (0.85, 1000.0), (0.8, 100.0))
MOON_SPECTRA = ((0.6, 250.0), (0.85, 250.0), (0.7, 250.0), (0.7, 250.0))
CLOUD_TEXTURE = 0.6  # relative cloud-top brightness per unit of pixel-scale cloud noise


@dataclass(frozen=True)
class StarsConfig:
    """Point stars: Poisson count, log-uniform radiance between the two bounds."""

    density_per_mpx: float  # mean count per million pixels
    brightness_min: float  # radiance
    brightness_max: float  # radiance; above 1 a star is as bright as a lit spacecraft
    fraction_2x2: float  # share of the stars drawn as 2 x 2 pixel blocks


@dataclass(frozen=True)
class EarthConfig:
    """The Earth below a chaser in low orbit, its surface, clouds, night lights and air."""

    altitude_km: float
    nadir: tuple[float, float, float]  # unit vector camera -> Earth centre, camera frame
    pole: tuple[float, float, float]  # unit vector along the Earth's axis (sets latitudes)
    land_fraction: float  # of the whole terrain field; a frame sees ocean only, land only, coast
    land_albedo: float  # median over land
    ocean_albedo: float
    ice_albedo: float  # polar ice and mountain snow
    ice_latitude_deg: float  # polar ice starts here
    snow_level: float  # terrain field above the coast, in noise std, where snow lies
    cloud_cover: float  # fraction of the surface under cloud
    cloud_albedo: float  # of thick cloud
    cloud_softness: float  # width of the cloud edges, in noise std
    wind_m_s: float  # sea-surface wind: width and peak of the sun glint (Cox-Munk slopes)
    haze_depth: float  # vertical optical depth of the low haze
    haze_scale_km: float  # its scale height
    glow_depth: float  # vertical optical depth of the thin upper layer (the limb glow)
    glow_scale_km: float
    sky_radiance: float  # radiance of an optically thick, sunlit atmosphere
    city_probability: float  # chance that an urban pixel on the night side holds a light
    city_radiance: float  # median radiance of a city light


@dataclass(frozen=True)
class MoonConfig:
    """The Moon's disc: direction, apparent size and the albedos of highlands and maria."""

    direction: tuple[float, float, float]  # unit vector to the Moon's centre, camera frame
    radius_deg: float  # apparent radius
    highland_albedo: float
    mare_albedo: float
    mare_fraction: float


@dataclass(frozen=True)
class GhostConfig:
    """One lens-flare ghost on the line from the Sun's image through the principal point."""

    position: float  # 1 at the Sun's image, 0 at the principal point, negative beyond it
    radius: float  # fraction of the frame diagonal
    ring_width: float  # fraction of the radius; 0 for a filled disc
    softness: float  # edge width, fraction of the radius
    radiance: float  # when the Sun is in view


@dataclass(frozen=True)
class OpticsConfig:
    """Stray sunlight in the camera: halo around the disc, veiling glare, ghosts."""

    halo_radiance: float  # at the disc's edge
    halo_width_deg: float  # exponential fall-off
    glare_radiance: float  # at GLARE_REFERENCE_DEG from the Sun
    glare_exponent: float  # power-law fall-off with the angle to the Sun
    ghosts: tuple[GhostConfig, ...]


@dataclass(frozen=True)
class BackgroundConfig:
    """Everything a background depends on besides the camera, the Sun and the texture seed."""

    kind: str
    stars: StarsConfig
    optics: OpticsConfig
    earth: EarthConfig | None = None
    moon: MoonConfig | None = None

    def metadata(self) -> dict:
        """Plain, rounded, JSON-serialisable copy for the dataset's sample records."""
        return _plain(dataclasses.asdict(self))


def _plain(value):
    """Dicts, lists, floats to 6 significant digits: what json.dumps takes and a reader wants."""
    if isinstance(value, dict):
        return {key: _plain(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(item) for item in value]
    if isinstance(value, float | np.floating):
        return float(f"{float(value):.6g}")
    if isinstance(value, np.integer):
        return int(value)
    return value


# ----------------------------------------------------------------------------- small geometry


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` to an orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = _unit(np.cross(axis, helper))
    return a, np.cross(axis, a)


def _log_uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(np.exp(rng.uniform(np.log(low), np.log(high))))


def _softplus(x: np.ndarray, width: float) -> np.ndarray:
    """max(x, 0) with its corner rounded over ``width``: a soft terminator."""
    return width * np.logaddexp(0.0, x / width)


def _frame_half_angles(K: Intrinsics) -> tuple[float, float]:
    """Angles (deg) from the optical axis to the nearest frame edge and the farthest corner."""
    u0, u1, v0, v1 = -0.5, K.width - 0.5, -0.5, K.height - 0.5
    edges = K.pixel_rays(np.array([u0, u1, K.cx, K.cx]), np.array([K.cy, K.cy, v0, v1]))
    corners = K.pixel_rays(np.array([u0, u1, u0, u1]), np.array([v0, v0, v1, v1]))

    def off_axis(rays):
        return np.degrees(np.arctan(np.hypot(rays[:, 0], rays[:, 1])))

    return float(off_axis(edges).min()), float(off_axis(corners).max())


def _angle_to_frame_deg(K: Intrinsics, direction: np.ndarray) -> float:
    """Angle (deg) from a direction to the nearest ray of the frame; 0 if it projects inside."""
    d = _unit(direction)
    if d[2] > 0:
        u, v = K.project(d)
        if -0.5 <= u <= K.width - 0.5 and -0.5 <= v <= K.height - 0.5:
            return 0.0
    s = np.linspace(0.0, 1.0, 257)
    us = np.concatenate([s * K.width, s * K.width, np.zeros(257), np.full(257, 1.0 * K.width)])
    vs = np.concatenate([np.zeros(257), np.full(257, 1.0 * K.height), s * K.height, s * K.height])
    rays = _unit(K.pixel_rays(us - 0.5, vs - 0.5))
    return float(np.degrees(np.arccos(np.clip((rays @ d).max(), -1.0, 1.0))))


def sun_in_view(K: Intrinsics, sun: np.ndarray, margin_deg: float = 0.0) -> bool:
    """Whether the Sun's direction projects inside the frame or within ``margin_deg`` of it."""
    return _angle_to_frame_deg(K, sun) <= margin_deg


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
        sun = _unit(K.pixel_rays(u, v))
        if sun_in_view(K, sun, margin_deg):
            return sun


def _cone_box(
    K: Intrinsics, direction: np.ndarray, radius_rad: float, margin_px: int = 2
) -> tuple[int, int, int, int] | None:
    """Pixel box (u0, u1, v0, v1) holding the image of a cone of directions, or None if empty."""
    a, b = _basis(direction)
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


def _crop(K: Intrinsics, box: tuple[int, int, int, int]) -> Intrinsics:
    u0, u1, v0, v1 = box
    return Intrinsics(K.fx, K.fy, K.cx - u0, K.cy - v0, u1 - u0, v1 - v0)


# ----------------------------------------------------------------------------- sampling


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
    sun = _unit(sun)
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
    inscribed, corner = _frame_half_angles(K)
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
    return _unit(point - centre)


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
        corner = _frame_half_angles(K)[1]
        altitude = float(np.clip(altitude, 300.0, max(_altitude_limit_km(corner + 1.0), 300.0)))
    rho = math.degrees(math.asin(EARTH_RADIUS_KM / (EARTH_RADIUS_KM + altitude)))
    alpha = _earth_axis_angle(rng, K, kind, rho)
    nadir = _earth_direction(rng, alpha, rho, altitude, sun)
    return EarthConfig(
        altitude_km=altitude,
        nadir=tuple(float(x) for x in nadir),
        pole=tuple(float(x) for x in _unit(rng.normal(size=3))),
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
        direction = _unit(K.pixel_rays(u, v))
        if direction @ sun < math.cos(math.radians(radius + SUN_RADIUS_DEG + 0.2)):
            break
    return MoonConfig(
        direction=tuple(float(x) for x in direction),
        radius_deg=radius,
        highland_albedo=float(rng.uniform(0.11, 0.16)),
        mare_albedo=float(rng.uniform(0.06, 0.09)),
        mare_fraction=float(rng.uniform(0.1, 0.5)),
    )


# ----------------------------------------------------------------------------- coarse grid


@dataclass(frozen=True)
class _Grid:
    """Cells ``factor`` times coarser than the pixels, one cell of padding all round.

    Cell (i, j) sits at pixel coordinates (factor (j - 1) + (factor - 1) / 2, same for i), the
    sampling that ``cv2.resize`` assumes, so ``upsample`` lands on the pixel centres."""

    K: Intrinsics
    factor: int
    rays: np.ndarray  # (h, w, 3) unit directions
    pixel_rad: np.ndarray  # (h, w) angular size of one full-resolution pixel, radians

    @classmethod
    def of(cls, K: Intrinsics, factor: int) -> _Grid:
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
class _SphereView:
    """A sphere seen on the coarse grid: per cell, the surface (or the closest approach) point.

    ``q`` is the squared distance from the centre to the ray (D^2 + b^2 for rays pointing away),
    smooth across the limb so that it upsamples to the exact per-pixel hit test q < R^2."""

    hit: np.ndarray  # (h, w) bool
    q: np.ndarray  # (h, w) km^2
    normal: np.ndarray  # (h, w, 3) at the hit, or at the closest approach for a miss
    mu_view: np.ndarray  # (h, w) cos of the emission angle, floored at 0.02
    log_footprint: np.ndarray  # (h, w) log2 of the pixel footprint on the surface, km
    chart: tuple[np.ndarray, np.ndarray]  # (h, w) orthographic surface coordinates, km


def _sphere_view(grid: _Grid, centre_km: np.ndarray, radius_km: float) -> _SphereView:
    b = grid.rays @ centre_km
    d2 = float(centre_km @ centre_km)
    q = np.where(b > 0, d2 - b**2, d2 + b**2)
    hit = q < radius_km**2
    t = np.where(hit, b - np.sqrt(np.maximum(radius_km**2 - q, 0.0)), np.maximum(np.abs(b), 1e-3))
    normal = _unit(t[..., None] * grid.rays - centre_km)
    mu_view = np.clip(-np.sum(normal * grid.rays, axis=-1), 0.02, 1.0)
    footprint = t * grid.pixel_rad / np.sqrt(mu_view)
    e1, e2 = _basis(_unit(-centre_km))
    middle = normal[normal.shape[0] // 2, normal.shape[1] // 2]
    chart = tuple((radius_km * (normal @ e - middle @ e)).astype(np.float32) for e in (e1, e2))
    return _SphereView(
        hit,
        q.astype(np.float32),
        normal,
        mu_view,
        np.log2(footprint).astype(np.float32),
        chart,
    )


# ----------------------------------------------------------------------------- fractal noise


@dataclass(frozen=True)
class _Noise:
    """Four fields of value noise (Earth: terrain, cloud, albedo, aux; Moon: maria, detail, -, -)
    from one periodic tile, in octaves of halving cell size (km).

    Octave k maps chart km to tile cells by its own rotation, scale 1 / cells_km[k] and offset.
    ``amplitude[k, c]`` is gain_c ** k normalised so that each field has unit variance."""

    tile: np.ndarray  # (TILE + 1, TILE + 1, 4) float32, unit variance, first row/column repeated
    cells_km: np.ndarray  # (n,)
    transform: np.ndarray  # (n, 2, 3)
    amplitude: np.ndarray  # (n, 4)
    channels: tuple[np.ndarray, ...]  # the tile's channels, contiguous, for one-channel remaps

    def maps(self, k: int, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tile coordinates of octave k, wrapped into [0, TILE] (the padded tile's range)."""
        out = []
        for a, b, c in self.transform[k]:
            m = cv2.addWeighted(u, float(a), v, float(b), float(c))
            turns = np.floor(np.multiply(m, 1.0 / TILE))
            out.append(cv2.scaleAdd(turns, -float(TILE), m, dst=m))
        return out[0], out[1]

    def sample(self, k: int, maps, channel: int | None = None) -> np.ndarray:
        """Octave k of one channel at unit amplitude, or of all four scaled by their amplitude."""
        if channel is None:
            tile = self.tile * self.amplitude[k].astype(np.float32)
        else:
            tile = self.channels[channel]
        return cv2.remap(tile, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _make_noise(
    rng: np.random.Generator, finest_km: float, spectra: tuple[tuple[float, float], ...]
) -> _Noise:
    """Tile (smoothed white noise, so octaves have no cell-scale creases) and octave layout.

    ``spectra`` holds, per channel, the amplitude ratio of successive octaves (the roughness)
    and the largest cell (km): octaves above it are left out of that channel."""
    white = rng.standard_normal((TILE, TILE, 4), dtype=np.float32)
    pad = ((4, 4), (4, 4), (0, 0))  # the blur's reach, wrapped so the tile stays periodic
    smooth = cv2.GaussianBlur(np.pad(white, pad, mode="wrap"), (9, 9), 1.0)[4:-4, 4:-4]
    mean, std = cv2.meanStdDev(smooth)
    smooth = (smooth - mean.ravel().astype(np.float32)) / std.ravel().astype(np.float32)
    tile = np.pad(smooth, ((0, 1), (0, 1), (0, 0)), mode="wrap")
    gains, largest = (np.array(column) for column in zip(*spectra, strict=True))
    n = max(math.floor(math.log2(largest.max() / finest_km)) + 1, 1)
    cells = largest.max() * 2.0 ** -np.arange(n)
    angle = rng.uniform(0, 2 * np.pi, n)
    offset = rng.uniform(0, TILE, (n, 2))
    c, s = np.cos(angle) / cells, np.sin(angle) / cells
    transform = np.stack(
        [np.stack([c, -s, offset[:, 0]], axis=1), np.stack([s, c, offset[:, 1]], axis=1)], axis=1
    )
    g = gains[None, :] ** np.arange(n)[:, None] * (cells[:, None] <= largest * 1.001)
    amplitude = g / np.sqrt(np.sum(g**2, axis=0) + 1e-30)
    channels = tuple(np.ascontiguousarray(tile[..., c]) for c in range(4))
    return _Noise(tile, cells, transform, amplitude, channels)


def _band_weight(
    log_cell: float, lfp: np.ndarray, lfp_range: tuple[float, float], start: float, stop: float
) -> np.ndarray | float:
    """Weight of an octave of cell 2**log_cell km on pixels of footprint 2**lfp km.

    With x = log2(cell / footprint), the cell's size in pixels, the weight ramps up over
    x = start -+ 0.5 and down over x = stop -+ 0.5 (stop = inf: never). Returns a scalar 0 or 1
    when that holds over all of ``lfp`` (its (min, max) given), sparing the per-pixel work."""
    x_low, x_high = log_cell - lfp_range[1], log_cell - lfp_range[0]
    if x_high <= start - 0.5 or x_low >= stop + 0.5:
        return 0.0
    if x_low >= start + 0.5 and x_high <= stop - 0.5:
        return 1.0
    x = log_cell - lfp
    w = np.clip(x - (start - 0.5), 0.0, 1.0)
    return w - np.clip(x - (stop - 0.5), 0.0, 1.0) if math.isfinite(stop) else w


def _value_range(a: np.ndarray) -> tuple[float, float]:
    return float(a.min()), float(a.max())


def _coarse_fbm(noise: _Noise, view: _SphereView, factor: int) -> np.ndarray:
    """(h, w, 4) fields from the octaves the coarse grid resolves, faded at its cell size."""
    out = np.zeros((*view.q.shape, 4), np.float32)
    lfp_range = _value_range(view.log_footprint)
    for k, cell in enumerate(noise.cells_km):
        start = math.log2(factor)
        w = _band_weight(math.log2(cell), view.log_footprint, lfp_range, start, math.inf)
        if np.isscalar(w) and w == 0:
            continue
        octave = noise.sample(k, noise.maps(k, *view.chart))
        out += octave if np.isscalar(w) else octave * w[..., None]
    return out


def _fine_octaves(noise: _Noise, view: _SphereView, factor: int) -> list[int]:
    """The octaves worth doing per pixel: the FULL_RES_OCTAVES most used over the body."""
    where = view.hit if view.hit.any() else np.ones_like(view.hit)
    lfp = view.log_footprint[where]
    lfp = lfp[:: max(len(lfp) // 4096, 1)]  # a sample is enough to rank them
    lfp_range, stop = _value_range(lfp), math.log2(factor)
    use = [
        float(np.sum(_band_weight(math.log2(c), lfp, lfp_range, 0.0, stop) * np.ones_like(lfp)))
        for c in noise.cells_km
    ]
    ranked = [k for k in np.argsort(use)[::-1][:FULL_RES_OCTAVES] if use[k] > 0]
    return sorted(int(k) for k in ranked)


def _finest_cell_km(view: _SphereView) -> float:
    where = view.hit if view.hit.any() else np.ones_like(view.hit)
    return 0.7 * 2.0 ** float(view.log_footprint[where].min())


# ----------------------------------------------------------------------------- the Earth


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
    cfg: EarthConfig, view: _SphereView, mu_sun: np.ndarray, ray_sun: np.ndarray
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
    cfg: EarthConfig, grid: _Grid, view: _SphereView, coarse: np.ndarray, sun: np.ndarray
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
    def of(cls, cfg: EarthConfig, noise: _Noise) -> _EarthLevels:
        land = float(ndtri(1.0 - cfg.land_fraction))
        cover = float(np.clip(cfg.cloud_cover, 1e-4, 1 - 1e-4))
        return cls(
            land=land,
            snow=land + cfg.snow_level,
            cloud=float(ndtri(1.0 - cover)) - cfg.cloud_softness / 2,
            coast_width=float(noise.amplitude[-1, 0]),
        )


def _fine_detail(
    noise: _Noise,
    octaves: list[int],
    up: dict[str, np.ndarray],
    factor: int,
    terms: tuple[tuple[int, int], ...],
) -> list[np.ndarray]:
    """Pixel-scale octaves, one sum per (noise channel, amplitude column) term.

    Two terms may share a noise channel with different gains (the Earth's terrain and land
    albedo), which costs one remap."""
    sums = [np.zeros_like(up["u"]) for _ in terms]
    lfp = up["log_footprint"]
    lfp_range, stop = _value_range(lfp), math.log2(factor)
    for k in octaves:
        w = _band_weight(math.log2(noise.cells_km[k]), lfp, lfp_range, 0.0, stop)
        if np.isscalar(w) and w == 0:
            continue
        maps = noise.maps(k, up["u"], up["v"])
        octave = {c: noise.sample(k, maps, c) for c in dict.fromkeys(c for c, _ in terms)}
        if not np.isscalar(w):
            octave = {c: sample * w for c, sample in octave.items()}
        for total, (channel, column) in zip(sums, terms, strict=True):
            cv2.scaleAdd(octave[channel], float(noise.amplitude[k, column]), total, dst=total)
    return sums


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
    noise: _Noise,
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
        detail = _fine_detail(noise, octaves, up, factor, ((0, 0), (0, 2), (1, 1)))
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


def _render_earth(
    cfg: EarthConfig,
    K: Intrinsics,
    sun: np.ndarray,
    rng: np.random.Generator,
    radiance: np.ndarray,
    transmission: np.ndarray,
) -> None:
    """Write the Earth (surface, clouds, air, limb glow) into ``radiance``, and its shadow on
    the light from beyond (stars, the Sun's disc) into ``transmission``."""
    grid = _Grid.of(K, FACTOR)
    centre = (EARTH_RADIUS_KM + cfg.altitude_km) * np.asarray(cfg.nadir)
    view = _sphere_view(grid, centre, EARTH_RADIUS_KM)
    noise = _make_noise(rng, _finest_cell_km(view), EARTH_SPECTRA)
    fields = _earth_fields(cfg, grid, view, _coarse_fbm(noise, view, FACTOR), sun)
    fields = {name: field.astype(np.float32) for name, field in fields.items()}
    octaves = _fine_octaves(noise, view, FACTOR)
    levels = _EarthLevels.of(cfg, noise)
    for r0, rows in grid.strips():
        up = {name: grid.upsample(field, r0, rows) for name, field in fields.items()}
        strip, seen = _earth_strip(cfg, levels, noise, octaves, up, FACTOR, rng)
        radiance[r0 : r0 + rows] = strip
        transmission[r0 : r0 + rows] *= seen


def _earth_transmission(cfg: EarthConfig, direction: np.ndarray) -> float:
    """Share of light from far beyond the Earth that reaches the camera along a direction."""
    centre = (EARTH_RADIUS_KM + cfg.altitude_km) * np.asarray(cfg.nadir)
    b = float(direction @ centre)
    if b <= 0:
        return 1.0
    altitude = math.sqrt(max(float(centre @ centre) - b * b, 0.0)) - EARTH_RADIUS_KM
    return 0.0 if altitude < 0 else float(np.exp(-_limb_depth(cfg, altitude)))


# ----------------------------------------------------------------------------- the Moon


def _moon_radiance(
    cfg: MoonConfig,
    grid: _Grid,
    view: _SphereView,
    noise: _Noise,
    octaves: list[int],
    sun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Radiance and hit mask of the Moon's disc in a crop: maria, Lommel-Seeliger light."""
    coarse = _coarse_fbm(noise, view, grid.factor)
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
        mare, detail = _fine_detail(noise, octaves, up, grid.factor, ((0, 0), (1, 1)))
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


def _render_moon(
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
    box = _cone_box(K, direction, radius)
    if box is None:
        return
    # Bilinear upsampling puts the limb within factor^2 / (8 r) pixels: coarse only for big discs.
    factor = FACTOR if radius * math.sqrt(K.fx * K.fy) >= 32 * FACTOR else 1
    grid = _Grid.of(_crop(K, box), factor)
    view = _sphere_view(grid, direction * MOON_RADIUS_KM / math.sin(radius), MOON_RADIUS_KM)
    noise = _make_noise(rng, _finest_cell_km(view), MOON_SPECTRA)
    moon, hit = _moon_radiance(cfg, grid, view, noise, _fine_octaves(noise, view, factor), sun)
    u0, u1, v0, v1 = box
    radiance[v0:v1, u0:u1] = np.where(hit, moon, radiance[v0:v1, u0:u1])
    transmission[v0:v1, u0:u1] *= ~hit


# ----------------------------------------------------------------------------- stars, Sun


def _add_stars(
    cfg: StarsConfig, rng: np.random.Generator, radiance: np.ndarray, transmission: np.ndarray
) -> None:
    """Single-pixel stars (a few 2 x 2), dimmed by the air and hidden by the Earth and Moon."""
    H, W = radiance.shape
    count = int(rng.poisson(cfg.density_per_mpx * H * W / 1e6))
    rows, cols = rng.integers(0, H, count), rng.integers(0, W, count)
    log_b = rng.uniform(np.log(cfg.brightness_min), np.log(cfg.brightness_max), count)
    block = rng.random(count) < cfg.fraction_2x2
    rows[block] = np.minimum(rows[block], max(H - 2, 0))
    cols[block] = np.minimum(cols[block], max(W - 2, 0))
    index = rows * W + cols
    corners = [index[block] + offset for offset in (1, W, W + 1)] if H > 1 and W > 1 else []
    index = np.concatenate([index, *corners])
    brightness = np.exp(np.concatenate([log_b, *[log_b[block]] * len(corners)]))
    np.add.at(
        radiance.ravel(), index, (brightness * transmission.ravel()[index]).astype(np.float32)
    )


def _sun_visibility(config: BackgroundConfig, sun: np.ndarray) -> float:
    """Share of the Sun's light reaching the camera past the Earth and the Moon."""
    seen = 1.0
    if config.earth is not None:
        seen *= _earth_transmission(config.earth, sun)
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
    grid = _Grid.of(K, FACTOR)
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
    box = _cone_box(K, sun, math.radians(layout.reach_deg))
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


def _add_sun(
    config: BackgroundConfig,
    K: Intrinsics,
    sun: np.ndarray,
    radiance: np.ndarray,
    transmission: np.ndarray,
) -> np.ndarray | None:
    """The Sun's disc (into ``radiance``, behind everything), and its halo, veiling glare and
    ghosts, when it is near enough to the frame: returned apart (None when there are none),
    since they are light scattered inside the lens and fall on the spacecraft too."""
    off_frame = _angle_to_frame_deg(K, sun)
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


# ----------------------------------------------------------------------------- entry point


@dataclass(frozen=True)
class Background:
    """What the camera sees besides the spacecraft, radiance (H, W) float32: ``scene`` lies
    behind it (sky, stars, Earth, Moon, the Sun's disc), ``stray`` is the Sun's light
    scattered in the lens (halo, glare, ghosts; None when the Sun is far) and falls on the
    spacecraft as well."""

    scene: np.ndarray
    stray: np.ndarray | None

    @property
    def radiance(self) -> np.ndarray:
        """Everything, as a frame without a spacecraft shows it."""
        return self.scene if self.stray is None else self.scene + self.stray


def render_background(
    config: BackgroundConfig, K: Intrinsics, sun: np.ndarray, rng: np.random.Generator
) -> Background:
    """The background for a camera and Sun (unit vector, camera frame).

    The generator supplies the textures and the star field: the same config, camera, Sun and
    generator state give the same image bit for bit."""
    sun = _unit(sun)
    radiance = np.zeros((K.height, K.width), np.float32)
    transmission = np.ones((K.height, K.width), np.float32)  # of light from beyond the bodies
    if config.earth is not None:
        _render_earth(config.earth, K, sun, rng, radiance, transmission)
    if config.moon is not None:
        _render_moon(config.moon, K, sun, rng, radiance, transmission)
    _add_stars(config.stars, rng, radiance, transmission)
    stray = _add_sun(config, K, sun, radiance, transmission)
    return Background(radiance, stray)
