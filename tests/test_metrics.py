import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA
from sdcnet.metrics import (
    ALPHA_M,
    BAND_NAMES,
    MetricTable,
    false_specks,
    frame_metrics,
    markdown_table,
    mask_error_bands,
    normal_errors,
    same_pixel_errors,
    surface_normals,
)


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
    assert bands["missed_unseen"] == 0 and bands["fp_far"] == 0
    assert np.isnan(mask_error_bands(np.zeros((4, 4), bool), np.zeros((4, 4)))["miss_edge"])


def test_mask_error_bands_count_the_foreground_the_network_never_saw_apart():
    gt = np.zeros((20, 20), np.float32)
    gt[5:15, 5:15] = 100.0
    seen = np.zeros((20, 20), bool)
    seen[:, :12] = True  # the crop ends 3 columns before the spacecraft does
    pred = (gt > 0) & seen
    pred[1, 1] = True  # a false speck far from the spacecraft
    bands = mask_error_bands(pred, gt, seen)
    union = 101
    assert bands["missed_unseen"] == pytest.approx(30 / union)  # rows 5:15, columns 12:15
    assert bands["miss_edge"] == 0 and bands["miss_near"] == 0
    assert bands["miss_far"] == pytest.approx(1 / union) and bands["fp_far"] == bands["miss_far"]
    iou = frame_metrics(np.where(pred, 100.0, 0.0), pred, gt)["IOU"]
    shares = ("missed_unseen", "miss_edge", "miss_near", "miss_far")
    assert sum(bands[k] for k in shares) == pytest.approx(1 - iou)
    # without ``seen`` the same columns are missed at and away from the outline instead
    assert mask_error_bands(pred, gt)["missed_unseen"] == 0


PAPER_K = PAPER_CAMERA.intrinsics()


def test_same_pixel_errors_by_distance_to_the_nearest_return():
    gt = np.full((40, 40), 100.0, np.float32)
    sparse = np.zeros_like(gt)
    sparse[20, 20] = 100.0
    rows, cols = np.mgrid[0:40, 0:40]
    distance = np.hypot(rows - 20, cols - 20)
    band = np.select([distance <= 3, distance <= 6, distance <= 10], [0, 1, 2], 3)
    pred = gt + 0.1 * (band + 1)  # 0.1 m in the first band, 0.2 in the second...
    fill = gt + 0.05
    pred_mask = np.ones_like(gt, bool)
    fill_mask = distance <= 12  # the fill answers only near the return: the common pixels
    e = same_pixel_errors(pred, pred_mask, fill, fill_mask, gt, sparse)
    common = fill_mask
    assert e["MAE"] == pytest.approx(float((0.1 * (band + 1))[common].mean()), rel=1e-5)
    assert e["fill_MAE"] == pytest.approx(0.05, rel=1e-4)
    for i, name in enumerate(BAND_NAMES):
        assert e[f"MAE_{name}"] == pytest.approx(0.1 * (i + 1), rel=1e-4)
        assert e[f"fill_MAE_{name}"] == pytest.approx(0.05, rel=1e-4)
    nothing = same_pixel_errors(pred, pred_mask, fill, np.zeros_like(fill_mask), gt, sparse)
    assert np.isnan(nothing["MAE"]) and np.isnan(nothing["fill_MAE_0-3px"])


def tilted_plane(shape=(120, 120), z0=100.0, gx=0.004, gy=-0.006) -> np.ndarray:
    """Camera-frame Z (metres) of a plane seen at an angle: Z changes gx, gy metres per pixel."""
    rows, cols = np.mgrid[0 : shape[0], 0 : shape[1]]
    return (z0 + gx * (cols - shape[1] / 2) + gy * (rows - shape[0] / 2)).astype(np.float32)


def test_normals_of_a_tilted_plane_offset_in_depth_are_right():
    gt = tilted_plane()
    mask = np.ones_like(gt, bool)
    n = normal_errors(gt + 0.5, mask, gt, PAPER_K)  # 0.5 m too far, same orientation
    assert n["normal_mean_deg"] < 0.5 and n["normal_within_11.25"] == 1.0
    normals = surface_normals(gt, PAPER_K)
    assert np.allclose(np.linalg.norm(normals[5:-5, 5:-5], axis=-1), 1.0)
    assert (normals[5:-5, 5:-5, 2] < 0).all()  # facing the camera (z forward)


def test_a_ripple_between_scan_lines_tilts_the_normals_by_its_slope():
    gt = np.full((144, 144), 100.0, np.float32)  # a wall facing the camera
    rows = np.arange(144)[:, None]
    amplitude, period = 0.01, 18.0  # 1 cm with the period of the beam rows
    pred = gt + (amplitude * np.sin(2 * np.pi * rows / period)).astype(np.float32)
    n = normal_errors(pred, np.ones_like(gt, bool), gt, PAPER_K)
    # slope of the ripple over the pixel's footprint (Z / fy metres per pixel)
    slope = amplitude * 2 * np.pi / period * np.abs(np.cos(2 * np.pi * rows[3:-3] / period))
    expected = np.degrees(np.arctan(slope / (100.0 / PAPER_K.fy))).mean()
    assert expected > 5  # the ripple a 1 cm MAE hides
    assert n["normal_mean_deg"] == pytest.approx(expected, rel=0.05)


def test_normals_leave_out_the_outline_and_depth_edges():
    gt = tilted_plane()
    gt[:, 60:] += 5.0  # a step: two surfaces
    pred = gt.copy()
    pred[:, 55:65] = 0.0  # wrong right at the step: not counted
    mask = np.ones_like(gt, bool)
    assert normal_errors(pred, mask, gt, PAPER_K)["normal_mean_deg"] < 0.5
    assert np.isnan(normal_errors(pred, np.zeros_like(mask), gt, PAPER_K)["normal_mean_deg"])


def test_false_specks_are_stars_not_detached_parts_of_the_spacecraft():
    gt = np.zeros((60, 60), np.float32)
    gt[10:30, 10:30] = 100.0  # the body, with a return
    gt[40:50, 10:14] = 101.0  # an antenna that looks detached and has no return
    sparse = np.zeros_like(gt)
    sparse[20, 20] = 100.0
    pred = gt > 0
    pred[5:7, 50:52] = True  # a star taken for the spacecraft
    pred[55, 55] = True  # another one
    pred[38:52, 8:16] = True  # the antenna drawn too wide (36 % on it): an outline error
    assert false_specks(pred, sparse, gt) == 2
    assert false_specks(gt > 0, sparse, gt) == 0
