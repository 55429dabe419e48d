"""What a background is made of: its kinds, the sizes of the bodies, and the config of each
layer (stars, the Earth, the Moon, the lens's stray light) that ``sample_background`` draws."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

BACKGROUND_KINDS = ("stars", "earth-nadir", "earth-oblique", "earth-limb", "moon", "sun")
KIND_WEIGHTS = (0.35, 0.2, 0.15, 0.15, 0.07, 0.08)

EARTH_RADIUS_KM = 6371.0
MOON_RADIUS_KM = 1737.4
SUN_RADIUS_DEG = 0.267


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
