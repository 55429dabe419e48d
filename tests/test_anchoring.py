"""The depth anchored to the LIDAR returns: measured errors corrected, noise not copied."""

import math

import numpy as np
import pytest

from sdcnet.anchoring import (
    MAX_NOISE_M,
    MAX_NOISE_OF_DEPTH,
    MIN_ERROR_RATIO,
    MIN_RETURNS_FOR_RATIO,
    NETWORK_RATIO,
    SIGMA_AT_RETURN,
    SIGMA_BOUNDS_PX,
    SIGMA_PER_APART_M,
    SIGMA_PER_DISAGREEMENT,
    SIGMA_PER_MISFIT,
    SIGMA_PER_NOISE,
    SIGMA_SCALE,
    anchor_to_returns,
    anchored_sigma,
    error_ratio,
    nearest_return,
    recombined_sigma,
    shaped_by_grid,
    spreading_sigma_px,
)

SIZE = 96
#: The grid's focal length, pixels: a pixel 50 m away is 5 cm across.
FOCAL_PX = 1000.0


def tilted_plane() -> np.ndarray:
    """A panel 50 m away, tilted along the columns (metres)."""
    cols = np.arange(SIZE, dtype=np.float32)[None, :]
    return np.repeat(50.0 + 0.01 * cols, SIZE, axis=0)


def returns_of(depth: np.ndarray, step: int = 8) -> np.ndarray:
    sparse = np.zeros_like(depth)
    sparse[4::step, 4::step] = depth[4::step, 4::step]
    return sparse


def test_a_depth_edge_the_model_smoothed_is_sharpened_next_to_the_returns():
    truth = tilted_plane()
    truth[:, 48:] += 2.0  # a panel 2 m behind the one on the left
    ramp = np.clip((np.arange(SIZE) - 40) / 16, 0, 1).astype(np.float32)  # smoothed over 16 px
    predicted = tilted_plane() + 2.0 * ramp[None, :]
    sparse = returns_of(truth, step=4)
    anchored = anchor_to_returns(
        predicted, truth > 0, sparse, sigma_px=2.0, focal_px=FOCAL_PX
    ).depth
    checked = (sparse > 0) | (np.abs(np.arange(SIZE) - 46)[None, :] > 8)  # returns, flat parts
    before, after = np.abs(predicted - truth), np.abs(anchored - truth)
    assert after[sparse > 0].mean() < 0.3 * before[sparse > 0].mean()
    assert after[checked].mean() < 0.5 * before[checked].mean()


def test_a_local_error_is_corrected_at_its_return_and_left_far_from_it():
    truth = tilted_plane()
    predicted = truth.copy()
    predicted[30:40, 30:40] += 2.0  # a 2 m error around the return at (36, 36)
    sparse = returns_of(truth)
    anchored = anchor_to_returns(
        predicted, np.ones(truth.shape, bool), sparse, sigma_px=2.0, focal_px=FOCAL_PX
    ).depth
    assert abs(anchored[36, 36] - truth[36, 36]) < 0.2, "the measured point agrees"
    assert abs(anchored[60, 60] - truth[60, 60]) < 1e-6, "nothing moves far from the error"
    assert np.abs(anchored - truth)[34:39, 34:39].mean() < 0.5 * 2.0, "and its neighbours"


def test_the_lidar_noise_is_not_copied_into_a_surface_the_model_fits():
    truth = tilted_plane()
    sparse = returns_of(truth, step=4)
    noisy = np.where(sparse > 0, sparse + np.random.default_rng(0).normal(0, 0.03, sparse.shape), 0)
    anchored = anchor_to_returns(
        truth, np.ones(truth.shape, bool), noisy.astype(np.float32), 2.0, FOCAL_PX
    ).depth
    copied = np.abs(noisy - truth)[sparse > 0].mean()
    assert np.abs(anchored - truth).mean() < 0.4 * copied  # a third of it at SHRINK 0.5


