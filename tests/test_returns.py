"""LIDAR returns as a row,col,z_m list (``sdcnet.returns``), ``sdc-client infer`` reading it,
and the compact answer layouts (``sdcnet.compact``): exact round trips, the nearest-wins rule,
and a clear error for every invalid list."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from sdcnet.client.cli import main as client_main
from sdcnet.compact import (
    crop,
    depth_from_fp16,
    fp16_residuals,
    mask_window,
    pack_mask,
    paste,
    unpack_mask,
)
from sdcnet.pipeline import resample_sparse
from sdcnet.returns import (
    ReturnsError,
    dense_from_returns,
    parse_returns_csv,
    read_returns_csv,
    returns_from_dense,
    write_returns_csv,
)
from tests.support.frames import synthetic_frame


def test_a_dense_map_round_trips_through_the_csv_to_the_millimetre(tmp_path):
    sparse = synthetic_frame(256).sparse
    write_returns_csv(tmp_path / "r.csv", returns_from_dense(sparse))
    returns = read_returns_csv(tmp_path / "r.csv")
    assert returns.dtype == np.float32 and returns.shape == (np.count_nonzero(sparse), 3)
    assert (tmp_path / "r.csv").read_text().splitlines()[0] == "row,col,z_m"
    dense = dense_from_returns(returns, sparse.shape)
    np.testing.assert_array_equal(dense > 0, sparse > 0)
    assert np.abs(dense - sparse).max() <= 0.0005 + 1e-4  # Z written to the millimetre


def test_the_nearest_return_wins_a_pixel_and_blank_lines_are_skipped(tmp_path):
    (tmp_path / "r.csv").write_text("row,col,z_m\n1,2,120.5\n\n1,2,119.25\n0,0,80\n")
    dense = dense_from_returns(read_returns_csv(tmp_path / "r.csv"), (3, 4))
    expected = np.zeros((3, 4), np.float32)
    expected[1, 2], expected[0, 0] = 119.25, 80.0
    np.testing.assert_array_equal(dense, expected)


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "the first line must be the header row,col,z_m"),
        ("x,y,z\n1,2,3\n", "the first line must be the header row,col,z_m"),
        ("row,col,z_m\n1,2\n", "line 2: expected row,col,z_m numbers, got '1,2' (2 values)"),
        ("row,col,z_m\n1,2,3\n1,two,3\n", "line 3: expected row,col,z_m numbers, got '1,two,3'"),
        ("row,col,z_m\n1,2,nan\n", "returns must be finite numbers; return 0"),
        ("row,col,z_m\n1,2,3\n4,5,-1\n", "z_m must be > 0 (metres); return 1 has -1.0"),
        ("row,col,z_m\n1.5,2,3\n", "row and col must be pixel indices (whole, >= 0); return 0"),
        ("row,col,z_m\n-1,2,3\n", "row and col must be pixel indices (whole, >= 0); return 0"),
    ],
)
def test_a_bad_file_is_a_clear_error(tmp_path, text, message):
    (tmp_path / "r.csv").write_text(text)
    with pytest.raises(ValueError) as raised:
        read_returns_csv(tmp_path / "r.csv")
    assert str(raised.value).startswith(str(tmp_path / "r.csv"))
    assert message in str(raised.value)


def test_returns_outside_the_image_are_refused():
    with pytest.raises(ValueError, match="return 1 at row 3, col 0 is outside the 4 x 3 image"):
        dense_from_returns(np.array([[0, 0, 10], [3, 0, 10]], np.float32), (3, 4))


def test_sdc_client_says_what_is_wrong_with_a_returns_file_in_one_line(tmp_path, capsys):
    gray = tmp_path / "gray.png"
    cv2.imwrite(str(gray), synthetic_frame(64).gray)
    (tmp_path / "r.returns.csv").write_text("row,col,z_m\n64,0,100\n")
    url = "http://127.0.0.1:9"  # never reached: the file is refused first
    argv = ["infer", str(gray), str(tmp_path / "r.returns.csv"), "--url", url]
    assert client_main(argv) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"sdc-client: error: {tmp_path / 'r.returns.csv'}: return 0 at row 64, col 0 is outside "
        "the 64 x 64 image"
    ]
    assert client_main(["infer", str(gray), str(tmp_path / "none.csv"), "--url", url]) == 2
    assert "LIDAR returns file not found" in capsys.readouterr().err


def test_dense_and_list_convert_exactly_both_ways():
    sparse = synthetic_frame(256).sparse
    returns = returns_from_dense(sparse)
    assert returns.dtype == np.float32 and returns.shape == (np.count_nonzero(sparse), 3)
    np.testing.assert_array_equal(dense_from_returns(returns, sparse.shape), sparse)
    # float64 maps convert to the float32 the service uses
    np.testing.assert_array_equal(
        dense_from_returns(returns_from_dense(sparse.astype(np.float64)), sparse.shape), sparse
    )


@pytest.mark.parametrize(
    "layout",
    ["float32", "float64", "float16", "big-endian", "strided view", "transposed"],
)
def test_a_dense_maps_returns_are_listed_row_major_whatever_its_layout(layout):
    """The list is the map's nonzero pixels in row-major order (OpenCV's scan, as the pipeline
    finds them), for every float map a client may hold."""
    rng = np.random.default_rng(3)
    sparse = np.where(rng.random((48, 64)) < 0.05, 1.0 + 99.0 * rng.random((48, 64)), 0.0)
    maps = {
        "float32": sparse.astype(np.float32),
        "float64": sparse,
        "float16": sparse.astype(np.float16),
        "big-endian": sparse.astype(">f4"),
        "strided view": np.repeat(sparse.astype(np.float32), 2, axis=1)[:, ::2],
        "transposed": sparse.astype(np.float32).T,
    }
    given = maps[layout]
    returns = returns_from_dense(given)
    rows, cols = np.nonzero(given)
    np.testing.assert_array_equal(returns[:, 0], rows)
    np.testing.assert_array_equal(returns[:, 1], cols)
    np.testing.assert_array_equal(returns[:, 2], given[rows, cols].astype(np.float32))


def test_the_nearest_return_wins_a_pixel_as_when_resampling():
    returns = np.array([[3, 4, 120.0], [3, 4, 80.5], [0, 0, 90.0], [3, 4, 95.0]], np.float32)
    dense = dense_from_returns(returns, (8, 8))
    assert dense[3, 4] == np.float32(80.5) and dense[0, 0] == 90.0
    assert np.count_nonzero(dense) == 2
    # the same rule as sdcnet.pipeline.resample_sparse: two returns meeting on one pixel
    fine = np.zeros((8, 8), np.float32)
    fine[2, 2], fine[3, 3] = 100.0, 99.0
    assert resample_sparse(fine, (4, 4))[1, 1] == np.float32(99.0)


def test_csv_round_trips_the_same_float32_values(tmp_path):
    returns = returns_from_dense(synthetic_frame(256).sparse)
    path = tmp_path / "returns.csv"
    write_returns_csv(path, returns)
    assert path.read_text().startswith("row,col,z_m\n")
    np.testing.assert_array_equal(read_returns_csv(path), returns)
    with_spaces = "\ufeffrow, col, z_m\n1, 2, 100.5\n\n3,4,7\n"  # BOM, spaces, a blank line
    np.testing.assert_array_equal(
        parse_returns_csv(with_spaces), np.array([[1, 2, 100.5], [3, 4, 7]], np.float32)
    )


@pytest.mark.parametrize(
    ("returns", "code", "message"),
    [
        (np.zeros((4, 2), np.float32), "wrong_shape", "must be (N, 3)"),
        (np.zeros((4, 3), np.int32), "wrong_dtype", "float32 or float64"),
        (np.zeros((0, 3), np.float32), "no_returns", "no LIDAR return"),
        (np.array([[1, 1, np.nan]], np.float32), "invalid_depth", "finite numbers; return 0"),
        (np.array([[1, np.inf, 5]], np.float32), "invalid_depth", "finite numbers; return 0"),
        (np.array([[1, 1, 5], [1, 1, 0]], np.float32), "invalid_depth", "return 1 has 0.0"),
        (np.array([[1, 1, -3]], np.float32), "invalid_depth", "z_m must be > 0"),
        (np.array([[1, 1, 3], [2, 2, 1e30]], np.float32), "invalid_depth", "return 1 has 1e+30"),
        (np.array([[1.5, 1, 3]], np.float32), "invalid_returns", "(whole, >= 0); return 0"),
        (np.array([[-1, 1, 3]], np.float32), "invalid_returns", "(whole, >= 0); return 0"),
        (np.array([[8, 1, 3]], np.float32), "invalid_returns", "outside the 8 x 8 image"),
        (np.array([[1, 8, 3]], np.float32), "invalid_returns", "outside the 8 x 8 image"),
        (np.ones((65, 3), np.float32), "invalid_returns", "at most one per pixel"),
    ],
)
def test_invalid_returns_are_named(returns, code, message):
    with pytest.raises(ReturnsError, match=re.escape(message)) as raised:
        dense_from_returns(returns, (8, 8))
    assert raised.value.code == code


@pytest.mark.parametrize(
    ("text", "code"),
    [
        ("r,c,z\n1,2,3\n", "invalid_returns"),
        ("row,col,z_m\n", "no_returns"),
        ("row,col,z_m\n1,2\n", "invalid_returns"),
        ("row,col,z_m\n1,2,x\n", "invalid_returns"),
        ("row,col,z_m\n1,2,-3\n", "invalid_depth"),
        ("row,col,z_m\n1.5,2,3\n", "invalid_returns"),
    ],
)
def test_a_bad_csv_gets_the_code_the_service_answers_with(text, code):
    with pytest.raises(ReturnsError) as raised:
        parse_returns_csv(text, "upload")
    assert raised.value.code == code and str(raised.value).startswith("upload: ")


def test_a_dense_map_with_bad_depths_is_refused():
    sparse = np.zeros((4, 4), np.float32)
    sparse[1, 1] = np.nan
    with pytest.raises(ReturnsError, match="NaN"):
        returns_from_dense(sparse)
    sparse[1, 1] = -2
    with pytest.raises(ReturnsError, match="negative"):
        returns_from_dense(sparse)
    sparse[1, 1] = 2e5
    with pytest.raises(ReturnsError, match="1 depths beyond 100000 m"):
        returns_from_dense(sparse)


def test_region_and_bits_round_trip_exactly():
    rng = np.random.default_rng(0)
    depth = np.zeros((37, 53), np.float32)
    depth[5:20, 9:40] = rng.uniform(50, 250, (15, 31)).astype(np.float32)
    mask = depth > 0
    assert mask_window(mask) == (5, 9, 15, 31)
    assert mask_window(mask[2:, 3:], 2, 3) == (5, 9, 15, 31)  # a part of the frame, offset
    window = crop(depth, *mask_window(mask))
    np.testing.assert_array_equal(paste(window, 5, 9, depth.shape), depth)
    empty = mask_window(np.zeros((6, 6), bool), 2, 3)  # nothing: an empty window
    assert empty == (2, 3, 0, 0)
    nothing = unpack_mask(pack_mask(np.zeros((0, 0), bool)), (0, 0))
    np.testing.assert_array_equal(paste(nothing, 2, 3, (6, 6)), np.zeros((6, 6), bool))
    for shape in ((15, 31), (1, 1), (8, 8), (3, 5)):  # byte counts with and without padding
        m = rng.random(shape) > 0.5
        np.testing.assert_array_equal(unpack_mask(pack_mask(m), shape), m)
    bits = pack_mask(crop(mask, 5, 9, 15, 31))
    np.testing.assert_array_equal(paste(unpack_mask(bits, (15, 31)), 5, 9, mask.shape), mask)
    with pytest.raises(ValueError, match="cannot hold"):
        unpack_mask(bits[:-1], (15, 31))
    with pytest.raises(ValueError, match="does not fit"):
        paste(window, 30, 9, depth.shape)


def test_fp16_depth_comes_back_within_8_mm_and_zero_stays_zero():
    rng = np.random.default_rng(1)
    depth = np.zeros((64, 64), np.float32)
    depth[10:50, 10:50] = rng.uniform(180.0, 211.0, (40, 40)).astype(np.float32)  # 31 m deep
    residuals, offset = fp16_residuals(depth)
    assert residuals.dtype == np.float16 and offset == pytest.approx(depth[depth > 0].min())
    back = depth_from_fp16(residuals, offset)
    assert back.dtype == np.float32
    np.testing.assert_array_equal(back == 0, depth == 0)
    assert np.abs(back - depth).max() <= 0.008
    empty, zero = fp16_residuals(np.zeros((4, 4), np.float32))
    np.testing.assert_array_equal(depth_from_fp16(empty, zero), np.zeros((4, 4), np.float32))
