"""The caveats a completed frame's answer carries: what its mask may not hold."""

import cv2
import numpy as np
import pytest

from sdcnet.caveats import (
    CAVEATS,
    CROP_CUT_IOU_FACTOR,
    FEW_RETURNS,
    MASK_IOU_EXPONENT,
    UNCERTAIN_MASK_IOU,
    expected_iou,
    frame_caveats,
    mask_iou_estimate,
)
from sdcnet.pipeline import ModelFn, complete
from tests.test_pipeline import FX, bright_model, frame, panel_past_the_field


def caveats_of(gray: np.ndarray, sparse: np.ndarray, model: ModelFn | None = None) -> list[str]:
    result = complete(model or bright_model([]), gray, sparse, FX, stride=64)
    return frame_caveats(result, int(np.count_nonzero(sparse)))


def doubtful_model(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
    """A stand-in network sure of nothing: probability 0.55 where the gray image is bright,
    0.45 in a band 8 working pixels wide around it, depth 100 m."""
    bright = (gray[0, 0] > 0.5).astype(np.uint8)
    band = cv2.dilate(bright, np.ones((17, 17), np.uint8)) > bright
    prob = np.where(bright > 0, 0.55, np.where(band, 0.45, 0.0)).astype(np.float32)
    return np.full_like(gray, 100.0), prob[None, None]


def under_the_earth(gray: np.ndarray) -> np.ndarray:
    """``gray`` with the Earth's limb bright across the top of the frame, apart from the
    spacecraft: the sky is not dark, so the crop stays the returns' own
    (``sdcnet.lit_extent``)."""
    earth = gray.copy()
    earth[:100] = 150
    return earth


def test_a_well_covered_frame_has_none():
    assert caveats_of(*frame()) == []


def test_a_frame_with_few_returns_says_so():
    gray, sparse = frame(spacing=(60, 60), box=(400, 600, 300, 700))  # 4 x 7 returns
    assert np.count_nonzero(sparse) >= FEW_RETURNS
    assert caveats_of(gray, sparse) == []
    sparse[:, 420:] = 0  # the same spacecraft, a handful of its returns left
    assert 0 < np.count_nonzero(sparse) < FEW_RETURNS
    # ... on its left end: the rest of it, in sight, runs past the crop around them: under a
    # dark sky the crop grows to hold it, and under the Earth a second look past that crop's
    # side answers all of it
    result = complete(bright_model([]), gray, sparse, FX, stride=64)
    assert result.beyond is None and result.mask[400:600, 300:700].all()
    result = complete(bright_model([]), under_the_earth(gray), sparse, FX, stride=64)
    assert result.beyond is not None and result.mask[400:600, 300:700].all()
    assert caveats_of(gray, sparse) == ["few_returns"]
    gray[:, 420:] = 0  # a spacecraft as small as its returns say
    assert caveats_of(gray, sparse) == ["few_returns"]


def test_a_lidar_field_ending_across_the_spacecraft_says_so():
    gray, sparse = panel_past_the_field((300, 600))  # a panel 300 px wide, cut at column 500
    assert caveats_of(gray, sparse) == ["lidar_field_cut"]
    dark = gray.copy()
    dark[:, 500:] = 0  # the image ends with the returns: the spacecraft does, not the field
    assert caveats_of(dark, sparse) == []


def test_a_mask_that_reaches_the_side_of_its_crop_says_so():
    """The LIDAR hit a bus (rows 400-600, columns 300-500) and not the boom bright beside it
    (columns 500-1000), the Earth in the frame: the crop is the bus's with a margin, and the
    mask, following the image, fills it to its right side. Where the frame's own border is
    that side, nothing is said: the frame, not the crop, cut the spacecraft."""
    gray, sparse = frame(box=(400, 600, 300, 500))
    assert caveats_of(gray, sparse) == []
    boom = under_the_earth(gray)  # under a dark sky the crop would hold the boom
    boom[480:520, 500:1000] = 200
    result = complete(bright_model([]), boom, sparse, FX, stride=64)
    assert result.region.x1 < 1000  # the crop ends before the boom does
    assert result.mask[500, result.region.x1 - 1]
    assert frame_caveats(result, int(np.count_nonzero(sparse))) == ["crop_cut"]
    # sure of its outline on what it saw, not of what lies beyond: the estimate lowered
    assert result.mask_iou_estimate == pytest.approx(CROP_CUT_IOU_FACTOR)
    at_border = frame(box=(400, 600, 0, 200))  # the bus cut by the frame's left border
    result = complete(bright_model([]), *at_border, FX, stride=64)
    assert result.region.x0 == 0 and result.mask[500, 0]
    assert caveats_of(*at_border) == [] and result.mask_iou_estimate == 1.0


def test_the_expected_iou_is_the_probabilitys_intersection_over_its_union():
    prob = np.zeros((10, 10), np.float32)
    mask = np.zeros((10, 10), bool)
    mask[:4] = True  # 40 pixels
    prob[:4] = 1.0
    assert expected_iou(prob, mask) == 1.0  # certain, and the mask follows it
    prob[:4] = 0.5
    prob[4:6] = 0.25  # 20 pixels off the mask, a quarter likely the spacecraft's
    assert expected_iou(prob, mask) == pytest.approx(20 / (40 + 5))
    assert expected_iou(prob, np.zeros_like(mask)) == 0.0
    assert expected_iou(np.zeros_like(prob), np.zeros_like(mask)) == 0.0
    estimate = mask_iou_estimate(prob, mask)  # the network surer than right: lowered
    assert estimate == pytest.approx((20 / 45) ** MASK_IOU_EXPONENT) and estimate < 20 / 45
    prob[0, 0], prob[9, 9] = 7.0, -3.0  # another model's output, outside [0, 1]: clipped
    assert expected_iou(prob, mask) == pytest.approx(20.5 / (40 + 5))
    prob[0, 1], prob[5, 5] = np.nan, np.nan  # taken as 0, as the mask takes them
    assert expected_iou(prob, mask) == pytest.approx(20.0 / (40 + 4.75))


def test_a_mask_the_network_doubts_says_so():
    gray, sparse = frame()
    certain = complete(bright_model([]), gray, sparse, FX, stride=64)
    assert certain.mask_iou_estimate == 1.0
    doubtful = complete(doubtful_model, gray, sparse, FX, stride=64)
    np.testing.assert_array_equal(doubtful.mask, certain.mask)  # the same mask, in doubt
    assert doubtful.mask_iou_estimate < UNCERTAIN_MASK_IOU
    assert caveats_of(gray, sparse, doubtful_model) == ["mask_uncertain"]


def test_every_code_has_a_meaning():
    assert set(CAVEATS) == {"few_returns", "lidar_field_cut", "crop_cut", "mask_uncertain"}
    assert all(len(meaning) > 40 for meaning in CAVEATS.values())
