"""The crop-resample-infer-paste pipeline every consumer shares, and its fixed budget."""

import cv2
import numpy as np
import pytest

from sdcnet.camera import Intrinsics
from sdcnet.normals import cloud_normals, normal_map
from sdcnet.pipeline import (
    FIELD_EDGE_GROWTH,
    MAX_UPSAMPLE,
    MIN_SECOND_LOOK_SHARE,
    MIN_WORK_SHARE,
    RETURN_REACH_PX,
    SECOND_LOOK_SHARE,
    WORK_PIXELS,
    Region,
    complete,
    complete_on,
    drop_specks,
    frame_work_pixels,
    grown_past_sides,
    guide_gain,
    guided_probability,
    join_returns_beside,
    mask_box,
    nearest_resampled,
    region_around,
    region_of_interest,
    resample_depth,
    resample_image,
    resample_sparse,
    return_pixels,
    return_spacing,
    second_look_pixels,
    source_indices,
    spacecraft_region,
    vouched_mask,
    working_grid,
    working_inputs,
)
from sdcnet.returns import row_ends

FX = 7939.2


def frame(size: int = 1024, spacing: tuple[int, int] = (18, 12), box=(400, 600, 300, 700)):
    y0, y1, x0, x1 = box
    gray = np.zeros((size, size), np.uint8)
    gray[y0:y1, x0:x1] = 200  # a bright "spacecraft"
    sparse = np.zeros((size, size), np.float32)
    sparse[y0 : y1 : spacing[0], x0 : x1 : spacing[1]] = 120.0
    return gray, sparse


