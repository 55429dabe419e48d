"""Worlds: every factor a frame is drawn with renders what it claims and is recorded."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA, Intrinsics
from sdcnet.training.data.background import sun_in_view
from sdcnet.training.data.conditions import ANY, ROBUSTNESS, CameraDraw, World, draw_conditions
from sdcnet.training.data.generate import (
    GenerateConfig,
    build_spacecraft,
    frame_conditions,
    generate,
    make_sample,
    render_scene,
)
from sdcnet.training.data.render import PosedModel, render_camera
from sdcnet.training.data.scene import SceneConfig, sample_scene
from sdcnet.training.data.sensor import Sensor, expose


def hfov_deg(K: Intrinsics) -> float:
    return math.degrees(2 * math.atan(K.width / 2 / K.fx))


@pytest.mark.parametrize("name", sorted(ROBUSTNESS))
def test_each_condition_draws_the_camera_lidar_and_sky_it_names(name):
    world = ROBUSTNESS[name]
    for seed in range(6):
        c = draw_conditions(world, np.random.default_rng(seed))
        if world.camera == "paper":
            assert c.intrinsics == PAPER_CAMERA.intrinsics()
        else:
            lo, hi = world.camera.hfov_deg
            assert lo - 0.01 <= hfov_deg(c.intrinsics) <= hi + 0.01
            assert c.intrinsics.width in world.camera.widths
        kinds = {"paper": "scanning", "grid": "scanning"}
        if world.lidar:
            assert c.lidar.metadata()["kind"] in {kinds.get(k, k) for k in world.lidar}
        if world.backgrounds:
            assert c.background in world.backgrounds


def test_any_world_spans_cameras_sizes_sensors_and_lidars():
    draws = [draw_conditions(ANY, np.random.default_rng(seed)) for seed in range(60)]
    fovs = [hfov_deg(c.intrinsics) for c in draws]
    assert 5 <= min(fovs) < 10 and 40 < max(fovs) <= 60
    assert {c.sensor.bits for c in draws} == {8, 12, 16}
    assert any(c.intrinsics.width != c.intrinsics.height for c in draws)
    assert len({c.lidar.metadata()["kind"] for c in draws}) >= 3
    assert any(c.sensor.jpeg_quality for c in draws) and any(c.sensor.defocus_px for c in draws)


def test_a_sample_records_every_factor_and_never_puts_the_camera_inside_the_spacecraft():
    config = GenerateConfig(models=3, views=2, size=256, seed=4, world="any")
    model = build_spacecraft(config, 1)
    for view in range(2):
        sample = make_sample(config, model, 1, view, "train")
        meta = json.loads(json.dumps(sample.meta))  # JSON all the way
        assert meta["world"] == "any"
        assert {"kind", "max_range_m", "offset_m"} <= set(meta["lidar"])
        assert {"bits", "exposure", "jpeg_quality"} <= set(meta["sensor"])
        assert "kind" in meta["background"]
        assert meta["distance_m"] >= model.radius_m + 1.0
        K = Intrinsics(**meta["intrinsics"])
        assert sample.gray.shape == sample.depth.shape == (K.height, K.width)
        assert sample.gray.dtype == (np.uint8 if meta["sensor"]["bits"] == 8 else np.uint16)


@pytest.mark.parametrize("kind", ["paper", "grid", "multibeam", "flash", "rosette"])
def test_returns_lie_on_the_spacecraft_within_the_lidar_noise(kind):
    """Every LIDAR kind, parallax and losses drawn: a return's depth is the surface's at its
    pixel (the camera's ground truth), within the noise bound, but for a few on depth edges
    where the LIDAR sees around a corner the camera does not."""
    small = World("small", CameraDraw(widths=(320,)), "any", (kind,), ("stars",), ANY.scene)
    config = GenerateConfig(models=2, seed=7)
    on, total = 0, 0
    for m in range(2):
        model = build_spacecraft(config, m)
        for view in range(3):
            conditions = draw_conditions(small, np.random.default_rng([m, view]))
            scene = sample_scene(
                np.random.default_rng([m, view, 1]),
                replace(conditions.scene, max_distance_m=60.0),
                conditions.intrinsics,
                model.radius_m,
            )
            sample = render_scene(model, scene, conditions, (7, m, view))
            lidar = sample.meta["lidar"]
            rows, cols = np.nonzero(sample.sparse)
            truth = sample.depth[rows, cols]
            z = sample.sparse[rows, cols]
            bound = 3 * (lidar["range_noise_m"] + lidar["range_noise_per_100m"] * z / 100) + 0.02
            on += int(np.sum((truth > 0) & (np.abs(z - truth) <= bound)))
            total += len(z)
    assert total > 20 and on >= 0.9 * total


def test_the_background_never_shows_inside_the_spacecraft():
    """The same spacecraft in front of black sky and in front of a bright Earth: the same
    pixels wherever the blur cannot carry the background in."""
    config = GenerateConfig(models=1, views=1, size=256, seed=2)
    model = build_spacecraft(config, 0)
    K = PAPER_CAMERA.intrinsics().scaled(256, 256)
    scene = sample_scene(
        np.random.default_rng(3), SceneConfig(min_distance_m=60, max_distance_m=60)
    )
    posed = PosedModel.place(model, scene)
    sensor = Sensor(0.8, 0.0, 0.0, 1.0, 1e9, 0.0, 8, True, 2.2, 0)  # noiseless
    black = render_camera(posed, K, np.random.default_rng(0), np.zeros((256, 256)), sensor)
    earth = render_camera(posed, K, np.random.default_rng(0), np.full((256, 256), 0.6), sensor)
    mask = black.depth > 0
    import cv2

    inside = cv2.erode(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert inside.sum() > 200
    difference = np.abs(black.gray[inside].astype(int) - earth.gray[inside])
    assert difference.max() <= 1, "a rounding step at most: the Earth adds ~150 where it shows"
    assert (earth.gray[~mask].mean() - black.gray[~mask].mean()) > 100


@pytest.mark.parametrize(
    ("bits", "msb", "top"),
    [(8, True, 255), (12, False, 4095), (12, True, 65520), (16, True, 65535)],
)
def test_the_sensor_writes_the_digital_numbers_of_its_bit_depth(bits, msb, top):
    radiance = np.zeros((64, 64))
    radiance[:, 32:] = 2.0  # twice a lit white surface
    sensor = Sensor(0.3, 0.0, 0.0, 1.0, 1e9, 0.0, bits, msb, 1.0, 0)
    image = expose(radiance, sensor, np.random.default_rng(0))
    assert image.dtype == (np.uint8 if bits == 8 else np.uint16)
    assert (image[:, 40:] == top).all(), "over full scale: clipped to the top number"
    assert (image[:, :24] == 0).all()
    if bits == 12 and msb:
        assert (image % 16 == 0).all()


def test_exposure_darkens_and_brightens_and_jpeg_compresses():
    radiance = np.full((64, 64), 0.5)
    radiance[20:40, 20:40] = 0.05

    def mean(exposure, jpeg=0):
        sensor = Sensor(0.5, 0.0, 0.0, exposure, 1e9, 0.0, 8, True, 1.0, jpeg)
        return expose(radiance, sensor, np.random.default_rng(0))

    assert mean(0.2).mean() < mean(1.0).mean() < mean(4.0).mean()
    assert mean(4.0).max() == 255
    compressed = mean(1.0, jpeg=40)
    assert compressed.dtype == np.uint8 and not np.array_equal(compressed, mean(1.0))


def test_the_paper_world_is_tables_1_and_2():
    c = frame_conditions(GenerateConfig(), 3, 5)
    assert c.world == "paper" and c.intrinsics == PAPER_CAMERA.intrinsics()
    assert c.lidar.metadata()["horizontal_step_deg"] == pytest.approx(0.09)
    assert c.sensor.bits == 8 and c.background == "stars"
    assert (c.scene.min_distance_m, c.scene.max_distance_m) == (50.0, 250.0)


def test_only_splits_renders_the_unseen_models_alone(tmp_path):
    config = GenerateConfig(models=6, views=1, size=128, seed=0, only_splits=("test",))
    store = generate(config, tmp_path, progress=False)
    assert store is not None and len(store) == 1
    assert {r["split"] for r in store.records} == {"test"}


def test_a_sun_frame_puts_the_sun_in_or_near_the_view_and_its_glare_on_the_image():
    config = GenerateConfig(models=3, views=8, seed=1, world="sun-moon")
    model = build_spacecraft(config, 0)
    suns = 0
    for view in range(8):
        meta = frame_conditions(config, 0, view)
        if meta.background != "sun":
            continue
        sample = make_sample(config, model, 0, view, "test")
        K = Intrinsics(**sample.meta["intrinsics"])
        assert sun_in_view(K, np.array(sample.meta["sun_direction"]), margin_deg=10.5)
        assert sample.meta["sun_angle_deg"] > 150, "behind the target as the camera sees it"
        suns += 1
    assert suns >= 2
