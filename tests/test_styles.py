"""Render styles: another renderer's way of drawing the same frame, and only the gray image."""

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA
from sdcnet.training.data.conditions import ROBUSTNESS, draw_conditions
from sdcnet.training.data.generate import (
    GenerateConfig,
    build_spacecraft,
    frame_conditions,
    make_sample,
)
from sdcnet.training.data.render import PosedModel, render_radiance
from sdcnet.training.data.scene import SceneConfig, sample_scene
from sdcnet.training.data.styles import (
    OURS,
    RenderStyle,
    ggx_specular,
    sample_style,
    stained,
    subpixel_offsets,
)


@pytest.fixture(scope="module")
def posed():
    model = build_spacecraft(GenerateConfig(models=1, views=1, seed=2), 0)
    scene = sample_scene(
        np.random.default_rng(3), SceneConfig(min_distance_m=60, max_distance_m=60)
    )
    return PosedModel.place(model, scene)


K = PAPER_CAMERA.intrinsics().scaled(256, 256)


def test_the_other_renderer_draws_the_paper_frames_but_for_the_gray_image():
    """The same spacecraft, pose, sensor, LIDAR returns and depth truth: a paired comparison."""
    config = GenerateConfig(models=3, views=1, size=256, seed=5)
    model = build_spacecraft(config, 1)
    ours = make_sample(config, model, 1, 0, "test")
    other = make_sample(replace(config, world="other-renderer"), model, 1, 0, "test")
    np.testing.assert_array_equal(ours.sparse, other.sparse)
    np.testing.assert_array_equal(ours.depth, other.depth)
    assert ours.meta["sensor"] == other.meta["sensor"]
    assert ours.meta["render_style"] == OURS.metadata()
    assert other.meta["render_style"]["brdf"] == "ggx" and other.meta["render_style"]["samples"] > 1
    assert not np.array_equal(ours.gray, other.gray)


def test_every_pbr_draw_is_within_its_ranges_and_ours_draws_nothing_new():
    for seed in range(20):
        style = sample_style(np.random.default_rng(seed), "pbr")
        assert style.kind == "pbr" and 2 <= style.samples <= 4 and style.brdf == "ggx"
        assert 0.02 <= style.fill <= 0.3 and 0 <= style.stain <= 0.4
        assert math.isclose(np.linalg.norm(style.fill_direction), 1.0, rel_tol=1e-9)
    assert sample_style(np.random.default_rng(0), "ours") is OURS
    assert (
        draw_conditions(ROBUSTNESS["other-renderer"], np.random.default_rng(1)).style.brdf == "ggx"
    )
    with pytest.raises(ValueError, match="unknown render style"):
        sample_style(np.random.default_rng(0), "cycles")


def test_subpixel_rays_cover_the_pixel_evenly():
    np.testing.assert_array_equal(subpixel_offsets(1), [[0.0, 0.0]])
    offsets = subpixel_offsets(4)
    assert offsets.shape == (16, 2) and np.allclose(offsets.mean(axis=0), 0.0)
    assert offsets.min() == -0.375 and offsets.max() == 0.375


def test_anti_aliasing_blends_the_outline_with_the_background(posed):
    ours = render_radiance(posed, K, np.random.default_rng(0))
    aa = render_radiance(posed, K, np.random.default_rng(0), RenderStyle(samples=3))
    np.testing.assert_array_equal(ours.depth, aa.depth)  # the truth is the pixel centre's
    assert set(np.unique(ours.coverage)) <= {0.0, 1.0}
    np.testing.assert_array_equal(ours.coverage > 0, ours.depth > 0)
    mask = (ours.depth > 0).astype(np.uint8)
    inside = cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)
    partial = (aa.coverage > 0) & (aa.coverage < 1)
    assert partial.sum() > 50, "the outline's pixels are partly covered"
    assert np.mean(aa.coverage[inside] == 1.0) > 0.99, "inside the outline every ray hits"
    # the rays' coverage measures the same area as the pixel centres, within 5 %
    assert abs(aa.coverage.sum() / mask.sum() - 1.0) < 0.05


def test_ggx_reflects_as_the_formula_at_normal_incidence_and_brightens_at_grazing():
    n = np.array([[0.0, 0.0, 1.0]])
    f0, shininess = np.array([0.04]), np.array([98.0])  # alpha^2 = 0.02
    value = ggx_specular(n, np.array([0.0, 0.0, 1.0]), n.copy(), f0, shininess)
    # D = 1 / (pi alpha^2), G = 1, F = f0 at normal incidence: pi D G F / 4
    assert value[0] == pytest.approx(0.04 / 0.02 / 4, rel=1e-6)
    grazing = np.array([math.sin(1.45), 0.0, math.cos(1.45)])  # 83 deg, mirror geometry
    mirror = np.array([[-grazing[0], 0.0, grazing[2]]])
    assert ggx_specular(n, grazing, mirror, f0, shininess)[0] > 3 * value[0], "Fresnel"


def test_stains_vary_the_albedo_within_their_amplitude():
    points = np.random.default_rng(0).uniform(-3, 3, (5000, 3))
    albedo = np.full(5000, 0.5)
    assert stained(albedo, points, OURS) is albedo
    style = RenderStyle(stain=0.3, stain_scale_m=0.5, stain_seed=7)
    varied = stained(albedo, points, style)
    assert varied.min() >= 0.5 * 0.7 - 1e-12 and varied.max() <= 0.5 * 1.3 + 1e-12
    assert varied.std() > 0.05
    np.testing.assert_array_equal(varied, stained(albedo, points, style))  # seeded


def test_the_fill_light_shows_the_parts_the_sun_leaves_in_shadow(posed):
    dark = render_radiance(posed, K, np.random.default_rng(0))
    filled = render_radiance(
        posed, K, np.random.default_rng(0), RenderStyle(fill=0.3, fill_direction=(0.0, 0.0, -1.0))
    )
    on = dark.depth > 0
    # the fill light comes from the camera's side: every pixel facing it is brighter or equal
    assert (filled.radiance[on] >= dark.radiance[on] - 1e-12).all()
    assert (filled.radiance[on] - dark.radiance[on]).mean() > 0.02


def test_a_dataset_drawn_with_other_styles_records_them_and_keeps_its_frames():
    config = GenerateConfig(models=3, views=2, size=128, seed=6, world="mixed")
    styled = replace(config, styles=("ours", "pbr"))
    assert styled.command().endswith("--world mixed --styles ours pbr")
    drawn = [frame_conditions(styled, 0, v).style.brdf for v in range(20)]
    assert {frame_conditions(config, 0, v).style for v in range(20)} == {OURS}
    assert 3 <= drawn.count("ggx") <= 17
    view = drawn.index("ggx")
    model = build_spacecraft(config, 0)
    plain, other = (make_sample(c, model, 0, view, "t") for c in (config, styled))
    np.testing.assert_array_equal(plain.sparse, other.sparse)
    assert plain.meta["render_style"] == OURS.metadata()
    assert other.meta["render_style"]["brdf"] == "ggx"