def bright_model(calls: list):
    """A stand-in network: foreground where the gray image is bright, depth 100 m."""

    def run(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
        calls.append((gray.shape, int(np.count_nonzero(sparse)), float(focal_px.item())))
        return np.full_like(gray, 100.0), (gray > 0.5).astype(np.float32)

    return run


def test_region_holds_every_return_with_a_margin_of_a_few_spacings():
    gray, sparse = frame()
    region = region_of_interest(gray, sparse)
    rows, cols = np.nonzero(sparse)
    assert region.y0 <= rows.min() - 30 and rows.max() + 30 < region.y1
    assert region.x0 <= cols.min() - 30 and cols.max() + 30 < region.x1
    spacing = return_spacing(rows, cols)
    assert region == region_around(rows, cols, sparse.shape, spacing), "black sky past the edges"
    gray, dense = frame(spacing=(2, 2))
    assert region_of_interest(gray, dense).shape[0] < region.shape[0], "denser, less margin"
    empty = np.zeros((100, 80), np.uint8), np.zeros((100, 80), np.float32)
    assert region_of_interest(*empty).shape == (100, 80)
    lone = np.zeros((1000, 1000), np.float32)
    lone[500, 500] = 50.0  # one return cannot tell the spacecraft's size: a wide margin
    assert region_of_interest(np.zeros(lone.shape, np.uint8), lone).shape == (301, 301)


def test_the_region_grows_past_the_edge_of_a_lidar_field_narrower_than_the_camera():
    """A flash array over the left part of a panel: its returns stop along a straight line with
    the panel going on in the image; the crop grows on that side only, in proportion to the
    returns' width."""
    gray, sparse = frame(box=(400, 600, 200, 800))
    plain = region_of_interest(gray, sparse)
    sparse[:, 400:] = 0  # the LIDAR's field ends at column 400
    cut = region_of_interest(gray, sparse)
    cols = np.nonzero(sparse)[1]
    width = cols.max() + 1 - cols.min()
    gray_dark = gray.copy()
    gray_dark[:, 400:] = 0  # the same returns, the image black past them: the panel ends there
    ended = region_of_interest(gray_dark, sparse)
    assert (cut.y0, cut.y1, cut.x0) == (ended.y0, ended.y1, ended.x0)
    assert cut.x1 == pytest.approx(ended.x1 + FIELD_EDGE_GROWTH * width, abs=1)
    assert cut.x1 >= 600 and plain.x1 >= 800, "the cut panel's crop reaches past the field"


def panel_past_the_field(panel_rows: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A bus (rows 100-900, columns 100-400) with a panel out to column 1000 on ``panel_rows``;
    the LIDAR's field ends at column 500, across the panel only."""
    gray, sparse = frame(box=(100, 900, 100, 400))
    panel_gray, panel_sparse = frame(box=(*panel_rows, 400, 1000))
    gray, sparse = np.maximum(gray, panel_gray), np.maximum(sparse, panel_sparse)
    sparse[:, 500:] = 0
    return gray, sparse


def test_the_region_grows_where_the_field_cuts_across_part_of_the_spacecraft():
    """The field's edge crosses a panel 300 px wide (20 return spacings) on a side 800 px
    long: a cut, so the crop grows on that side, and only where the image beyond the cut,
    alongside it, is bright. A panel 100 px wide ending there is the spacecraft's outline
    meeting its box, and the crop keeps its margin."""
    gray, sparse = panel_past_the_field((300, 600))
    cols = np.nonzero(sparse)[1]
    width = cols.max() + 1 - cols.min()
    grown = region_of_interest(gray, sparse)
    dark = gray.copy()
    dark[:, 500:] = 0
    ended = region_of_interest(dark, sparse)
    assert (grown.y0, grown.y1, grown.x0) == (ended.y0, ended.y1, ended.x0)
    assert grown.x1 == min(1024, round(ended.x1 + FIELD_EDGE_GROWTH * width)) == 1024
    assert ended.x1 < 700
    narrow_gray, narrow_sparse = panel_past_the_field((450, 550))
    rows, cols = return_pixels(narrow_sparse)
    narrow, cuts = spacecraft_region(rows, cols, narrow_gray, return_spacing(rows, cols))
    assert cuts is None, "no cut: the crop is not grown past the field ..."
    assert narrow.x1 >= 1000, "... but to the panel the image shows bright (sdcnet.lit_extent)"


def test_complete_runs_on_the_crop_and_pastes_back():
    gray, sparse = frame()
    calls = []
    result = complete(bright_model(calls), gray, sparse, FX, stride=64)
    ((shape, returns, focal),) = calls
    assert shape[2:] == result.grid.shape and returns == np.count_nonzero(sparse)
    assert focal == pytest.approx(FX * result.grid.scale[1])
    inner = np.zeros_like(result.mask)
    inner[402:598, 302:698] = True
    assert result.mask[inner].all() and not result.mask[(gray == 0) & ~_grown(gray > 0, 2)].any()
    # the stand-in says 100 m everywhere; the returns, 120 m: a bias of the whole surface
    # far above any LIDAR's noise (at most 0.1 % of 120 m, sdcnet.anchoring), so anchoring
    # corrects it and draws the depth to the returns next to them
    on_mask = result.depth[result.mask]
    at_returns = result.mask & (sparse > 0)
    assert on_mask.min() >= 100.0 and on_mask.max() <= 120.0 + 1e-3
    # (the crop seen 0.92x: a return's frame pixel is within a working pixel of its own)
    assert np.mean(np.abs(result.depth[at_returns] - 120.0) < 0.01) > 0.95
    assert np.all(result.depth[~result.mask] == 0)


def _grown(mask: np.ndarray, pixels: int) -> np.ndarray:
    import cv2

    size = 2 * pixels + 1
    return cv2.dilate(mask.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)


def test_the_budget_caps_the_network_input_of_a_2048_px_full_frame():
    gray, sparse = frame(2048, box=(0, 2048, 0, 2048))
    calls = []
    result = complete(bright_model(calls), gray, sparse, 2000.0, stride=64)
    ((shape, returns, focal),) = calls
    padded = [-(-n // 64) * 64 for n in shape[2:]]
    # returns across the whole frame: its work at full resolution leaves the network the least
    seen = padded[0] * padded[1]
    assert 0.7 * MIN_WORK_SHARE * WORK_PIXELS <= seen <= MIN_WORK_SHARE * WORK_PIXELS
    assert result.grid.region == Region(0, 2048, 0, 2048) and result.mask.shape == (2048, 2048)
    assert result.mask.all(), "a frame the spacecraft fills, answered at full resolution"
    assert focal == pytest.approx(2000.0 * shape[3] / 2048)
    assert returns <= np.count_nonzero(sparse)


def test_a_frame_gets_fewer_working_pixels_as_its_own_work_grows_down_to_a_floor():
    """The network's pixels and the frame's own work at its resolution share one budget."""
    paper_frame = frame_work_pixels(WORK_PIXELS, crop_pixels=700 * 700, hull_pixels=300 * 300)
    assert paper_frame == WORK_PIXELS
    large = [frame_work_pixels(WORK_PIXELS, 2048 * 2048, side * side) for side in (700, 900)]
    assert WORK_PIXELS > large[0] > large[1] > MIN_WORK_SHARE * WORK_PIXELS
    whole = frame_work_pixels(WORK_PIXELS, 2048 * 2048, 2048 * 2048)
    assert whole == int(MIN_WORK_SHARE * WORK_PIXELS)
    assert frame_work_pixels(2 * WORK_PIXELS, 700 * 700, 300 * 300) == 2 * WORK_PIXELS


def boom_past_the_returns() -> tuple[np.ndarray, np.ndarray]:
    """A bright boom across a 1024 px frame, rows 480-540, whose returns (a narrow LIDAR's,
    at no straight field edge: a ragged patch) lie on its middle alone, columns 470-560."""
    gray = np.zeros((1024, 1024), np.uint8)
    gray[480:540, :] = 200
    sparse = np.zeros(gray.shape, np.float32)
    rng = np.random.default_rng(3)
    rows, cols = rng.integers(482, 538, 300), rng.integers(470, 560, 300)
    sparse[rows, cols] = 60.0
    return gray, sparse


def test_a_mask_that_reaches_its_crop_side_gets_a_second_look_beyond_it():
    gray, sparse = boom_past_the_returns()
    calls = []
    result = complete(bright_model(calls), gray, sparse, FX, stride=64)
    first, grown = result.grid.region, result.region
    assert len(calls) == 2 and result.beyond is not None
    assert grown.x0 < first.x0 - 100 and first.x1 + 100 < grown.x1
    assert grown.y0 <= first.y0 and first.y1 <= grown.y1
    boom = gray == 200
    seen, looked = np.zeros_like(boom), np.zeros_like(boom)
    seen[first.slices], looked[grown.slices] = True, True
    # the boom beyond the first crop is answered, the first look's answer kept inside it;
    # it still goes on past the second crop, and the answer says so
    assert result.mask[boom & looked & ~seen].mean() > 0.95 and result.mask[boom & seen].all()
    assert not result.mask[~looked].any() and result.crop_cut
    alone = complete_on(bright_model([]), gray, sparse, working_inputs(gray, sparse, FX, 64))
    np.testing.assert_array_equal(result.mask[first.slices], alone.mask[first.slices])
    np.testing.assert_array_equal(result.depth[first.slices], alone.depth[first.slices])
    assert not result.mask[~boom].any()
    assert (result.depth[result.mask] > 0).all() and not result.depth[~result.mask].any()
    assert np.array_equal(result.probability > 0.5, result.mask)
    # every point's normal from the grid that saw it, the cloud's as the map's
    K = Intrinsics(fx=FX, fy=FX, cx=511.5, cy=511.5, width=1024, height=1024)
    normals = normal_map(result, K)[result.mask]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert (normals[:, 2] < 0).all()  # facing the camera
    for stride in (1, 3):
        lattice = result.mask[::stride, ::stride]
        np.testing.assert_array_equal(
            cloud_normals(result, result.mask, K, stride=stride),
            normal_map(result, K)[::stride, ::stride][lattice],
        )


def test_a_second_look_takes_only_what_the_frames_budget_left():
    gray, sparse = boom_past_the_returns()
    inputs = working_inputs(gray, sparse, FX, 64)
    grown = grown_past_sides(inputs.grid.region, (False, False, True, True), gray.shape)
    left = second_look_pixels(inputs, grown, WORK_PIXELS)
    assert MIN_SECOND_LOOK_SHARE * WORK_PIXELS <= left <= SECOND_LOOK_SHARE * WORK_PIXELS
    assert second_look_pixels(inputs, grown, WORK_PIXELS, frame_share=0.75) < left
    # the whole frame: its crop's work and the points it may add leave no room
    assert second_look_pixels(inputs, Region(0, 1024, 0, 1024), WORK_PIXELS) == 0
    # a 2048 px frame its returns fill took its whole budget at the first look: none left
    big_gray, big_sparse = frame(2048, box=(0, 2048, 0, 2048))
    full = working_inputs(big_gray, big_sparse, 2000.0, 64)
    assert second_look_pixels(full, Region(0, 2048, 0, 2048), WORK_PIXELS) == 0
    gray[:, :] = 0  # a boom no longer than its returns: one look
    gray[480:540, 470:560] = 200
    calls = []
    assert complete(bright_model(calls), gray, sparse, FX, stride=64).beyond is None
    assert len(calls) == 1


def test_a_second_looks_part_joined_only_through_the_first_crop_is_vouched_for_again():
    """The second look (a coarser grid) joins a dim patch to the boom through pixels inside
    the first crop that the first look (a stricter model here) left off its mask; pasted
    beside the first look's answer there, the patch beyond the first crop is joined to nothing
    the returns vouch for, and is dropped with its depth."""
    gray, sparse = boom_past_the_returns()
    first = working_inputs(gray, sparse, FX, 64).grid.region
    x = first.x1 - 40  # a dim bridge down from the boom, past the first crop's bottom ...
    gray[540:580, x : x + 12] = 60
    gray[576:590, x : first.x1 + 60] = 60  # ... to a patch that goes on past its side
    dim = gray == 60
    dim[first.slices] = False  # the dim pixels the second look alone answers for

    def stricter_first(calls: list):
        def run(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
            calls.append(gray.shape)
            cut = 0.5 if len(calls) == 1 else 0.1  # the second look marks the dim pixels too
            return np.full_like(gray, 100.0), (gray > cut).astype(np.float32)

        return run

    result = complete(stricter_first([]), gray, sparse, FX, stride=64)
    assert result.beyond is not None and result.grid.region == first
    assert result.region.holds(*np.nonzero(dim)).all()
    assert not result.mask[dim].any() and not result.depth[dim].any()
    boom_beyond = np.zeros(gray.shape, bool)
    boom_beyond[480:540, first.x1 : result.region.x1] = True
    assert result.mask[boom_beyond].mean() > 0.95, "the boom beyond, joined to the returns, kept"
    # the second look alone marked the patch: through the bridge, it was joined to the boom
    h, w = result.beyond.grid.shape
    again = working_inputs(gray, sparse, FX, 64, h * w, region=result.region)
    alone = complete_on(stricter_first([None]), gray, sparse, again)
    assert alone.mask[dim].mean() > 0.9


def test_a_small_crop_is_enlarged_up_to_the_limit_and_answered_at_its_own_size():
    gray, sparse = frame(1024, spacing=(6, 6), box=(500, 530, 500, 540))
    calls = []
    result = complete(bright_model(calls), gray, sparse, FX, stride=64)
    ((shape, returns, _),) = calls
    scale = result.grid.scale
    assert scale[0] == pytest.approx(MAX_UPSAMPLE, rel=0.02) and shape[2] > result.region.shape[0]
    assert returns == np.count_nonzero(sparse), "every return kept once"
    assert abs(int(result.mask.sum()) - 30 * 40) < 0.1 * 30 * 40


def test_working_grid_fills_its_padded_input_with_frame_pixels():
    grid = working_grid(Region(100, 700, 200, 900), (1024, 1024), stride=64)
    h, w = grid.shape
    assert (-(-h // 64) * 64) * (-(-w // 64) * 64) <= WORK_PIXELS
    assert grid.region.shape[0] >= 600 and grid.region.shape[1] >= 700, "grown, not cut"
    assert grid.scale[0] == pytest.approx(grid.scale[1], rel=0.02)
    small = working_grid(Region(0, 300, 0, 300), (1024, 1024), stride=64, work_pixels=512 * 512)
    assert small.scale[0] > 1.5


def test_resample_sparse_keeps_returns_and_the_nearest_wins():
    sparse = np.zeros((8, 8), np.float32)
    sparse[0, 0], sparse[0, 1], sparse[5, 6] = 50.0, 40.0, 70.0
    small = resample_sparse(sparse, (4, 4))
    assert small[0, 0] == 40.0 and small[2, 3] == 70.0 and np.count_nonzero(small) == 2
    big = resample_sparse(sparse, (16, 16))
    assert sorted(big[big > 0]) == [40.0, 50.0, 70.0]


def test_resample_depth_interpolates_surfaces_but_never_between_two_of_them():
    depth = np.full((8, 8), 100.0, np.float32)
    depth[:, :4] += np.arange(4, dtype=np.float32) * 0.01  # a gentle slope
    depth[:, 4:] = 104.0  # a surface 4 m behind
    big = resample_depth(depth, (32, 32), footprint_m=0.01)
    values = np.unique(np.round(big, 3))
    assert not ((values > 100.1) & (values < 104.0)).any(), "no point between the surfaces"
    assert len(np.unique(big[:, :12])) > 4, "the slope is interpolated"


def test_the_edge_pixels_take_the_exact_nearest_source_pixel():
    depth = np.full((576, 384), 100.0, np.float32)
    depth[:, 192:] = 104.0 + np.arange(192, dtype=np.float32)  # behind, a step per column
    big = resample_depth(depth, (882, 588), footprint_m=0.01)
    cols = np.arange(588)
    on_edge = (cols >= 292) & (cols <= 300)  # around the step at 192 * 588 / 384 = 294
    expected = depth[0, (2 * cols + 1) * 384 // (2 * 588)]  # the pixel under each centre
    np.testing.assert_array_equal(big[0, on_edge], expected[on_edge])


@pytest.mark.parametrize("frame_cols", [125, 128, 301])
def test_a_shrunk_depth_is_the_one_under_each_pixels_centre(frame_cols):
    """A panel seen edge-on (0.33 m a frame pixel, as on a frame whose crop the working grid
    enlarged 2.5 times): the working grid's depth sampled at its pixel centres, pasted back to
    the frame, is the panel's depth at each frame pixel's centre within half a working pixel
    of slope; OpenCV's nearest, a pixel to the left, was off by up to 0.3 m."""
    slope, working_cols = 0.33, 318  # metres a frame pixel; the working grid's columns
    scale = working_cols / frame_cols
    centres = (np.arange(working_cols) + 0.5) / scale - 0.5  # in frame pixels
    depth = np.repeat((100.0 + slope * centres)[None, :].astype(np.float32), 4, axis=0)
    small = resample_depth(depth, (2, frame_cols), footprint_m=0.01)
    truth = 100.0 + slope * np.arange(frame_cols)
    assert np.abs(small[0] - truth).max() <= 0.5 * slope / scale + 1e-4


@pytest.mark.parametrize(
    ("shape", "footprint_m"), [((882, 588), 0.01), ((882, 588), float("inf")), ((300, 200), 0.01)]
)
def test_a_window_of_the_resampled_depth_is_that_window_of_the_whole_map(shape, footprint_m):
    rng = np.random.default_rng(0)
    depth = np.full((576, 384), 100.0, np.float32) + rng.random((576, 384), np.float32)
    depth[200:400, 100:300] = 104.0  # depth edges: their pixels take the nearest source pixel
    whole = resample_depth(depth, shape, footprint_m)
    for window in (Region(0, shape[0], 0, shape[1]), Region(10, 290, 33, 197), Region(5, 5, 0, 9)):
        np.testing.assert_array_equal(
            resample_depth(depth, shape, footprint_m, window), whole[window.slices]
        )


def test_the_mask_box_holds_every_pixel_and_its_margin_within_the_mask():
    mask = np.zeros((50, 60), bool)
    assert mask_box(mask, 3).shape == (0, 0)
    mask[10, 20] = mask[30, 58] = True
    assert mask_box(mask) == Region(10, 31, 20, 59)
    assert mask_box(mask, 2) == Region(8, 33, 18, 60)
    assert mask_box(mask).within(Region(100, 150, 7, 67)) == Region(110, 131, 27, 66)


def test_the_returns_spacing_comes_from_their_row_ends_in_any_order():
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, 500, 4000), rng.integers(0, 700, 4000)
    points = np.stack([cols, rows], 1).astype(np.float32)
    hull_area = cv2.contourArea(cv2.convexHull(points))
    assert cv2.contourArea(cv2.convexHull(row_ends(rows, cols))) == hull_area
    assert return_spacing(rows, cols) == pytest.approx(np.sqrt(hull_area / 4000))
    assert len(row_ends(rows, cols)) <= 2 * 500
    assert return_spacing(np.array([5, 5, 5]), np.array([1, 9, 30])) is None  # on one line


def test_only_components_the_returns_vouch_for_are_kept():
    mask = np.zeros((200, 200), bool)
    sparse = np.zeros((200, 200), np.float32)
    mask[50:90, 50:90] = True  # the body
    sparse[60, 60] = 100.0
    mask[95:97, 50:90] = True  # a boom 5 px from the body that no beam hit
    mask[150:153, 170:173] = True  # a star 60 px away
    mask[45, 45] = True  # a star of 1 px next to the body
    mask[120:126, 120:140] = True  # a part with a return of its own, apart from the body
    sparse[123, 130] = 90.0
    kept = drop_specks(mask, sparse, reach_px=1)
    assert kept[50:90, 50:90].all() and kept[120:126, 120:140].all()
    assert not kept[95:97, 50:90].any(), "no return vouches for it"
    assert not kept[150:153, 170:173].any() and not kept[45, 45]
    assert kept.sum() == 40 * 40 + 6 * 20
    edge_return = np.zeros_like(sparse)
    edge_return[49, 70] = 100.0  # a return one pixel outside the predicted outline
    assert drop_specks(mask, edge_return, 1)[50:90, 50:90].all()
    assert not drop_specks(mask, edge_return, 0).any(), "without reach it must lie on the mask"
    two_off = np.zeros_like(sparse)
    two_off[48, 70] = 100.0  # two pixels outside: beyond a reach of 1
    assert not drop_specks(mask, two_off, 1).any()
    assert not drop_specks(mask, np.zeros_like(sparse), 1).any()
    lone_return = np.zeros_like(sparse)
    lone_return[45, 45] = 100.0  # a 1 px component holding a return is the spacecraft
    assert drop_specks(mask, lone_return, 1)[45, 45]


def test_complete_drops_stars_from_the_mask_and_the_depth():
    gray, sparse = frame()
    gray[330:333, 250:253] = 255  # a star inside the crop, ~60 px from every return
    result = complete(bright_model([]), gray, sparse, FX, stride=64)
    assert result.region.y0 < 330 and result.region.x0 < 250
    assert not result.mask[328:335, 248:255].any() and (result.depth[328:335, 248:255] == 0).all()
    assert result.mask[420:580, 320:680].all()


def test_a_12_bit_frame_in_the_low_bits_is_answered_as_in_the_top_bits():
    """The stand-in network sees gray above half of full scale: a 12-bit camera's 3200 reads
    0.78 in a 16-bit image's top bits and 0.05 in its low bits, unless the pipeline moves it."""
    gray, sparse = frame()
    low_bits = gray.astype(np.uint16) * 16  # the spacecraft at 3200 of 4095
    low = complete(bright_model([]), low_bits, sparse, FX, stride=64)
    top = complete(bright_model([]), low_bits << 4, sparse, FX, stride=64)
    assert low.mask[420:580, 320:680].all()
    np.testing.assert_array_equal(low.mask, top.mask)
    np.testing.assert_array_equal(low.depth, top.depth)
    low_bits[0, 0] = 4096  # a pixel past 12 bits: a dark 16-bit frame, taken as it is
    assert not complete(bright_model([]), low_bits, sparse, FX, stride=64).mask.any()


def test_bad_focal_lengths_and_sizes_are_refused():
    gray, sparse = frame(256, box=(100, 150, 100, 150))
    for focal in (0.0, -5.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="focal_px"):
            complete(bright_model([]), gray, sparse, focal, stride=64)
    with pytest.raises(ValueError, match="differ"):
        complete(bright_model([]), gray, sparse[:-1], FX, stride=64)


def outline_case(dtype=np.uint8):
    """A bright panel with edges between the working grid's pixels, and a network's outline
    4 frame pixels too far out, on a grid shrunk to 0.4 (area-averaged), returns on it."""
    mask = np.zeros((500, 500), bool)
    mask[101:373, 57:311] = True
    top = np.iinfo(dtype).max
    gray = np.where(mask, int(0.8 * top), int(0.02 * top)).astype(dtype)
    shape = (200, 200)
    too_far = cv2.dilate(mask.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(np.float32)
    prob = resample_image(too_far, shape)
    gray_w = resample_image(gray.astype(np.float32) / top, shape)
    sparse_w = np.zeros(shape, np.float32)
    sparse_w[50:140:5, 30:120:5] = 80.0
    return mask, gray, prob, gray_w, sparse_w


def iou_of(answer: np.ndarray, mask: np.ndarray) -> float:
    return float(((answer > 0.5) & mask).sum() / ((answer > 0.5) | mask).sum())


def test_the_guided_paste_back_puts_the_outline_where_the_image_has_it():
    mask, gray, prob, gray_w, sparse_w = outline_case()
    guided = guided_probability(prob, gray_w, guide_gain(gray_w, sparse_w), gray)
    assert iou_of(resample_image(prob, mask.shape), mask) < 0.96
    assert iou_of(guided, mask) > 0.995
    _, gray16, *inputs16 = outline_case(np.uint16)  # a 16-bit frame is guided alike
    prob16, gray_w16, sparse_w16 = inputs16
    guided16 = guided_probability(prob16, gray_w16, guide_gain(gray_w16, sparse_w16), gray16)
    np.testing.assert_allclose(guided16, guided, atol=1e-3)


def test_the_guided_paste_back_keeps_the_networks_outline_where_the_image_is_flat():
    _, _, prob, gray_w, sparse_w = outline_case()
    flat = np.full((500, 500), 120, np.uint8)
    flat_w = np.full_like(gray_w, 120 / 255)
    guided = guided_probability(prob, flat_w, guide_gain(flat_w, sparse_w), flat)
    assert iou_of(guided, resample_image(prob, flat.shape) > 0.5) > 0.99


def test_a_shrunk_crop_gets_its_outline_from_the_image_and_no_star_beside_it():
    """A 2048 px frame whose panel's crop the budget shrinks: the pasted-back mask follows the
    image's outline to the frame's pixel, and a star 3 px off the outline, which the image
    would guide into the mask, is left out (no return on it)."""
    gray, sparse = frame(size=2048, spacing=(9, 9), box=(601, 1399, 503, 1497))
    gray[1402, 900] = 255  # a star beside the panel's bottom edge
    result = complete(bright_model([]), gray, sparse, FX, stride=64)
    assert result.grid.scale[0] < 0.6
    truth = gray == 200
    iou = (result.mask & truth).sum() / (result.mask | truth).sum()
    assert iou > 0.999 and not result.mask[1402, 900]
    assert np.array_equal(result.probability > 0.5, result.mask)


@pytest.mark.parametrize("specks", [40, 400])  # an 8-bit lookup up to 256 components, else not
def test_drop_specks_keeps_exactly_the_components_a_return_lies_on(specks):
    rng = np.random.default_rng(specks)
    mask = np.zeros((200, 200), bool)
    spots = rng.choice(100 * 100, specks, replace=False)
    rows, cols = 2 * (spots // 100), 2 * (spots % 100)  # isolated pixels, 8-connected apart
    mask[rows, cols] = True
    sparse = np.zeros(mask.shape, np.float32)
    hit = rng.random(specks) < 0.5
    sparse[rows[hit], cols[hit]] = 30.0
    expected = np.zeros_like(mask)
    expected[rows[hit], cols[hit]] = True
    assert np.array_equal(drop_specks(mask, sparse, reach_px=0), expected)


@pytest.mark.parametrize(
    "source, shape, window",
    [
        ((23, 17), (80, 50), Region(3, 77, 0, 50)),  # enlarged, a window
        ((40, 31), (40, 31), None),  # the same grid
        ((90, 70), (31, 29), Region(5, 6, 0, 29)),  # shrunk, one row
        ((7, 300), (700, 2048), Region(0, 700, 1000, 1999)),  # enlarged unevenly
    ],
)
def test_nearest_resampled_takes_the_source_pixel_under_each_pixels_centre(source, shape, window):
    image = np.arange(source[0] * source[1], dtype=np.float32).reshape(source)
    out = nearest_resampled(image, shape, window)
    w = Region(0, shape[0], 0, shape[1]) if window is None else window
    rows = source_indices(w.y0, w.y1, shape[0], source[0])
    cols = source_indices(w.x0, w.x1, shape[1], source[1])
    assert np.array_equal(out, image[rows[:, None], cols[None, :]])
    assert np.array_equal(out, nearest_resampled(image, shape)[w.slices])
    assert np.array_equal(rows, np.floor((np.arange(w.y0, w.y1) + 0.5) * source[0] / shape[0]))


@pytest.mark.parametrize("specks", [40, 400])  # both ways of keeping the vouched components
@pytest.mark.parametrize("reach", [0, 1, 2])
def test_drop_specks_keeps_the_components_within_reach_of_a_return(specks, reach):
    """Blobs of one to a few pixels and two large parts; returns on some, beside others (up to
    3 px off): the kept pixels are those of every component whose pixels come within ``reach``
    (Chebyshev) of a return, found here label by label."""
    rng = np.random.default_rng(specks + reach)
    mask = np.zeros((240, 240), bool)
    mask[10:60, 10:200] = True  # a panel
    mask[100:230, 90:110] = True  # a boom
    for y, x in zip(rng.integers(0, 236, specks), rng.integers(0, 236, specks), strict=True):
        mask[y : y + rng.integers(1, 4), x : x + rng.integers(1, 4)] = True
    sparse = np.zeros(mask.shape, np.float32)
    ys, xs = np.nonzero(mask)
    pick = rng.choice(len(ys), specks // 4, replace=False)
    offsets = rng.integers(-3, 4, (len(pick), 2))
    at_y = np.clip(ys[pick] + offsets[:, 0], 0, 239)
    at_x = np.clip(xs[pick] + offsets[:, 1], 0, 239)
    sparse[at_y, at_x] = 40.0
    count, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    assert (count > 257) == (specks == 400)
    reached = cv2.dilate((sparse > 0).astype(np.uint8), np.ones((2 * reach + 1,) * 2, np.uint8))
    vouched = {label for label in np.unique(labels[reached > 0]) if label > 0}
    expected = np.isin(labels, list(vouched))
    assert 0 < expected.sum() < mask.sum()
    assert np.array_equal(drop_specks(mask, sparse, reach), expected)


def test_returns_beside_the_mask_are_joined_to_it_and_no_other():
    """A return one pixel off the mask (a truss member whose pixel the mask missed, beside the
    fragment it vouched for) joins the mask, with a probability just over the threshold; a
    return two pixels off, or on the mask already, changes nothing."""
    mask = np.zeros((60, 60), bool)
    mask[20:30, 20:30] = True  # a part
    mask[40, 40] = True  # a fragment of one pixel beside a return
    sparse = np.zeros(mask.shape, np.float32)
    sparse[41, 41] = 9.0  # diagonal to the fragment: within reach
    sparse[25, 30] = 9.0  # beside the part's right edge
    sparse[25, 25] = 9.0  # on the part
    sparse[10, 25] = 9.0  # ten pixels above the part: beyond reach
    sparse[20, 31] = 9.0  # two pixels off: beyond reach
    mask[58, 58] = True
    sparse[59, 59] = 9.0  # in the crop's corner, diagonal to the mask
    mask[0, 57] = True
    sparse[0, 59] = 9.0  # on the crop's top edge, two pixels off
    prob = np.where(mask, np.float32(0.9), np.float32(0.2))
    before = mask.copy()
    join_returns_beside(mask, prob, *np.nonzero(sparse), 0.5)
    assert mask[41, 41] and mask[25, 30] and mask[59, 59]
    assert (mask ^ before).sum() == 3
    assert np.array_equal(prob > 0.5, mask)
    assert 0.5 < prob[41, 41] < 0.5001
    empty, low = np.zeros_like(mask), np.zeros_like(prob)
    join_returns_beside(empty, low, *np.nonzero(sparse), 0.5)
    assert not empty.any() and not low.any()


def test_complete_joins_a_return_its_mask_missed_by_a_pixel():
    """A return one pixel past the panel's outline, which the stand-in network's mask leaves
    out: the answer holds the return, with the depth beside it, and the probability agrees
    with the mask."""
    gray, sparse = frame()
    sparse[600, 500] = 120.0  # the panel's last row is 599
    result = complete(bright_model([]), gray, sparse, FX, stride=64)
    assert result.mask[600, 500] and not result.mask[600, 499] and not result.mask[601, 500]
    assert result.depth[600, 500] > 0
    assert np.array_equal(result.probability > 0.5, result.mask)


@pytest.mark.parametrize("specks", [40, 400])
def test_the_crop_is_vouched_for_within_its_mask_box_as_a_whole(specks):
    """The frame-resolution vouching searches only the window around the mask: the same
    components kept as ``drop_specks`` over the whole crop, returns just outside the mask's
    box (within reach) included, and the probability of the dropped pixels set to 0."""
    rng = np.random.default_rng(specks)
    prob = np.zeros((300, 400), np.float32)
    spots = rng.choice(60 * 80, specks, replace=False)
    rows, cols = 50 + 3 * (spots // 80), 80 + 3 * (spots % 80)
    prob[rows, cols] = 0.9
    prob[100:150, 150:250] = 0.8  # the body
    sparse = np.zeros(prob.shape, np.float32)
    sparse[120, 200] = 100.0
    hit = rng.random(specks) < 0.3
    sparse[rows[hit] - 1, cols[hit]] = 90.0  # a return 1 px off a speck: within reach
    prob[40, 60] = 0.9  # the mask box's corner: a speck vouched for from outside the box
    sparse[39, 60] = 80.0
    expected = drop_specks(prob > 0.5, sparse, RETURN_REACH_PX)
    vouched = prob.copy()
    mask = vouched_mask(vouched, sparse, 0.5)
    assert np.array_equal(mask, expected) and 0 < mask.sum() < (prob > 0.5).sum()
    np.testing.assert_array_equal(vouched, np.where(mask | (prob <= 0.5), prob, 0))
