"""The caveats a completed frame's answer carries: what its mask may not hold."""

import numpy as np

from sdcnet.caveats import CAVEATS, FEW_RETURNS, frame_caveats
from sdcnet.pipeline import complete
from tests.test_pipeline import FX, bright_model, frame, panel_past_the_field


def caveats_of(gray: np.ndarray, sparse: np.ndarray) -> list[str]:
    result = complete(bright_model([]), gray, sparse, FX, stride=64)
    return frame_caveats(result, int(np.count_nonzero(sparse)))


def test_a_well_covered_frame_has_none():
    assert caveats_of(*frame()) == []


def test_a_frame_with_few_returns_says_so():
    gray, sparse = frame(spacing=(60, 60), box=(400, 600, 300, 700))  # 4 x 7 returns
    assert np.count_nonzero(sparse) >= FEW_RETURNS
    assert caveats_of(gray, sparse) == []
    sparse[:, 420:] = 0  # the same spacecraft, a handful of its returns left
    assert 0 < np.count_nonzero(sparse) < FEW_RETURNS
    assert caveats_of(gray, sparse) == ["few_returns"]


def test_a_lidar_field_ending_across_the_spacecraft_says_so():
    gray, sparse = panel_past_the_field((300, 600))  # a panel 300 px wide, cut at column 500
    assert caveats_of(gray, sparse) == ["lidar_field_cut"]
    dark = gray.copy()
    dark[:, 500:] = 0  # the image ends with the returns: the spacecraft does, not the field
    assert caveats_of(dark, sparse) == []


def test_every_code_has_a_meaning():
    assert set(CAVEATS) == {"few_returns", "lidar_field_cut"}
    assert all(len(meaning) > 40 for meaning in CAVEATS.values())
