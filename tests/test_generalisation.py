"""The shipped model on frames of cameras it must not care about."""

import math

import cv2
import numpy as np
import pytest

from sdcnet.camera import Intrinsics
from sdcnet.pipeline import complete
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.service.settings import shipped_model_path
from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, model_splits
from sdcnet.training.data.lidar import ScanningLidar, scan_lidar
from sdcnet.training.data.render import PosedModel, render_camera
from sdcnet.training.data.scene import Scene, random_rotation
from sdcnet.training.data.sensor import Sensor


def camera(hfov_deg: float, size: int) -> Intrinsics:
    fx = (size / 2) / math.tan(math.radians(hfov_deg) / 2)
    return Intrinsics(fx, fx, (size - 1) / 2, (size - 1) / 2, size, size)


@pytest.fixture(scope="module")
def model() -> OnnxModel:
    return OnnxModel(shipped_model_path(), provider="cpu", threads=2)


@pytest.mark.parametrize("seed", [0, 1])
def test_two_cameras_seeing_the_same_scene_give_the_same_mask_within_a_pixel_of_its_outline(
    model, seed
):
    """One scene, one LIDAR, two cameras of the same field of view at 512 and 1024 px: the
    1024 px mask, brought to 512 px, is the 512 px mask but within a pixel of the outline."""
    config = GenerateConfig(seed=0)
    test_model = min(m for m, split in model_splits(config).items() if split == "test")
    spacecraft = build_spacecraft(config, test_model)
    rng = np.random.default_rng(seed)
    distance = 1.5 * spacecraft.radius_m / math.tan(math.radians(20.0) / 2)
    sun = np.array([0.3, -0.4, -1.0]) / np.linalg.norm([0.3, -0.4, -1.0])
    scene = Scene(random_rotation(rng), np.array([0.0, 0.0, distance]), sun, 25.0)
    posed = PosedModel.place(spacecraft, scene)
    lidar = ScanningLidar(horizontal_step_deg=0.25, vertical_step_deg=0.35, dropout=0.0)
    sensor = Sensor(0.7, 0.0, 0.0, 1.0, 1e6, 0.002, 8, True, 2.2, 0)
    masks, truth = {}, None
    for size in (512, 1024):
        K = camera(20.0, size)
        frame = render_camera(posed, K, np.random.default_rng(seed), np.zeros((size, size)), sensor)
        sparse = scan_lidar(posed, lidar, K, np.random.default_rng(seed))
        result = complete(model.run, frame.gray, sparse, K.fx, model.stride, model.info.work_pixels)
        masks[size] = result.mask
        truth = frame.depth > 0 if size == 512 else truth
    coarse = cv2.resize(masks[1024].astype(np.float32), (512, 512), interpolation=cv2.INTER_AREA)
    differ = masks[512] != (coarse > 0.5)
    outline = cv2.morphologyEx(
        truth.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)
    )
    near_outline = cv2.dilate(outline, np.ones((3, 3), np.uint8)).astype(bool)
    assert truth.sum() > 5000, "a spacecraft a few hundred pixels across"
    assert (differ & ~near_outline).sum() <= 0.005 * truth.sum()
