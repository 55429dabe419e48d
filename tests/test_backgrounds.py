"""Backgrounds behind the spacecraft: stars, the Earth, the Moon, the Sun (linear radiance)."""

import dataclasses
import itertools
import json
import math
import time

import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA, Intrinsics
from sdcnet.training.data.background import (
    BACKGROUND_KINDS,
    EARTH_RADIUS_KM,
    BackgroundConfig,
    MoonConfig,
    StarsConfig,
    render_background,
    sample_background,
    sample_sun_near_view,
    sun_in_view,
)

BRIGHT_STARS = StarsConfig(
    density_per_mpx=20000.0, brightness_min=1.0, brightness_max=3.0, fraction_2x2=0.05
)
NO_STARS = StarsConfig(
    density_per_mpx=0.0, brightness_min=0.01, brightness_max=0.1, fraction_2x2=0.0
)


def rendered(config, K, sun, rng) -> np.ndarray:
    """All the background's light (scene and lens stray light), as one radiance image."""
    return render_background(config, K, sun, rng).radiance


def camera(width: int = 128, fov_deg: float = 30.0, height: int | None = None) -> Intrinsics:
    """Square-pixel pinhole camera with ``fov_deg`` across its width."""
    height = width if height is None else height
    f = width / 2 / math.tan(math.radians(fov_deg / 2))
    return Intrinsics(f, f, (width - 1) / 2, (height - 1) / 2, width, height)


def unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def pixel_rays(K: Intrinsics) -> np.ndarray:
    """(H, W, 3) unit ray directions at the pixel centres."""
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    rays = K.pixel_rays(u, v)
    return rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def earth_geometry(K: Intrinsics, config: BackgroundConfig) -> tuple[np.ndarray, np.ndarray]:
    """Independent ray-sphere test: hit mask and tangent altitude (km) per pixel."""
    earth = config.earth
    centre = (EARTH_RADIUS_KM + earth.altitude_km) * np.asarray(earth.nadir)
    rays = pixel_rays(K)
    b = rays @ centre
    q = centre @ centre - b**2
    hit = (b > 0) & (q < EARTH_RADIUS_KM**2)
    altitude = np.where(b > 0, np.sqrt(np.maximum(q, 0)) - EARTH_RADIUS_KM, np.inf)
    return hit, altitude


def sun_for(kind: str, rng: np.random.Generator, K: Intrinsics) -> np.ndarray:
    if kind == "sun":
        return sample_sun_near_view(rng, K, 3.0)
    return unit([0.3, -0.4, -0.85])  # behind the camera, as in the scene sampler


def limb_config(K: Intrinsics, seed: int = 0) -> BackgroundConfig:
    """Earth below, horizon through the principal point, stars bright and dense."""
    rng = np.random.default_rng(seed)
    config = sample_background(rng, K, unit([0, 0, -1]), "earth-limb")
    earth = config.earth
    rho = math.asin(EARTH_RADIUS_KM / (EARTH_RADIUS_KM + earth.altitude_km))
    nadir = (0.0, math.sin(rho), math.cos(rho))  # Earth centre straight down (+y) at the limb
    return dataclasses.replace(
        config, stars=BRIGHT_STARS, earth=dataclasses.replace(earth, nadir=nadir)
    )


