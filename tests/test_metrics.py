import numpy as np
import pytest

from sdcnet.metrics import ALPHA_M, MetricTable, frame_metrics, markdown_table, mask_error_bands


def test_oracle_scores_perfectly():
    gt = np.zeros((6, 6), np.float32)
    gt[1:4, 2:5] = 100.0
    m = frame_metrics(gt, gt > 0, gt)
    assert m == {"IOU": 1.0, "IOI": 1.0, "MAEI": 0.0, "MATE": 0.0, "RMSEI": 0.0, "RMSTE": 0.0}


def test_hand_computed_example():
    gt = np.array([[0, 100, 100, 100]], np.float32)  # A = {1, 2, 3}
    pred = np.array([[90, 101, 103, 0]], np.float32)
    mask = np.array([[1, 1, 1, 0]], bool)  # Â = {0, 1, 2}: one false positive, one miss
    m = frame_metrics(pred, mask, gt)
    assert m["IOU"] == pytest.approx(2 / 4)
    assert m["IOI"] == pytest.approx(2 / 3)
    assert m["MAEI"] == pytest.approx((1 + 3) / 2)
    assert m["RMSEI"] == pytest.approx(np.sqrt((1 + 9) / 2))
    # the false positive (90 m over sky) is truncated at alpha
    assert m["MATE"] == pytest.approx((ALPHA_M + 1 + 3) / 3)
    assert m["RMSTE"] == pytest.approx(np.sqrt((ALPHA_M**2 + 1 + 9) / 3))


def test_empty_sets_are_counted_not_averaged():
    gt = np.zeros((2, 2), np.float32)
    gt[0, 0] = 50
    missed = frame_metrics(np.zeros_like(gt), np.zeros((2, 2), bool), gt)
    assert np.isnan(missed["MAEI"]) and missed["MATE"] == ALPHA_M and missed["IOU"] == 0
    table = MetricTable()
    table.add(missed)
    table.add(frame_metrics(gt, gt > 0, gt))
    assert table.mean()["MAEI"] == 0.0 and table.undefined()["MAEI"] == 1
    assert table.mean()["MATE"] == pytest.approx(ALPHA_M / 2)
    assert "| a | 50.00 |" in markdown_table({"a": table.mean()})


def test_mask_error_bands_split_the_iou_deficit_by_distance_to_the_outline():
    gt = np.zeros((20, 20), np.float32)
    gt[5:15, 5:15] = 100.0  # a 10 x 10 square
    pred = gt > 0
    pred[5:15, 15] = True  # one column too wide: false foreground touching the outline
    pred[9, 9] = False  # a hole 4 px inside: a far miss
    bands = mask_error_bands(pred, gt)
    union = 110
    assert bands["fp_edge"] == pytest.approx(10 / union) and bands["fn_edge"] == 0
    assert bands["miss_edge"] == pytest.approx(10 / union)
    assert bands["miss_near"] == 0 and bands["miss_far"] == pytest.approx(1 / union)
    iou = frame_metrics(np.where(pred, 100.0, 0.0), pred, gt)["IOU"]
    assert bands["miss_edge"] + bands["miss_near"] + bands["miss_far"] == pytest.approx(1 - iou)
    # off the edge only the hole is wrong: 8 x 8 interior minus 1, over the 64 off-edge pixels
    assert bands["IOU_off_edge"] == pytest.approx(63 / 64)
    assert np.isnan(mask_error_bands(np.zeros((4, 4), bool), np.zeros((4, 4)))["miss_edge"])
