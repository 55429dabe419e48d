"""Past the returns, under a dark sky: the crop grows to the bright part of the spacecraft the
LIDAR missed, and nowhere else."""

import numpy as np
import pytest

from sdcnet.lit_extent import lit_box
from sdcnet.pipeline import complete, region_of_interest, return_pixels

FX = 7939.2


def bus_and_dark_panel() -> tuple[np.ndarray, np.ndarray]:
    """A bus (rows 300-700, columns 200-500) with returns every 8 px, and a panel (rows
    480-520) out to column 950 that the LIDAR missed (too dark, too specular to answer) but
    the camera sees, gray 200 on a black sky."""
    gray = np.zeros((1024, 1024), np.uint8)
    sparse = np.zeros((1024, 1024), np.float32)
    gray[300:700, 200:500] = 200
    gray[480:520, 500:950] = 200
    sparse[300:700:8, 200:500:8] = 12.0
    return gray, sparse


def bright_model(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
    """A stand-in network: foreground where the gray image is bright, depth 12 m."""
    return np.full_like(gray, 12.0), (gray > 0.5).astype(np.float32)


def crop_of(region) -> tuple[int, int, int, int]:
    return region.y0, region.y1, region.x0, region.x1


def test_the_crop_grows_to_the_part_the_lidar_missed_and_the_mask_holds_it():
    gray, sparse = bus_and_dark_panel()
    region = region_of_interest(gray, sparse)
    assert 950 <= region.x1 <= 950 + 2 * 4, "to the panel's end, a sample's step (4 px) beyond"
    assert region.y0 < 300 and region.y1 > 700 and region.x0 < 200, "the returns' crop within"
    result = complete(bright_model, gray, sparse, FX, stride=64)
    assert result.mask[485:515, 520:945].mean() > 0.97, "the panel is in the mask"
    assert not result.mask[:, 960:].any() and not result.mask[:290].any()


@pytest.mark.parametrize("rows", [(760, 1024), (690, 1024)], ids=["apart", "touching"])
def test_under_a_bright_earth_the_crop_stays_the_returns(rows):
    """The Earth below the spacecraft, apart from it (the sky is not dark) or touching it (the
    bright region joined to the returns is most of the frame): the image cannot tell the
    spacecraft from what is behind it, so the crop is the returns' own."""
    gray, sparse = bus_and_dark_panel()
    plain = region_of_interest(np.ascontiguousarray(gray[:, :500]), sparse[:, :500])
    gray[rows[0] : rows[1]] = np.maximum(gray[rows[0] : rows[1]], 150)
    region = region_of_interest(gray, sparse)
    assert region.x1 < 700, "not grown to the panel"
    assert (region.y0, region.x0) == (plain.y0, plain.x0)
    rows_, cols_ = return_pixels(sparse)
    assert lit_box(rows_, cols_, gray, crop_of(region)) is None


def test_a_far_spacecraft_against_a_bright_limb_is_not_grown_to_it():
    """A small spacecraft (40 x 40 px) on the edge of a bright region a tenth of the frame: the
    region joined to its returns lies almost all outside its crop."""
    gray = np.zeros((1024, 1024), np.uint8)
    sparse = np.zeros((1024, 1024), np.float32)
    gray[500:540, 500:540] = 200
    sparse[500:540:4, 500:540:4] = 150.0
    gray[540:860, 300:620] = 120  # the limb's glow, joined to the spacecraft
    rows, cols = return_pixels(sparse)
    assert lit_box(rows, cols, gray, (480, 560, 480, 560)) is None
    assert region_of_interest(gray, sparse).y1 < 700, "not grown to the limb's end (row 860)"


def test_nothing_to_grow_without_returns_or_past_the_crop():
    gray, sparse = bus_and_dark_panel()
    assert lit_box(np.empty(0, np.intp), np.empty(0, np.intp), gray, (0, 1024, 0, 1024)) is None
    rows, cols = return_pixels(sparse)
    assert lit_box(rows, cols, gray, (0, 1024, 0, 1024)) is None, "all of it in the crop"
    gray[480:520, 500:950] = 0  # no panel: the bus alone, in its crop
    assert lit_box(rows, cols, gray, crop_of(region_of_interest(gray, sparse))) is None