def test_where_the_surface_missed_its_returns_the_returns_answer_next_to_them():
    """Where a surface is off its returns by far more than the frame's noise (a slope the
    plane fit got wrong, here a 30 cm ripple over a third of the panel), the depth goes
    from the return's own at the return to the corrected surface two kernel widths away, as a
    fill would next to the returns; where the surface fits, nothing moves."""
    truth = tilted_plane()
    cols = np.arange(SIZE, dtype=np.float32)[None, :]
    ripple = np.where((cols >= 32) & (cols < 64), np.sin(cols / 1.3), 0.0)
    predicted = (truth + 0.3 * ripple * np.ones((SIZE, 1))).astype(np.float32)
    sparse = returns_of(truth)
    anchored = anchor_to_returns(predicted, np.ones(truth.shape, bool), sparse, 2.0, FOCAL_PX)
    at = sparse > 0
    off = at & (np.abs(predicted - truth) > 0.03)
    np.testing.assert_allclose(anchored.depth[off], truth[off], atol=1e-5)  # not shrunk
    beside = np.roll(off, 1, axis=1)  # a pixel right of each: a quarter of the way out
    # the return's residual spread onto its neighbour left 0.18 m there: the ripple differs
    assert np.abs(anchored.depth - truth)[beside].mean() < 0.08
    np.testing.assert_array_equal(anchored.depth[:, :16], truth[:, :16])  # the fitting part
    nearest = nearest_return(sparse)[1]
    np.testing.assert_allclose(anchored.disagreement_m, np.abs(anchored.depth - nearest))


def test_without_returns_on_the_mask_the_depth_is_unchanged():
    truth = tilted_plane()
    mask = np.zeros(truth.shape, bool)
    mask[40:60, 40:60] = True
    sparse = returns_of(truth)
    sparse[40:60, 40:60] = 0  # returns only off the mask
    predicted = truth + 1.0
    np.testing.assert_array_equal(
        anchor_to_returns(predicted, mask, sparse, 3.0, FOCAL_PX).depth, predicted
    )


@pytest.mark.parametrize(
    ("spacing", "frame_per_grid", "expected"),
    [
        (8.0, 1.0, 6.0),  # 0.75 x 8 = 6 frame px
        (40.0, 1.0, SIGMA_BOUNDS_PX[1]),  # sparse returns: capped
        (1.0, 1.0, SIGMA_BOUNDS_PX[0]),  # dense returns: at least the floor
        (4.0, 2.0, 3.0),  # a shrunk crop: 4 grid px = 8 frame px -> 6 frame px = 3 grid px
        (None, 0.25, SIGMA_BOUNDS_PX[1] / 0.25),  # spacing unknown: the cap
    ],
)
def test_the_kernel_follows_the_returns_spacing_in_frame_pixels(spacing, frame_per_grid, expected):
    assert spreading_sigma_px(spacing, frame_per_grid) == pytest.approx(expected)


def test_the_sigma_shrinks_at_the_returns_and_grows_away_from_them():
    truth = tilted_plane()
    sparse = np.zeros_like(truth)
    sparse[20:40:4, 20:40:4] = truth[20:40:4, 20:40:4]  # returns on one patch only
    rng = np.random.default_rng(0)
    predicted = truth + np.where(sparse > 0, rng.normal(0, 0.05, truth.shape), 0)  # off by ~5 cm
    anchored = anchor_to_returns(predicted.astype(np.float32), truth > 0, sparse, 2.0, FOCAL_PX)
    network = np.full(truth.shape, 0.1, np.float32)
    sigma = recombined_sigma(network, anchored)
    ratio = error_ratio(network, anchored)
    assert ratio == pytest.approx(np.median(np.abs(anchored.residual)) / 0.1)
    floor = (SIGMA_PER_MISFIT * anchored.misfit) ** 2 + (SIGMA_PER_NOISE * anchored.noise_m) ** 2
    floor += (SIGMA_PER_DISAGREEMENT * anchored.disagreement_m) ** 2
    at_return = math.sqrt((0.1 * ratio * SIGMA_AT_RETURN) ** 2 + floor[28, 28])
    assert sigma[28, 28] == pytest.approx(at_return, rel=1e-4)
    # (80, 80) is 44 px down and across from the nearest return, (36, 36): 62 px of 5 cm
    apart_m = math.hypot(44, 44) * truth[80, 80] / FOCAL_PX
    assert anchored.apart_m[80, 80] == pytest.approx(apart_m, rel=0.02)
    # ... and 44 columns of 1 cm each further along the tilt than it
    assert anchored.disagreement_m[80, 80] == pytest.approx(0.44, abs=0.01)
    far = 0.1 * ratio * math.hypot(SIGMA_AT_RETURN, SIGMA_PER_APART_M * anchored.apart_m[80, 80])
    assert sigma[80, 80] == pytest.approx(math.sqrt(far**2 + floor[80, 80]), rel=1e-4)
    assert sigma[28, 28] < sigma[30, 30] < sigma[80, 80]  # between returns: a little apart


