"""Stray LIDAR returns: alone in the sky, left out before the crop is chosen."""

import numpy as np

from sdcnet.pipeline import complete
from sdcnet.returns import return_pixels
from sdcnet.stray_returns import (
    MIN_GROUP_RETURNS,
    MIN_RETURNS_TO_JUDGE,
    STRAY_SPACINGS,
    stray_returns,
    without_strays,
)
from tests.test_pipeline import FX, bright_model, frame

STRAYS = ((40, 900), (950, 60), (980, 990))  # far from the spacecraft's returns


def strays_of(sparse: np.ndarray) -> set[tuple[int, int]]:
    rows, cols = return_pixels(sparse)
    flagged = stray_returns(rows, cols, sparse.shape)
    return {(int(r), int(c)) for r, c in zip(rows[flagged], cols[flagged], strict=True)}


def test_returns_alone_far_from_the_spacecrafts_are_strays_and_no_other():
    _, sparse = frame()
    for row, col in STRAYS:
        sparse[row, col] = 120.0
    assert strays_of(sparse) == set(STRAYS)
    kept, count = without_strays(sparse)
    assert count == 3 and np.count_nonzero(kept) == np.count_nonzero(sparse) - 3
    assert all(kept[r, c] == 0 for r, c in STRAYS)


def test_no_lidar_patterns_own_returns_are_strays():
    size = 1024
    patterns = {
        "grid": (slice(400, 600, 18), slice(300, 700, 12)),  # the paper's scanner
        "multi-beam": (slice(300, 700, 40), slice(200, 800, 2)),  # rows far apart, dense along
        "flash": (slice(256, 768, 4), slice(256, 768, 4)),  # a dense array
    }
    for name, (rows, cols) in patterns.items():
        sparse = np.zeros((size, size), np.float32)
        sparse[rows, cols] = 50.0
        assert not strays_of(sparse), name


def test_a_small_part_with_a_few_returns_of_its_own_is_kept():
    _, sparse = frame()
    sparse[100:130:10, 880:900:10] = 120.0  # an antenna's 6 returns, 300 px from the body
    sparse[60, 60] = 120.0  # and one return alone
    assert strays_of(sparse) == {(60, 60)}


def test_strays_near_each_other_far_from_the_spacecraft_are_strays_together():
    _, sparse = frame()
    pair = {(60, 60), (60, 75)}  # one return spacing apart, 250 px from the spacecraft's
    for row, col in pair:
        sparse[row, col] = 120.0
    assert MIN_GROUP_RETURNS == 3 and strays_of(sparse) == pair
    sparse[70, 65] = 120.0  # a third joins them: a group of three is a part
    assert not strays_of(sparse)


def test_a_return_within_reach_of_another_is_not_a_stray():
    _, sparse = frame()  # returns 18 x 12 px apart: a spacing of about 14.7 px
    rows, _ = return_pixels(sparse)
    near = int(rows.max()) + int(0.8 * STRAY_SPACINGS * 14.7)
    far = int(rows.max()) + int(2 * STRAY_SPACINGS * 14.7)
    sparse[near, 500] = sparse[far, 300] = 120.0
    assert strays_of(sparse) == {(far, 300)}


def test_too_few_returns_or_too_sparse_a_pattern_keeps_every_return():
    sparse = np.zeros((1024, 1024), np.float32)
    rng = np.random.default_rng(0)
    spots = rng.choice(1024 * 1024, MIN_RETURNS_TO_JUDGE - 1, replace=False)
    sparse.ravel()[spots] = 80.0
    assert not strays_of(sparse)
    sparse.ravel()[rng.choice(1024 * 1024, 200, replace=False)] = 80.0  # scattered all over
    assert not strays_of(sparse)
    assert without_strays(sparse)[0] is sparse


def test_the_answer_with_strays_is_the_answer_without_them():
    gray, sparse = frame()
    clean = complete(bright_model([]), gray, sparse, FX, stride=64)
    noisy_sparse = sparse.copy()
    for row, col in STRAYS:
        noisy_sparse[row, col] = 120.0
        gray[row - 1 : row + 2, col - 1 : col + 2] = 255  # each on a star
    noisy = complete(bright_model([]), gray, noisy_sparse, FX, stride=64)
    assert noisy.stray_returns == 3 and clean.stray_returns == 0
    assert noisy.region == clean.region
    assert np.array_equal(noisy.mask, clean.mask) and np.array_equal(noisy.depth, clean.depth)
    # the answer records the returns it used: what POST /pose registers the cloud to
    assert np.array_equal(noisy.used_returns, sparse) and clean.used_returns is sparse


def test_a_parts_lone_return_is_left_out_of_the_crop_but_still_anchors_its_depth():
    gray, sparse = frame()
    sparse[:, 500:] = 0  # the returns cover the left half of the spacecraft ...
    sparse[500, 690] = 130.0  # ... and one more lies on its right end, 190 px from them
    result = complete(bright_model([]), gray, sparse, FX, stride=64)
    assert result.stray_returns == 1
    assert result.mask[500, 690]  # the network's mask holds the part, the stray aside
    assert abs(result.depth[500, 690] - 130.0) < 0.5  # anchored to it all the same
    without = sparse.copy()
    without[500, 690] = 0
    assert abs(complete(bright_model([]), gray, without, FX, stride=64).depth[500, 690] - 130) > 5
