"""The normals of a completed frame (sdcnet.normals): right on planes seen through any working
grid (within 0.2 degrees: a tilted plane's depth is not linear in the pixel, and the
differences are one-sided), not tilted by a depth edge next to them, one per point in the
order asked."""

from __future__ import annotations

import numpy as np
import pytest

from sdcnet.camera import Intrinsics
from sdcnet.metrics import surface_normals
from sdcnet.normals import (
    NORMAL_STEP_PX,
    cloud_normals,
    normal_directions,
    normal_map,
    normals_at,
)
from sdcnet.pipeline import Completion, Region, WorkingGrid

K = Intrinsics(fx=800.0, fy=760.0, cx=150.0, cy=110.0, width=320, height=240)


def plane_depth(normal: np.ndarray, offset_m: float, rows: np.ndarray, cols: np.ndarray):
    """Z (metres) where the rays of pixels (rows, cols) meet the plane normal . P = offset."""
    ray = np.stack(np.broadcast_arrays((cols - K.cx) / K.fx, (rows - K.cy) / K.fy, np.ones(1)), -1)
    return (offset_m / (ray @ normal)).astype(np.float32)


def unit(*v: float) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def working_plane(normal: np.ndarray, offset_m: float, grid: WorkingGrid) -> np.ndarray:
    """The plane's depth on ``grid``: each working pixel at its centre's frame position."""
    (sr, sc), region = grid.scale, grid.region
    v = region.y0 + (np.arange(grid.shape[0]) + 0.5) / sr - 0.5
    u = region.x0 + (np.arange(grid.shape[1]) + 0.5) / sc - 0.5
    return plane_depth(normal, offset_m, v[:, None], u[None, :])


def completion_of(
    depth_w: np.ndarray,
    mask_w: np.ndarray,
    grid: WorkingGrid,
    gray_w: np.ndarray | None = None,
    sigma_w: np.ndarray | None = None,
) -> Completion:
    """A completion whose frame mask is the whole region (what normals_at reads of it), seen
    in ``gray_w`` (uniformly lit without it), its depth as uncertain as ``sigma_w`` says."""
    mask = np.zeros((K.height, K.width), bool)
    mask[grid.region.slices] = True
    empty = np.zeros(mask.shape, np.float32)
    gray_w = np.full(grid.shape, 0.5, np.float32) if gray_w is None else gray_w
    return Completion(empty, mask, empty, grid, depth_w, mask_w, gray_w, working_sigma=sigma_w)


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1.0, 1.0)))


@pytest.mark.parametrize("working_shape", [(100, 160), (200, 320), (400, 640)])
def test_a_tilted_plane_has_its_normal_through_any_working_grid(working_shape):
    region = Region(20, 220, 0, 320)
    grid = WorkingGrid(region, working_shape)
    normal = unit(0.4, -0.3, -1.0)  # facing the camera (-z), tilted on both axes
    depth_w = working_plane(normal, -60.0, grid)
    completion = completion_of(depth_w, np.ones(working_shape, bool), grid)
    rows, cols = np.nonzero(completion.mask)
    got = normals_at(completion, rows, cols, K)
    assert got.shape == (len(rows), 3) and got.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-5)
    assert angles_deg(got, normal).max() < 0.2


def test_a_depth_edge_does_not_tilt_the_normals_beside_it():
    """A panel 3 m in front of a bus, each lit as its own facet: the pixels on either side of
    the edge keep their surface's normal, where the depth map's central differences tilt them
    by tens of degrees."""
    grid = WorkingGrid(Region(0, K.height, 0, K.width), (K.height, K.width))
    front, back = unit(0.2, 0.0, -1.0), unit(-0.3, 0.1, -1.0)
    depth_w = working_plane(back, -40.0, grid)
    panel = np.zeros(grid.shape, bool)
    panel[:, :160] = True
    depth_w[panel] = working_plane(front, -37.0, grid)[panel]
    mask_w = np.ones(grid.shape, bool)
    gray_w = np.where(panel, 0.8, 0.3).astype(np.float32)
    normals = normal_map(completion_of(depth_w, mask_w, grid, gray_w), K)
    beside = slice(160 - NORMAL_STEP_PX, 160 + NORMAL_STEP_PX)
    inner = slice(10, -10)
    truth = np.where(panel[:, :, None], front, back)
    assert angles_deg(normals[inner, beside], truth[inner, beside]).max() < 2.0
    central = surface_normals(depth_w, K)
    assert angles_deg(central[inner, 159:161], truth[inner, 159:161]).min() > 30


def test_the_mask_side_is_taken_at_the_outline():
    """Beside the mask's outline the depth off the mask (whatever the network left there) is
    not used: the normal is the surface's own."""
    grid = WorkingGrid(Region(0, K.height, 0, K.width), (K.height, K.width))
    normal = unit(0.0, 0.5, -1.0)
    depth_w = working_plane(normal, -30.0, grid)
    mask_w = np.zeros(grid.shape, bool)
    mask_w[50:150, 60:200] = True
    depth_w[~mask_w] = 5.0  # a cliff off the mask, closer than the surface
    x, y, z = normal_directions(depth_w, mask_w, grid, K)
    got = np.stack([x, y, z], -1)[mask_w]
    got /= np.linalg.norm(got, axis=-1, keepdims=True)
    assert angles_deg(got, normal).max() < 0.2