def test_the_sigma_away_from_the_returns_is_the_same_seen_by_two_cameras():
    """The same panel and LIDAR seen at focal lengths of 1000 and 500 px: the pixel at the
    same place on the panel is as far from the nearest return in metres, so as uncertain."""
    sigmas = []
    for focal_px, step in ((FOCAL_PX, 8), (FOCAL_PX / 2, 4)):
        size = int(SIZE * focal_px / FOCAL_PX)
        depth = np.full((size, size), 50.0, np.float32)
        sparse = np.zeros_like(depth)
        sparse[: size // 2 : step, : size // 2 : step] = 50.0  # returns on the upper left only
        anchored = anchor_to_returns(depth, depth > 0, sparse, 2.0, focal_px)
        sigmas.append(recombined_sigma(np.full_like(depth, 0.1), anchored))
    wide, narrow = sigmas
    assert narrow[40, 40] == pytest.approx(wide[80, 80], rel=0.05)
    assert wide[80, 80] > 5 * wide[4, 4]  # and it did grow away from the returns


def test_the_sigma_follows_how_wrong_the_network_was_at_the_returns():
    truth = tilted_plane()
    sparse = returns_of(truth)
    offsets = np.random.default_rng(1).normal(0, 1.0, truth.shape).astype(np.float32)
    network = np.full(truth.shape, 0.1, np.float32)
    sigmas = []
    for error_m in (0.05, 0.15):  # the network's errors at the returns, then three times as large
        predicted = truth + error_m * offsets
        anchored = anchor_to_returns(predicted, truth > 0, sparse, sigma_px=2.0, focal_px=FOCAL_PX)
        sigmas.append(anchored_sigma(network, anchored, truth > 0)[80, 80])
    # within 6 %: the metres per pixel of apart_m follow the depth, which moved by the error,
    # and the misfit, the disagreement and the noise (capped) grow with it, not in proportion
    assert sigmas[1] == pytest.approx(3 * sigmas[0], rel=0.06)


def test_a_surface_off_by_metres_at_every_return_is_not_taken_for_noise():
    """The network 1 m behind every return: the residuals' median is its misfit, not the
    LIDAR's noise (centimetres), so the depth is drawn to the returns."""
    truth = tilted_plane()
    sparse = returns_of(truth)
    anchored = anchor_to_returns(truth + 1.0, truth > 0, sparse, sigma_px=2.0, focal_px=FOCAL_PX)
    cap = max(MAX_NOISE_M, MAX_NOISE_OF_DEPTH * float(np.median(sparse[sparse > 0])))
    assert anchored.noise_m == pytest.approx(cap)
    at_returns = sparse > 0
    np.testing.assert_allclose(anchored.depth[at_returns], truth[at_returns], atol=1e-4)
    assert np.abs(anchored.depth - truth)[4:-4, 4:-4].max() < 1.0  # nearer everywhere


@pytest.mark.parametrize("count", [1, MIN_RETURNS_FOR_RATIO - 1, MIN_RETURNS_FOR_RATIO])
def test_a_few_returns_copied_exactly_do_not_lower_the_networks_sigma(count):
    """A network that matched every return exactly: from many returns the frame is taken as
    easy (the ratio at its floor); from a few, that says nothing of the depth between them."""
    truth = tilted_plane()
    sparse = np.zeros_like(truth)
    rows, cols = np.divmod(np.arange(count) * 7 % (SIZE * SIZE), SIZE)  # spread over the panel
    sparse[rows, cols] = truth[rows, cols]
    anchored = anchor_to_returns(truth, truth > 0, sparse, sigma_px=2.0, focal_px=FOCAL_PX)
    assert anchored.residual.size == count
    ratio = error_ratio(np.full(truth.shape, 0.1, np.float32), anchored)
    few = count < MIN_RETURNS_FOR_RATIO
    assert ratio == pytest.approx(NETWORK_RATIO if few else MIN_ERROR_RATIO)


def test_without_returns_on_the_mask_the_sigma_is_the_networks():
    truth = tilted_plane()
    mask = np.zeros(truth.shape, bool)
    mask[40:60, 40:60] = True
    sparse = returns_of(truth)
    sparse[40:60, 40:60] = 0
    network = np.full(truth.shape, 0.1, np.float32)
    anchored = anchor_to_returns(truth, mask, sparse, 3.0, FOCAL_PX)
    np.testing.assert_allclose(anchored_sigma(network, anchored, mask), network, rtol=1e-6)


def test_the_sigma_covers_an_error_the_returns_measured():
    truth = tilted_plane()
    predicted = truth.copy()
    predicted[28:45, 28:45] += 2.0  # the model 2 m off around the returns at (36, 36) and more
    sparse = returns_of(truth)
    anchored = anchor_to_returns(
        predicted, np.ones(truth.shape, bool), sparse, sigma_px=2.0, focal_px=FOCAL_PX
    )
    network = np.full(truth.shape, 0.01, np.float32)
    sigma = recombined_sigma(network, anchored)
    assert anchored.misfit[36, 36] == pytest.approx(2.0, abs=0.05)  # its own return's misfit
    ratio = error_ratio(network, anchored)
    expected = math.sqrt(
        (0.01 * ratio * SIGMA_AT_RETURN) ** 2
        + (SIGMA_PER_MISFIT * anchored.misfit[36, 36]) ** 2
        + (SIGMA_PER_DISAGREEMENT * anchored.disagreement_m[36, 36]) ** 2
        + (SIGMA_PER_NOISE * anchored.noise_m) ** 2
    )
    assert sigma[36, 36] == pytest.approx(expected, rel=1e-4)  # 0 m apart at the return
    assert sigma[36, 36] > 1.9  # about the 2 m error the returns measured around it
    assert sigma[70, 70] < 0.1  # far from the error: the network's and the noise's sigma


def test_the_nearest_return_and_its_depth_are_found_for_every_pixel():
    sparse = np.zeros((5, 6), np.float32)
    sparse[4, 1], sparse[0, 4], sparse[2, 0] = 7.0, 3.0, 5.0
    apart_px, depth = nearest_return(sparse)
    assert depth[0, 0] == 5.0 and depth[4, 5] == 7.0 and depth[1, 5] == 3.0
    assert depth[4, 1] == 7.0 and apart_px[4, 1] == 0.0
    assert apart_px[0, 0] == pytest.approx(2.0, abs=0.05)  # two rows above (2, 0)


def test_the_sigma_grows_across_a_depth_edge():
    """One panel with returns on a grid, a second one 3 m behind on the right with none: the
    back panel's pixels, whose nearest returns are the front's, are as uncertain as 3 m of
    disagreement says, many times the front panel's pixels between its returns."""
    depth = np.full((SIZE, SIZE), 50.0, np.float32)
    depth[:, 60:] += 3.0
    sparse = np.zeros_like(depth)
    sparse[4:90:4, 4:56:4] = 50.0
    anchored = anchor_to_returns(depth, depth > 0, sparse, 2.0, FOCAL_PX)
    sigma = recombined_sigma(np.full_like(depth, 0.05), anchored)
    assert anchored.disagreement_m[48, 62] == pytest.approx(3.0, abs=1e-3)
    assert anchored.disagreement_m[48, 30] == 0.0
    assert sigma[48, 62] >= SIGMA_PER_DISAGREEMENT * 3.0 > 3 * sigma[48, 30]


def test_the_sigma_is_shaped_by_the_working_pixels_to_a_return_and_the_outline():
    """By hand: 0.1 m far inside the mask next to a return is ``SIGMA_SCALE`` x 0.1; 31 px from
    the return, (1 + 31) ** 0.2 = 2 times that; on the outline (1 px from the nearest pixel off
    the mask) 1 + 0.6 exp(-1 / 3) times, 4 px in 1 + 0.6 exp(-4 / 3); the grid's border is no
    outline."""
    sigma = np.full((40, 60), 0.1, np.float32)
    apart_px = np.zeros_like(sigma)
    apart_px[:, 30:] = 31.0
    mask = np.zeros(sigma.shape, bool)
    mask[:, :50] = True  # the outline between columns 49 and 50; rows run off the grid
    shaped = shaped_by_grid(sigma, apart_px, mask)
    assert shaped.dtype == np.float32
    assert shaped[0, 10] == pytest.approx(SIGMA_SCALE * 0.1)  # on the border: no outline
    assert shaped[20, 49] == pytest.approx(SIGMA_SCALE * 0.1 * 2.0 * (1 + 0.6 * math.exp(-1 / 3)))
    assert shaped[20, 46] == pytest.approx(SIGMA_SCALE * 0.1 * 2.0 * (1 + 0.6 * math.exp(-4 / 3)))
    assert shaped[20, 10] == pytest.approx(SIGMA_SCALE * 0.1, rel=1e-5)  # 40 px in


def test_the_anchored_sigma_is_the_recombined_one_shaped_on_the_mask():
    truth = tilted_plane()
    sparse = returns_of(truth)
    mask = truth > 0
    mask[:, 70:] = False
    anchored = anchor_to_returns(truth + 0.05, mask, sparse, sigma_px=2.0, focal_px=FOCAL_PX)
    network = np.full(truth.shape, 0.1, np.float32)
    expected = shaped_by_grid(recombined_sigma(network, anchored), anchored.apart_px, mask)
    np.testing.assert_array_equal(anchored_sigma(network, anchored, mask), expected)
    assert anchored.apart_px[4, 4] == 0.0
    assert anchored.apart_px[8, 8] == pytest.approx(4 * 2**0.5, abs=0.1)  # 4 px down, 4 across
