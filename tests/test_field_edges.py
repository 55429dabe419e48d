"""Past the edge of a LIDAR field narrower than the camera's: the crop grows there and the mask
follows the image beyond it, where the sky is dark."""

import cv2
import numpy as np
import pytest

from sdcnet.field_edges import FieldCuts, field_cuts, grown_past_field
from sdcnet.pipeline import complete
from sdcnet.returns import return_pixels, return_spacing

FX = 7939.2


def bus_and_panel(earth: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A bus (rows 100-900, columns 100-400) with a panel out to column 1000 on rows 300-600,
    gray 200 on a black sky; returns every 18 x 12 px on both, the LIDAR's field ending at
    column 500, across the panel. A bright blob (rows 950-1000, columns 150-250) inside the
    field has no return. ``earth``: the frame's rows 640 and below are a bright Earth."""
    gray = np.zeros((1024, 1024), np.uint8)
    sparse = np.zeros((1024, 1024), np.float32)
    for y0, y1, x0, x1 in ((100, 900, 100, 400), (300, 600, 400, 1000)):
        gray[y0:y1, x0:x1] = 200
        sparse[y0:y1:18, x0:x1:12] = 120.0
    sparse[:, 500:] = 0
    if earth:
        gray[640:] = np.maximum(gray[640:], 150)
    gray[950:1000, 150:250] = 200
    return gray, sparse


def near_returns_model(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
    """A stand-in network that learned the spacecraft is where its returns are: foreground
    where the gray image is bright within a few pixels of a return, depth 100 m."""
    near = cv2.dilate((sparse[0, 0] > 0).astype(np.uint8), np.ones((25, 25), np.uint8)) > 0
    prob = ((gray[0, 0] > 0.5) & near).astype(np.float32)
    return np.full_like(gray, 100.0), prob[None, None]


def test_the_mask_follows_the_image_past_the_field_edge_under_a_dark_sky():
    gray, sparse = bus_and_panel()
    result = complete(near_returns_model, gray, sparse, FX, stride=64)
    beyond = result.mask[310:590, 520:990]
    assert beyond.mean() > 0.97, "the panel past the field's edge is in the mask"
    assert not result.mask[:, 1010:].any() and not result.mask[610:640, 420:].any()
    assert not result.mask[950:1000, 150:250].any(), "inside the field, no return, no mask"
    assert np.all(result.depth[result.mask] > 0), "every pixel of the mask has a depth"


def test_under_a_bright_earth_the_mask_stops_at_the_field_edge():
    """Past the field the image is all that tells the spacecraft from what is behind it: with
    the Earth bright beside it, nothing is grown (a cloud would be glued to the panel)."""
    gray, sparse = bus_and_panel(earth=True)
    result = complete(near_returns_model, gray, sparse, FX, stride=64)
    assert not result.mask[300:600, 700:].any()
    assert result.mask[310:590, 420:480].all(), "what the field saw stays"


def test_the_cut_is_the_side_the_returns_follow_with_the_image_bright_beyond():
    gray, sparse = bus_and_panel()
    rows, cols = return_pixels(sparse)
    cuts = field_cuts(rows, cols, gray, return_spacing(rows, cols))
    assert cuts is not None and (cuts.top, cuts.bottom, cuts.left, cuts.right) == (
        False,
        False,
        False,
        True,
    )
    assert (cuts.x0, cuts.x1) == (100, int(cols.max()) + 1) and cuts.bright == 50.0
    dark = gray.copy()
    dark[:, 500:] = 0  # the panel ends where the field does: no cut
    assert field_cuts(rows, cols, dark, return_spacing(rows, cols)) is None


def test_beyond_maps_the_cut_sides_onto_a_resampled_crop():
    cuts = FieldCuts(100, 200, 300, 400, spacing=10.0, bright=1.0, top=True, bottom=False,
                     left=False, right=True)  # fmt: skip
    zone = cuts.beyond(origin=(50, 250), scale=(0.5, 2.0), shape=(100, 400))
    rows = np.flatnonzero(zone[:, 0])  # column 0 lies left of the box: only the top cut there
    assert rows.max() + 1 == pytest.approx((100 - 5 - 50) * 0.5, abs=1)
    cols = np.flatnonzero(zone[-1])  # the last row lies below the top cut: the right cut alone
    assert cols.min() == pytest.approx((400 + 5 - 250) * 2.0, abs=1)


def test_only_bright_pixels_joined_to_the_mask_are_grown():
    gray = np.zeros((50, 60), np.float32)
    gray[10:20, 5:55] = 1.0  # a panel across the whole grid
    gray[30:35, 40:45] = 1.0  # a bright speck beyond, apart from it
    bright = 0.25  # a quarter of the gray at the returns
    mask = np.zeros(gray.shape, bool)
    mask[10:20, 5:32] = True  # the network's mask reaches a little past the returns
    beyond = np.zeros(gray.shape, bool)
    beyond[:, 30:] = True
    grown = grown_past_field(mask, gray, bright, beyond)
    assert grown[10:20, 5:55].all() and not grown[30:35].any()
    assert np.count_nonzero(grown) == 10 * 50, "nothing dark is grown"
    assert grown_past_field(mask, gray, bright, np.zeros_like(beyond)) is mask, "no zone"
    gray[10:20, 27:30] = 0.0
    mask[10:20, 27:32] = False  # a dark gap between the mask and the panel: nothing joins
    assert grown_past_field(mask, gray, bright, beyond) is mask
