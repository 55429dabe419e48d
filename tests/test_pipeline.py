"""The crop-infer-paste pipeline every consumer shares."""

import numpy as np
import pytest

from sdcnet.pipeline import complete, drop_specks, region_of_interest, resample_sparse


def frame(size: int = 1024, spacing: tuple[int, int] = (18, 12)):
    gray = np.zeros((size, size), np.uint8)
    gray[400:600, 300:700] = 200  # a bright 200 x 400 px "spacecraft"
    sparse = np.zeros((size, size), np.float32)
    sparse[400 : 600 : spacing[0], 300 : 700 : spacing[1]] = 120.0
    return gray, sparse


def bright_model(calls: list):
    """A stand-in network: foreground where the gray image is bright, depth 100 m."""

    def run(gray: np.ndarray, sparse: np.ndarray):
        calls.append((gray.shape, int(np.count_nonzero(sparse))))
        return np.full_like(gray, 100.0), (gray > 0.5).astype(np.float32)

    return run


def test_region_holds_every_return_and_is_aligned():
    _, sparse = frame()
    region = region_of_interest(sparse, stride=64)
    rows, cols = np.nonzero(sparse)
    assert region.y0 <= rows.min() and rows.max() < region.y1
    assert region.x0 <= cols.min() and cols.max() < region.x1
    assert region.shape[0] % 64 == 0 and region.shape[1] % 64 == 0
    assert region.shape[0] < 1024, "cropped, not the whole frame"
    empty = region_of_interest(np.zeros((100, 80), np.float32), stride=64)
    assert empty.shape == (100, 80)


def test_complete_runs_on_the_crop_and_pastes_back():
    gray, sparse = frame()
    calls = []
    result = complete(bright_model(calls), gray, sparse, stride=64)
    ((shape, returns),) = calls
    assert shape[2:] == result.region.shape and returns == np.count_nonzero(sparse)
    np.testing.assert_array_equal(result.mask, gray > 127)
    assert np.all(result.depth[result.mask] == 100.0) and np.all(result.depth[~result.mask] == 0)


def test_zoom_resamples_the_crop_for_the_network_and_answers_at_image_resolution():
    gray, sparse = frame(512, spacing=(9, 6))
    gray[200:300, 150:350] = 200
    gray[gray != 200] = 0
    sparse = np.zeros((512, 512), np.float32)
    sparse[200:300:9, 150:350:6] = 120.0
    calls = []
    result = complete(bright_model(calls), gray, sparse, stride=64, zoom=2.0)
    ((shape, returns),) = calls
    assert shape[2:] == (2 * result.region.shape[0], 2 * result.region.shape[1])
    assert returns == np.count_nonzero(sparse), "every return kept once"
    assert result.mask.shape == (512, 512)
    assert abs(int(result.mask.sum()) - 100 * 200) < 0.02 * 100 * 200
    with pytest.raises(ValueError, match="zoom"):
        complete(bright_model([]), gray, sparse, stride=64, zoom=0)


def test_resample_sparse_keeps_returns_and_the_nearest_wins():
    sparse = np.zeros((8, 8), np.float32)
    sparse[0, 0], sparse[0, 1], sparse[5, 6] = 50.0, 40.0, 70.0
    small = resample_sparse(sparse, (4, 4))
    assert small[0, 0] == 40.0 and small[2, 3] == 70.0 and np.count_nonzero(small) == 2
    big = resample_sparse(sparse, (16, 16))
    assert sorted(big[big > 0]) == [40.0, 50.0, 70.0]


def test_stars_are_dropped_and_detached_parts_near_the_returns_kept():
    mask = np.zeros((200, 200), bool)
    sparse = np.zeros((200, 200), np.float32)
    mask[50:90, 50:90] = True  # the body
    sparse[60, 60] = 100.0
    mask[95:97, 50:90] = True  # a boom 5 px from the body, no return
    mask[110:112, 50:90] = True  # and its continuation 13 px further: kept hop by hop
    mask[150:153, 170:173] = True  # a star 60 px away
    mask[40:42, 95:99] = True  # a detached part of 8 px, 5 px off the body's corner
    mask[45, 45] = True  # a star of 1 px next to the body
    kept = drop_specks(mask, sparse, keep_distance_px=16.0, min_part_px=8)
    assert kept[50:90, 50:90].all() and kept[95:97, 50:90].all() and kept[110:112, 50:90].all()
    assert kept[40:42, 95:99].all()
    assert not kept[150:153, 170:173].any() and not kept[45, 45]
    assert kept.sum() == 40 * 40 + 2 * 80 + 8
    edge_return = np.zeros_like(sparse)
    edge_return[49, 70] = 100.0  # a return one pixel outside the predicted outline
    assert drop_specks(mask, edge_return, 16.0, 8)[50:90, 50:90].all()
    assert not drop_specks(mask, np.zeros_like(sparse), 16.0, 8).any()
    lone_return = np.zeros_like(sparse)
    lone_return[45, 45] = 100.0  # a 1 px component holding a return is the spacecraft
    assert drop_specks(mask, lone_return, 16.0, 8)[45, 45]


def test_complete_drops_stars_from_the_mask_and_the_depth():
    gray, sparse = frame()
    gray[300:303, 210:213] = 255  # a star inside the crop, ~100 px from every return
    result = complete(bright_model([]), gray, sparse, stride=64)
    assert result.region.y0 < 300 and result.region.x0 < 210
    assert not result.mask[300:303, 210:213].any() and (result.depth[300:303, 210:213] == 0).all()
    assert result.mask[420:580, 320:680].all()