@pytest.mark.parametrize("kind", ["earth-oblique", "moon", "sun"])
def test_same_seed_same_image_other_seed_other_image(kind):
    K = camera(96)

    def draw(seed):
        rng = np.random.default_rng(seed)
        sun = sun_for(kind, rng, K)
        return rendered(sample_background(rng, K, sun, kind), K, sun, rng)

    a, b, c = draw(7), draw(7), draw(8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("kind", BACKGROUND_KINDS)
def test_every_kind_is_finite_non_negative_float32(kind):
    K = camera(90, 40.0, height=70)  # odd sizes, not multiples of the coarse grid
    for seed in range(3):
        rng = np.random.default_rng(seed)
        sun = sun_for(kind, rng, K) if kind == "sun" else unit(rng.normal(size=3))
        config = sample_background(rng, K, sun, kind)
        image = rendered(config, K, sun, rng)
        assert image.dtype == np.float32 and image.shape == (70, 90)
        assert np.all(np.isfinite(image)) and image.min() >= 0
        assert config.kind == kind


@pytest.mark.parametrize("kind", BACKGROUND_KINDS)
def test_metadata_round_trips_through_json(kind):
    K = camera(64)
    rng = np.random.default_rng(3)
    meta = sample_background(rng, K, sun_for(kind, rng, K), kind).metadata()
    assert json.loads(json.dumps(meta)) == meta
    assert meta["kind"] == kind
    assert (meta["earth"] is not None) == kind.startswith("earth")
    assert (meta["moon"] is not None) == (kind == "moon")


def test_random_kinds_follow_the_sun():
    K = camera(64)
    behind = unit([0.2, 0.1, -1.0])
    rng = np.random.default_rng(0)
    kinds = [sample_background(rng, K, behind).kind for _ in range(300)]
    assert "sun" not in kinds  # the Sun is far from the frame
    assert kinds.count("stars") > kinds.count("moon") > 0
    in_view = unit([0.05, 0.0, 1.0])
    kinds = {sample_background(rng, K, in_view).kind for _ in range(100)}
    assert "sun" in kinds
    assert not kinds & {"earth-nadir", "earth-oblique"}  # those would eclipse it
    with pytest.raises(ValueError, match="sun"):
        sample_background(rng, K, behind, "sun")


@pytest.mark.parametrize("fov_deg", [PAPER_CAMERA.fov_deg, 60.0])
def test_earth_views_have_the_geometry_of_their_kind(fov_deg):
    K = camera(64, fov_deg)
    for seed in range(15):
        for kind in ("earth-nadir", "earth-oblique", "earth-limb"):
            rng = np.random.default_rng(seed)
            config = sample_background(rng, K, unit(rng.normal(size=3)), kind)
            altitude = config.earth.altitude_km
            assert 300 <= altitude <= 1200
            hit, _ = earth_geometry(K, config)
            axis_angle = math.degrees(math.acos(config.earth.nadir[2]))
            if kind == "earth-nadir":
                assert hit.all() and axis_angle <= 20.0 + 1e-9
            elif kind == "earth-oblique":
                assert hit.mean() > 0.5 and axis_angle >= 20.0
            else:
                assert 0.05 < hit.mean() < 0.95


def test_nadir_fills_the_frame_with_a_plausible_day_side():
    K = camera(128, 60.0)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        config = sample_background(rng, K, unit([0, 0, -1]), "earth-nadir")
        sun = -np.asarray(config.earth.nadir)  # the Sun overhead of the camera
        image = rendered(
            dataclasses.replace(config, stars=NO_STARS), K, sun, np.random.default_rng(seed)
        )
        assert image.min() > 0.01  # no black sky anywhere
        assert 0.03 < image.mean() < 0.9
        starry = dataclasses.replace(config, stars=BRIGHT_STARS)
        assert np.array_equal(rendered(starry, K, sun, np.random.default_rng(seed)), image)


def test_limb_has_space_earth_and_a_glow_band_above_the_horizon():
    K = camera(256, 10.0)  # ~2 km per pixel at the horizon
    for seed in range(3):
        config = limb_config(K, seed)
        rng = np.random.default_rng(seed)
        sun = -np.asarray(config.earth.nadir)  # day at the limb
        image = rendered(config, K, sun, rng)
        hit, altitude = earth_geometry(K, config)
        space = ~hit & (altitude > 150)
        assert hit.mean() > 0.3 and space.mean() > 0.2
        assert image[hit].mean() > 0.02
        assert np.median(image[space]) < 1e-4  # black sky between the stars
        assert (image[space] > 0.5).mean() > 0.005  # the stars are there
        band = image[~hit & (altitude < 15)]
        above = image[~hit & (altitude > 40) & (altitude < 80)]
        assert band.size > 100 and above.size > 100
        assert np.median(band) > 2 * np.median(above) > 0


def test_night_side_is_dark_except_city_lights():
    K = camera(128, 60.0)
    lit_pixels = 0
    for seed in range(4):
        rng = np.random.default_rng(seed)
        config = sample_background(rng, K, unit([0, 0, -1]), "earth-nadir")
        sun = np.asarray(config.earth.nadir)  # the Sun behind the Earth
        earth = dataclasses.replace(config.earth, land_fraction=0.95, cloud_cover=0.0)
        dark = dataclasses.replace(
            config, stars=BRIGHT_STARS, earth=dataclasses.replace(earth, city_probability=0.0)
        )
        assert rendered(dark, K, sun, np.random.default_rng(seed)).max() < 1e-3
        cities = dataclasses.replace(
            config, stars=BRIGHT_STARS, earth=dataclasses.replace(earth, city_probability=0.5)
        )
        image = rendered(cities, K, sun, np.random.default_rng(seed))
        assert np.median(image) < 1e-3
        lights = image > 0.01
        assert lights.mean() < 0.05
        lit_pixels += lights.sum()
    assert lit_pixels > 0


def test_moon_disc_lands_where_its_direction_projects_and_is_dark_away_from_the_sun():
    K = camera(160, 30.0)
    rng = np.random.default_rng(0)
    config = sample_background(rng, K, unit([0, 0, -1]), "moon")
    centre_u, centre_v, radius_deg = 50.0, 90.0, 3.0
    direction = unit(K.pixel_rays(centre_u, centre_v))
    moon = MoonConfig(tuple(direction), radius_deg, 0.13, 0.075, 0.3)
    config = dataclasses.replace(config, stars=BRIGHT_STARS, moon=moon)
    sun = np.array([1.0, 0.0, 0.0])  # from the right, 75 deg off the frame: no glare
    image = rendered(config, K, sun, rng)
    angle = np.degrees(np.arccos(np.clip(pixel_rays(K) @ direction, -1, 1)))
    radius_px = K.fx * math.tan(math.radians(radius_deg))
    u = np.arange(K.width)[None, :] - centre_u + np.zeros((K.height, 1))
    disc = angle < 0.85 * radius_deg
    assert (image[disc & (u > 0.3 * radius_px)] > 0.005).all()  # lit half
    assert (image[disc & (u < -0.3 * radius_px)] == 0).all()  # dark half, no stars on it
    assert (image[angle > 1.1 * radius_deg] > 0.5).mean() > 0.01  # stars around it
    lit_u = np.nonzero(image * (angle < radius_deg) > 0.005)[1]
    assert centre_u < lit_u.mean() < centre_u + radius_px


def test_stars_are_single_pixels_of_the_drawn_brightness():
    K = camera(256)
    rng = np.random.default_rng(1)
    config = sample_background(rng, K, unit([0, 0, -1]), "stars")
    stars = StarsConfig(300.0, 0.01, 4.0, 0.0)
    image = rendered(dataclasses.replace(config, stars=stars), K, unit([0, 0, -1]), rng)
    lit = image[image > 0]
    assert 5 < lit.size < 60  # Poisson around 20
    assert lit.min() >= 0.01 and lit.max() <= 8.0  # duplicates may add up


def test_sun_glare_grows_as_the_sun_nears_the_frame_and_the_disc_saturates():
    K = camera(128, 20.0)
    rng = np.random.default_rng(2)
    config = dataclasses.replace(sample_background(rng, K, unit([0, 0, -1]), "stars"))
    config = dataclasses.replace(config, stars=NO_STARS)
    means = []
    for outside_deg in (40.0, 20.0, 8.0, 2.0):
        azimuth = math.radians(10.0 + outside_deg)  # the frame's edge is at 10 deg
        sun = np.array([math.sin(azimuth), 0.0, math.cos(azimuth)])
        assert not sun_in_view(K, sun) and sun_in_view(K, sun, outside_deg + 0.5)
        means.append(rendered(config, K, sun, rng).mean())
    assert all(b > a for a, b in itertools.pairwise(means))
    assert means[-1] > 0.003
    sun = unit([0.0, 0.0, 1.0])
    assert sun_in_view(K, sun)
    image = rendered(config, K, sun, rng)
    assert image[63:65, 63:65].min() > 1e4  # the disc, radiance ~46 000
    assert image.mean() > means[-1]


def test_the_earth_hides_the_sun_behind_it():
    K = camera(128, 10.0)
    config = dataclasses.replace(limb_config(K), stars=NO_STARS)
    sun = unit(K.pixel_rays(64.0, 120.0))  # in the frame, below the horizon
    assert sun_in_view(K, sun)
    hidden = rendered(config, K, sun, np.random.default_rng(0))
    assert hidden.max() < 100
    open_sky = dataclasses.replace(config, earth=None)
    assert rendered(open_sky, K, sun, np.random.default_rng(0)).max() > 1e4


def test_render_speed_at_1024_px():
    K = PAPER_CAMERA.intrinsics()
    times = {}
    for kind in BACKGROUND_KINDS:
        rng = np.random.default_rng(5)
        sun = sun_for(kind, rng, K)
        config = sample_background(rng, K, sun, kind)
        start = time.perf_counter()
        rendered(config, K, sun, rng)
        times[kind] = time.perf_counter() - start
    print("render_background 1024 x 1024:", {k: f"{t * 1e3:.0f} ms" for k, t in times.items()})
    assert max(times.values()) < 3.0
