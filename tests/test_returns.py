"""LIDAR returns as a row,col,z_m list (``sdcnet.returns``) and ``sdc-client infer`` reading it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sdcnet.client.cli import main as client_main
from sdcnet.devtools.frames import synthetic_frame
from sdcnet.returns import dense_from_returns, read_returns_csv, returns_of, write_returns_csv


def test_a_dense_map_round_trips_through_the_csv_to_the_millimetre(tmp_path):
    sparse = synthetic_frame(256).sparse
    write_returns_csv(tmp_path / "r.csv", returns_of(sparse))
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
