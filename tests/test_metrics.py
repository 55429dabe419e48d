import numpy as np
import pytest

from sdcnet.metrics import ALPHA_M, MetricTable, frame_metrics, markdown_table


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
