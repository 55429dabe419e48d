"""A shrunk crop's depth along the working grid's depth edges, drawn at the frame's pixels."""

import cv2
import numpy as np
import pytest

from sdcnet import pipeline
from sdcnet.anchoring import nearest_return
from sdcnet.edge_paste import (
    DISTANCE_WEIGHT,
    OFFSETS,
    RETURN_WEIGHT,
    edge_pixels,
    first_least,
    frame_pixels_under,
    paste_across_edges,
    two_sides,
)
from sdcnet.pipeline import complete, nearest_resampled, source_indices

PANEL_M, BOOM_M = 10.0, 6.0
FOCAL_PX = 250.0  # the working grid's: a pixel footprint of 4 cm at the panel


def boom_before_panel(scale: int = 4):
    """A frame of 240 x 240 pixels: a panel at 10 m, dark, and before it a bright vertical
    boom at 6 m whose sides (frame columns 101 and 130) fall inside working pixels of a grid
    ``scale`` times coarser; the grid's surface the frame's depth averaged over each of its
    pixels (the boom's sides in between the two depths), returns every 3 working pixels."""
    truth = np.full((240, 240), PANEL_M, np.float32)
    truth[:, 101:131] = BOOM_M
    gray = np.where(truth == BOOM_M, 200, 60).astype(np.uint8)
    shape = (240 // scale, 240 // scale)
    surface = cv2.resize(truth, shape[::-1], interpolation=cv2.INTER_AREA)
    guide = cv2.resize(gray.astype(np.float32) / 255, shape[::-1], interpolation=cv2.INTER_AREA)
    sparse = np.zeros(shape, np.float32)
    sparse[1::3, 1::3] = nearest_resampled(truth, shape)[1::3, 1::3]
    return truth, gray, surface, guide, sparse


def pasted(truth, gray, surface, guide, sparse, mask=None):
    """The frame's depth pasted by nearest neighbour, then along the edges."""
    mask = np.ones(surface.shape, bool) if mask is None else mask
    depth = nearest_resampled(np.where(mask, surface, 0), truth.shape)
    before = depth.copy()
    apart_px, nearest_m = nearest_return(sparse)
    rows = source_indices(0, truth.shape[0], truth.shape[0], surface.shape[0])
    cols = source_indices(0, truth.shape[1], truth.shape[1], surface.shape[1])
    paste_across_edges(
        depth, rows, cols, gray, 1 / 255, surface, mask, guide, nearest_m, apart_px,
        PANEL_M / FOCAL_PX,
    )  # fmt: skip
    return before, depth


def test_most_frame_pixels_along_a_step_take_their_own_sides_depth():
    """The nearest paste gives four columns of frame pixels along the boom's sides the
    working pixels' depth between the two surfaces; along the edges, the frame's gray and the
    returns put most of them on their own side. Not all: where the nearest return lies on
    the boom at the working pixel itself, it outweighs the gray of the panel's column there
    (``RETURN_WEIGHT``, chosen on rendered frames)."""
    truth, *scene = boom_before_panel()
    before, after = pasted(truth, *scene)
    wrong_before = np.abs(before - truth) > 0.1
    wrong_after = np.abs(after - truth) > 0.1
    assert wrong_before.sum() == 4 * 240 * 2, "two columns a side between the surfaces"
    assert wrong_after.sum() <= wrong_before.sum() / 4
    assert np.abs(after - truth).sum() < 0.5 * np.abs(before - truth).sum()
    assert np.array_equal(after[:, :96], truth[:, :96]), "away from the edges, as pasted"


def test_a_plane_however_steep_has_no_step():
    ramp = np.tile(np.arange(60, dtype=np.float32) * 2.0, (60, 1))  # 2 m per pixel
    rows, cols = edge_pixels(ramp, np.ones(ramp.shape, bool), 0.5)
    assert len(rows) == 0
    ramp[:, 30:] += 5.0  # a step of 5 m across it
    rows, cols = edge_pixels(ramp, np.ones(ramp.shape, bool), 0.5)
    assert set(cols.tolist()) == {29, 30} and len(rows) == 2 * 60


def test_the_mask_outline_is_no_step_and_pixels_off_the_mask_stay_off():
    truth, gray, surface, guide, sparse = boom_before_panel()
    mask = np.zeros(surface.shape, bool)
    mask[10:50, 10:50] = True
    surface = np.where(mask, surface, np.float32(0.0))  # the depth off the mask is none
    rows, cols = edge_pixels(surface, mask, 0.16)
    assert len(rows) and set(cols.tolist()) <= {24, 25, 26, 31, 32, 33}, "the boom's sides only"
    before, after = pasted(truth, gray, surface, guide, sparse, mask)
    assert np.array_equal(after > 0, before > 0)


def test_each_frame_pixel_lies_under_the_working_pixel_it_was_pasted_from():
    rows_of = source_indices(3, 77, 80, 23)  # a window of a crop of 80 shrunk to 23
    cols_of = source_indices(0, 50, 50, 17)
    at_rows, at_cols = np.array([0, 5, 22, 22]), np.array([0, 16, 3, 16])
    ys, xs, owner = frame_pixels_under(at_rows, at_cols, rows_of, cols_of)
    assert np.array_equal(rows_of[ys], at_rows[owner]) and np.array_equal(
        cols_of[xs], at_cols[owner]
    )
    every = {(y, x) for y in range(len(rows_of)) for x in range(len(cols_of))}
    under = {
        (y, x)
        for y, x in every
        if any(rows_of[y] == r and cols_of[x] == c for r, c in zip(at_rows, at_cols, strict=True))
    }
    assert set(zip(ys.tolist(), xs.tolist(), strict=True)) == under


def test_a_shrunk_crop_keeps_a_booms_sides_at_the_frames_pixels(monkeypatch):
    """Through ``complete``: a 2048 px frame whose crop the budget shrinks six times, a
    network whose depth blurs the boom's sides; pasted by nearest neighbour, a column of frame
    pixels along a side gets a depth between the boom's and the panel's, metres off; along
    the edges, every frame pixel gets one side's (within the network's own blur)."""
    size = 2048
    truth = np.full((size, size), PANEL_M, np.float32)
    truth[:, 1001:1061] = BOOM_M
    gray = np.where(truth == BOOM_M, 220, 70).astype(np.uint8)
    gray[:, :500] = gray[:, 1600:] = 0
    truth[:, :500] = truth[:, 1600:] = 0
    sparse = np.zeros((size, size), np.float32)
    sparse[::9, ::9] = truth[::9, ::9]

    def blurring_model(gray_w, sparse_w, focal_px):
        """The depth linear in the gray between the panel's and the boom's."""
        boom_share = np.clip((gray_w * 255 - 70) / (220 - 70), 0, 1)
        depth = PANEL_M + (BOOM_M - PANEL_M) * boom_share
        return depth.astype(np.float32), (gray_w > 0.1).astype(np.float32)

    def side_errors() -> np.ndarray:
        result = complete(blurring_model, gray, sparse, 2000.0, stride=64)
        assert result.grid.scale[0] < 0.2
        x = np.arange(size)[None, :]
        sides = result.mask & ((np.abs(x - 1001) < 6) | (np.abs(x - 1060) < 6))
        return np.abs(result.depth - truth)[sides]

    along_edges = side_errors()
    monkeypatch.setattr(pipeline, "paste_across_edges", lambda *args: None)
    nearest = side_errors()
    assert (nearest > 1.0).sum() >= size, "a column between the two surfaces"
    assert along_edges.max() < 0.5 and along_edges.mean() < 0.5 * nearest.mean()


def test_first_least_is_the_first_row_of_each_columns_least_value():
    rng = np.random.default_rng(3)
    values = rng.integers(0, 4, (9, 500)).astype(np.float32)  # many ties
    values[:, :20] = np.inf  # a column without a candidate takes the first row
    np.testing.assert_array_equal(first_least(values), np.argmin(values, axis=0))


def side_by_hand(r, c, surface, mask, return_depth, return_px, nearer_side):
    """One working pixel's candidates of one side, by the module docstring's rule, pixel by
    pixel: {flat index: cost}."""
    height, width = surface.shape
    around = [
        (min(max(r + dy, 0), height - 1), min(max(c + dx, 0), width - 1)) for dy, dx in OFFSETS
    ]
    depths = [surface[y, x] for y, x in around if mask[y, x]]
    near, far = min(depths), max(depths)
    costs = {}
    for (y, x), (dy, dx) in zip(around, OFFSETS, strict=True):
        if mask[y, x] and (surface[y, x] <= (near + far) / 2) == nearer_side:
            step = (far - near) * (1 + return_px[r, c])
            cost = RETURN_WEIGHT * abs(surface[y, x] - return_depth[r, c]) / step
            cost += DISTANCE_WEIGHT * np.hypot(dy, dx)
            # past the grid's side two offsets fall on one pixel: the nearer offset's cost
            costs[y * width + x] = min(cost, costs.get(y * width + x, np.inf))
    return costs


def test_two_sides_offers_each_sides_cheapest_candidate():
    rng = np.random.default_rng(4)
    surface = rng.choice([6.0, 10.0], (40, 50)).astype(np.float32)
    surface += rng.normal(0, 0.01, surface.shape).astype(np.float32)
    mask = rng.random(surface.shape) > 0.2
    guide = rng.random(surface.shape).astype(np.float32)  # tells the candidates apart
    return_depth = rng.choice([6.0, 10.0], surface.shape).astype(np.float32)
    return_px = rng.integers(0, 5, surface.shape).astype(np.float32)
    # the working pixels with a step among their neighbours on the mask, as edge_pixels finds
    spread = cv2.dilate(np.where(mask, surface, 0), None) - cv2.erode(
        np.where(mask, surface, 100), None
    )
    rows, cols = np.nonzero(mask & (spread > 1.0))
    depth, gray, cost = two_sides(rows, cols, surface, mask, guide, return_depth, return_px)
    assert depth.shape == gray.shape == cost.shape == (2, len(rows)) and len(rows) > 100
    for k, (r, c) in enumerate(zip(rows, cols, strict=True)):
        for side, nearer in ((0, True), (1, False)):
            costs = side_by_hand(r, c, surface, mask, return_depth, return_px, nearer)
            chosen = int(np.flatnonzero(guide.ravel() == gray[side, k])[0])
            assert surface.ravel()[chosen] == depth[side, k]
            assert costs[chosen] == pytest.approx(min(costs.values()), rel=1e-5)
            assert cost[side, k] == pytest.approx(costs[chosen], rel=1e-5)
