"""The depth anchored to the LIDAR returns: measured errors corrected, noise not copied."""

import numpy as np
import pytest

from sdcnet.anchoring import SIGMA_BOUNDS_PX, anchor_to_returns, spreading_sigma_px

SIZE = 96


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
    anchored = anchor_to_returns(predicted, truth > 0, sparse, sigma_px=2.0)
    checked = (sparse > 0) | (np.abs(np.arange(SIZE) - 46)[None, :] > 8)  # returns, flat parts
    before, after = np.abs(predicted - truth), np.abs(anchored - truth)
    assert after[sparse > 0].mean() < 0.3 * before[sparse > 0].mean()
    assert after[checked].mean() < 0.5 * before[checked].mean()


def test_a_local_error_is_corrected_at_its_return_and_left_far_from_it():
    truth = tilted_plane()
    predicted = truth.copy()
    predicted[30:40, 30:40] += 2.0  # a 2 m error around the return at (36, 36)
    sparse = returns_of(truth)
    anchored = anchor_to_returns(predicted, np.ones(truth.shape, bool), sparse, sigma_px=2.0)
    assert abs(anchored[36, 36] - truth[36, 36]) < 0.2, "the measured point agrees"
    assert abs(anchored[60, 60] - truth[60, 60]) < 1e-6, "nothing moves far from the error"
    assert np.abs(anchored - truth)[34:39, 34:39].mean() < 0.5 * 2.0, "and its neighbours"


def test_the_lidar_noise_is_not_copied_into_a_surface_the_model_fits():
    truth = tilted_plane()
    sparse = returns_of(truth, step=4)
    noisy = np.where(sparse > 0, sparse + np.random.default_rng(0).normal(0, 0.03, sparse.shape), 0)
    anchored = anchor_to_returns(truth, np.ones(truth.shape, bool), noisy.astype(np.float32), 2.0)
    copied = np.abs(noisy - truth)[sparse > 0].mean()
    assert np.abs(anchored - truth).mean() < 0.25 * copied


def test_without_returns_on_the_mask_the_depth_is_unchanged():
    truth = tilted_plane()
    mask = np.zeros(truth.shape, bool)
    mask[40:60, 40:60] = True
    sparse = returns_of(truth)
    sparse[40:60, 40:60] = 0  # returns only off the mask
    predicted = truth + 1.0
    np.testing.assert_array_equal(anchor_to_returns(predicted, mask, sparse, 3.0), predicted)


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