def test_normals_follow_the_order_of_the_pixels_asked():
    grid = WorkingGrid(Region(0, K.height, 0, K.width), (K.height, K.width))
    depth_w = working_plane(unit(0.0, 0.0, -1.0), -20.0, grid)
    depth_w[:, 200:] = working_plane(unit(0.6, 0.0, -1.0), -25.0, grid)[:, 200:]
    completion = completion_of(depth_w, np.ones(grid.shape, bool), grid)
    rows, cols = np.array([5, 5, 100]), np.array([300, 10, 250])
    got = normals_at(completion, rows, cols, K)
    assert angles_deg(got[1], unit(0.0, 0.0, -1.0)) < 0.2
    assert angles_deg(got[0], unit(0.6, 0.0, -1.0)) < 0.2
    assert angles_deg(got[2], unit(0.6, 0.0, -1.0)) < 0.2


def test_the_cloud_normals_are_those_of_its_pixels_in_row_major_order_band_by_band():
    grid = WorkingGrid(Region(10, 200, 20, 300), (95, 140))  # a crop shrunk to half
    depth_w = working_plane(unit(0.2, -0.4, -1.0), -45.0, grid)
    depth_w[:, 70:] = working_plane(unit(-0.5, 0.1, -1.0), -48.0, grid)[:, 70:]
    completion = completion_of(depth_w, np.ones(grid.shape, bool), grid)
    pixels = np.zeros(completion.mask.shape, bool)
    pixels[30:180:3, 40:290:2] = True  # as outlier removal and max_sigma leave a cloud
    rows, cols = np.nonzero(pixels)
    whole = normals_at(completion, rows, cols, K)
    banded = cloud_normals(completion, pixels, K, band_pixels=500)  # a band of 1-2 rows
    np.testing.assert_array_equal(banded, whole)
    assert banded.shape == (pixels.sum(), 3)


def test_the_image_guides_the_normals_smoothed_within_a_facet_and_at_a_fold():
    """A roof of two facets lit differently, its depth rippled by a centimetre as a completion
    leaves it: within each facet the guided normals are nearer the facet's own than the depth's
    differences alone, and at the fold, where those tilt by tens of degrees, the guide keeps
    each side's normal within 12 degrees."""
    grid = WorkingGrid(Region(0, K.height, 0, K.width), (K.height, K.width))
    left, right = unit(0.35, 0.0, -1.0), unit(-0.35, 0.0, -1.0)
    depth_left, depth_right = working_plane(left, -50.0, grid), working_plane(right, -50.0, grid)
    facet = depth_left < depth_right  # the left facet, nearer on its side of the fold
    fold = int(np.argmax(~facet[120]))  # the first column of the right facet
    rows, cols = np.mgrid[: grid.shape[0], : grid.shape[1]]
    ripple = 0.01 * np.sin(cols / 2.0) * np.cos(rows / 3.0)
    depth_w = (np.where(facet, depth_left, depth_right) + ripple).astype(np.float32)
    gray_w = np.where(facet, 0.7, 0.35).astype(np.float32)
    completion = completion_of(depth_w, np.ones(grid.shape, bool), grid, gray_w)
    truth = np.where(facet[..., None], left, right)
    guided = angles_deg(normal_map(completion, K), truth)
    directions = np.stack(normal_directions(depth_w, completion.working_mask, grid, K), -1)
    raw = angles_deg(directions / np.linalg.norm(directions, axis=-1, keepdims=True), truth)
    within = np.zeros(grid.shape, bool)
    within[20:-20, 20:-20] = True
    within[:, fold - 10 : fold + 10] = False
    assert guided[within].mean() < 0.7 * raw[within].mean()
    at_fold = np.s_[20:-20, fold - 2 : fold + 2]
    assert raw[at_fold].max() > 25 and guided[at_fold].max() < 12


def test_the_fits_weigh_each_pixel_by_the_inverse_of_its_depths_variance():
    """A plane whose depth ripples by 5 cm in a band of columns, where sigma says it is ten
    times less sure: weighed by sigma, the band's normals come from the sure pixels around it
    and are nearer the plane's than unweighed; a sigma alike everywhere changes nothing."""
    grid = WorkingGrid(Region(0, K.height, 0, K.width), (K.height, K.width))
    normal = unit(0.3, 0.2, -1.0)
    rows, cols = np.mgrid[: grid.shape[0], : grid.shape[1]]
    band = (cols >= 140) & (cols < 160)
    ripple = np.where(band, 0.05 * np.sin(cols * 1.3) * np.cos(rows / 2.0), 0.0)
    depth_w = (working_plane(normal, -40.0, grid) + ripple).astype(np.float32)
    mask_w = np.ones(grid.shape, bool)
    sigma_w = np.where(band, 0.1, 0.01).astype(np.float32)
    unweighed = angles_deg(normal_map(completion_of(depth_w, mask_w, grid), K), normal)
    weighed = normal_map(completion_of(depth_w, mask_w, grid, sigma_w=sigma_w), K)
    inner = np.s_[20:-20, 140:160]
    assert unweighed[inner].mean() > 6
    assert angles_deg(weighed, normal)[inner].mean() < 0.5 * unweighed[inner].mean()
    alike = np.full(grid.shape, 0.37, np.float32)
    np.testing.assert_allclose(
        normal_map(completion_of(depth_w, mask_w, grid, sigma_w=alike), K),
        normal_map(completion_of(depth_w, mask_w, grid), K),
        atol=1e-5,
    )
