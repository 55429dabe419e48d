"""Camera files (``sdcnet.calibration``): every form calibration tools write, read to the same
camera; bad files refused in one clear line; lens distortion removed from images and LIDAR
returns alike."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from sdcnet.calibration import CalibrationError, CameraCalibration, Undistorter, load_camera_file
from sdcnet.camera import Intrinsics

K = Intrinsics(1000.0, 1001.5, 511.5, 383.5, 1024, 768)
D = (-0.2, 0.05, 0.001, -0.0005, 0.01)

#: OpenCV's calibration sample (samples/cpp/tutorial_code/calib3d/camera_calibration), as
#: OpenCV 4 writes it: the YAML 1.0 header, opencv-matrix tags, doubles in %.16e.
OPENCV_YAML = """%YAML:1.0
---
calibration_time: "Tue 02 Dec 2025 10:00:00 CET"
nr_of_frames: 25
image_width: 1024
image_height: 768
board_width: 9
board_height: 6
square_size: 25.
fix_aspect_ratio: 1.
flags: 2
fisheye_model: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 1.0000000000000000e+03, 0., 5.1150000000000000e+02, 0.,
       1.0015000000000000e+03, 3.8350000000000000e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -2.0000000000000001e-01, 5.0000000000000003e-02,
       1.0000000000000000e-03, -5.0000000000000001e-04,
       1.0000000000000000e-02 ]
avg_reprojection_error: 2.5000000000000000e-01
"""

#: camera_calibration's ost.yaml (camera_info_manager's format).
ROS_CAMERA_INFO = """image_width: 1024
image_height: 768
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [1000, 0, 511.5, 0, 1001.5, 383.5, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.2, 0.05, 0.001, -0.0005, 0.01]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [950, 0, 511.5, 0, 0, 960, 383.5, 0, 0, 0, 1, 0]
"""

#: `ros2 topic echo --once /camera_info` (sensor_msgs/msg/CameraInfo).
ROS2_CAMERA_INFO = """header:
  stamp:
    sec: 1764669600
    nanosec: 0
  frame_id: camera_optical_frame
height: 768
width: 1024
distortion_model: plumb_bob
d:
- -0.2
- 0.05
- 0.001
- -0.0005
- 0.01
k:
- 1000.0
- 0.0
- 511.5
- 0.0
- 1001.5
- 383.5
- 0.0
- 0.0
- 1.0
r:
- 1.0
- 0.0
- 0.0
- 0.0
- 1.0
- 0.0
- 0.0
- 0.0
- 1.0
p:
- 950.0
- 0.0
- 511.5
- 0.0
- 0.0
- 960.0
- 383.5
- 0.0
- 0.0
- 0.0
- 1.0
- 0.0
binning_x: 0
binning_y: 0
roi:
  x_offset: 0
  y_offset: 0
  height: 0
  width: 0
  do_rectify: false
---
"""

#: `rostopic echo -n 1 /camera_info` (ROS 1 sensor_msgs/CameraInfo: uppercase D, K, R, P).
ROS1_CAMERA_INFO = """header:
  seq: 42
  stamp:
    secs: 1764669600
    nsecs: 0
  frame_id: "camera_optical_frame"
height: 768
width: 1024
distortion_model: "plumb_bob"
D: [-0.2, 0.05, 0.001, -0.0005, 0.01]
K: [1000.0, 0.0, 511.5, 0.0, 1001.5, 383.5, 0.0, 0.0, 1.0]
R: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
P: [950.0, 0.0, 511.5, 0.0, 0.0, 960.0, 383.5, 0.0, 0.0, 0.0, 1.0, 0.0]
binning_x: 0
binning_y: 0
roi:
  x_offset: 0
  y_offset: 0
  height: 0
  width: 0
  do_rectify: False
---
"""

PLAIN_JSON = json.dumps(
    {"fx": 1000, "fy": 1001.5, "cx": 511.5, "cy": 383.5, "width": 1024, "height": 768}
    | {"distortion": list(D)}
)


#: A small valid plain camera, and its size alone, for the bad files below.
SIZE = {"width": 200, "height": 200}
GOOD = {"fx": 900, "fy": 900, "cx": 99.5, "cy": 99.5} | SIZE


def written_by_filestorage(path, ext: str):
    """The camera as cv2.FileStorage itself writes it (the format follows ``ext``), saved
    under ``path`` (whose name says nothing of the format)."""
    written = path.with_name(f"written{ext}")
    storage = cv2.FileStorage(str(written), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", K.width)
    storage.write("image_height", K.height)
    storage.write("camera_matrix", K.matrix())
    storage.write("distortion_coefficients", np.array([D]).T)
    storage.write("avg_reprojection_error", 0.25)
    storage.release()
    written.rename(path)


FORMS = {
    "opencv_yaml": (OPENCV_YAML, "OpenCV YAML"),
    "opencv_json": (".json", "OpenCV JSON"),
    "opencv_xml": (".xml", "OpenCV XML"),
    "ros_camera_info": (ROS_CAMERA_INFO, "ROS camera_info YAML"),
    "ros2_camera_info": (ROS2_CAMERA_INFO, "ROS CameraInfo YAML"),
    "ros1_camera_info": (ROS1_CAMERA_INFO, "ROS CameraInfo YAML"),
    "plain_json": (PLAIN_JSON, "plain JSON"),
}


@pytest.mark.parametrize("form", sorted(FORMS))
def test_every_form_reads_to_the_same_camera(form, tmp_path):
    content, name = FORMS[form]
    path = tmp_path / "camera.cal"  # recognised by content, not by extension
    if content.startswith("."):
        written_by_filestorage(path, content)
    else:
        path.write_text(content)
    calibration = load_camera_file(path)
    assert calibration.intrinsics == K
    assert calibration.distortion == pytest.approx(D, abs=1e-15)
    assert calibration.model == "plumb_bob"
    assert calibration.source == f"camera.cal ({name})"
    assert calibration.describe() == {
        "source": calibration.source,
        "model": "plumb_bob",
        "intrinsics": K.as_dict(),
        "distortion": list(calibration.distortion),
    }


def test_distortion_models(tmp_path):
    path = tmp_path / "camera.yaml"
    rational = ROS_CAMERA_INFO.replace("plumb_bob", "rational_polynomial").replace(
        "cols: 5\n  data: [-0.2, 0.05, 0.001, -0.0005, 0.01]",
        "cols: 8\n  data: [-0.2, 0.05, 0.001, -0.0005, 0.01, 0.1, 0.02, 0.003]",
    )
    path.write_text(rational)
    calibration = load_camera_file(path)
    assert calibration.model == "rational_polynomial" and len(calibration.distortion) == 8

    path.write_text(json.dumps(GOOD))
    assert load_camera_file(path).distortion == () and load_camera_file(path).model == "pinhole"
    path.write_text(
        json.dumps({"k": list(K.matrix().ravel()), "d": [0.0] * 5, "width": 1024, "height": 768})
    )
    zeros = load_camera_file(path)  # a rectified camera's info: plumb_bob, all zero
    assert zeros.distortion == () and zeros.model == "pinhole"
    assert zeros.source == "camera.yaml (ROS CameraInfo JSON)"


BAD_FILES = {
    "binary": (b"\x89PNG\r\n\x1a\n\x00\x00", "is not a text file"),
    "broken_json": ('{"fx": 900, "fy": 900,\n "cx" 99.5}', "is not valid JSON (line 2, column"),
    "broken_yaml": ("image_width: 1024\ncamera_matrix: [1, 2\n", "nor valid YAML (line 3"),
    "broken_opencv_yaml": (OPENCV_YAML.split("0., 0., 1. ]")[0], "not valid OpenCV YAML"),
    "a_list": ("- 1\n- 2\n", "holds no calibration fields"),
    "empty": ("", "holds no calibration fields"),
    "no_size": ({"fx": 900, "fy": 900, "cx": 99.5, "cy": 99.5}, "does not give the image size"),
    "fractional_width": (GOOD | {"width": 199.5}, "width must be a whole number of pixels"),
    "no_matrix": (SIZE | {"fx": 900}, "has no camera matrix"),
    "text_focal": (GOOD | {"fx": "900"}, "fx must be a finite number, got '900'"),
    "nan_focal": (GOOD | {"fy": float("nan")}, "fy must be a finite number"),
    "negative_focal": (GOOD | {"fx": -900}, "focal lengths must be positive"),
    "zero_focal": (GOOD | {"fy": 0}, "focal lengths must be positive"),
    "far_principal_point": (GOOD | {"cx": 900, "cy": 99.5}, "lies far outside the 200 x 200"),
    "projection_as_matrix": (
        SIZE | {"camera_matrix": {"rows": 3, "cols": 4, "data": list(range(12))}},
        "camera_matrix is 3 x 4; a camera matrix is 3 x 3",
    ),
    "short_matrix": (SIZE | {"k": [900, 0, 99.5, 0, 900, 99.5]}, "k is 6; a camera matrix"),
    "rows_cols_mismatch": (
        SIZE | {"camera_matrix": {"rows": 3, "cols": 3, "data": [900, 0, 99.5]}},
        "camera_matrix declares 3 x 3 values but holds 3",
    ),
    "infinite_matrix": (SIZE | {"K": [np.inf, 0, 99.5, 0, 900, 99.5, 0, 0, 1]}, "not finite"),
    "not_a_camera_matrix": (SIZE | {"K": [900, 0, 99.5, 0, 900, 99.5, 1, 0, 1]}, "not a camera"),
    "skew": (SIZE | {"K": [900, 3, 99.5, 0, 900, 99.5, 0, 0, 1]}, "skew of 3"),
    "fisheye": (
        GOOD | {"distortion_model": "equidistant", "d": [0.1, 0.01, 0, 0]},
        "equidistant (fisheye) distortion model, which sdcnet does not support",
    ),
    "opencv_fisheye": (OPENCV_YAML.replace("fisheye_model: 0", "fisheye_model: 1"), "fisheye"),
    "unknown_model": (
        GOOD | {"distortion_model": "kb8", "d": [0.1]},
        "unsupported distortion model 'kb8'; supported: pinhole, plumb_bob, rational_polynomial",
    ),
    "model_and_count_disagree": (
        GOOD | {"distortion_model": "plumb_bob", "d": [0.1] * 8},
        "8 distortion coefficients do not fit plumb_bob",
    ),
    "odd_count": (GOOD | {"distortion": [0.1] * 6}, "6 distortion coefficients do not fit any"),
    "distortion_matrix": (
        GOOD | {"distortion": [[0.1, 0.2], [0.3, 0.4]]},
        "distortion is 2 x 2, not a vector",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_bad_files_are_refused_in_one_clear_line(case, tmp_path):
    content, expected = BAD_FILES[case]
    path = tmp_path / "camera.yaml"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
    with pytest.raises(CalibrationError) as caught:
        load_camera_file(path)
    message = str(caught.value)
    assert message.startswith(f"camera file {path}: "), message
    assert expected in message, message
    assert "\n" not in message and "OpenCV(" not in message and "Traceback" not in message


def test_missing_files_and_folders(tmp_path):
    with pytest.raises(CalibrationError, match=r"^camera file not found: .*none\.yaml$"):
        load_camera_file(tmp_path / "none.yaml")
    with pytest.raises(CalibrationError, match="is a directory, not a calibration file"):
        load_camera_file(tmp_path)


def test_a_frame_of_another_size_scales_the_camera_at_its_aspect_ratio_only():
    calibration = CameraCalibration(K, D, "plumb_bob", "camera.yaml (OpenCV YAML)")
    assert calibration.at_size(1024, 768) is calibration
    half = calibration.at_size(512, 384)
    assert half.intrinsics == K.scaled(512, 384) and half.distortion == D
    assert half.intrinsics.cx == pytest.approx(255.5)  # the centre stays the centre
    assert calibration.at_size(1030, 768).intrinsics == K.scaled(1030, 768)  # 0.6 % off
    with pytest.raises(CalibrationError, match=r"1024 x 1024 pixels, not of the aspect ratio"):
        calibration.at_size(1024, 1024)


# -- undistortion ------------------------------------------------------------------------

#: A strong barrel lens on a 640 x 480 sensor: 20 px of distortion near the edges.
LENS = CameraCalibration(
    Intrinsics(500.0, 520.0, 322.0, 236.5, 640, 480), (-0.3, 0.1, 0.002, -0.001, 0.0), "plumb_bob"
)
#: Normalised image coordinates (y = Y / Z) of the horizontal lines drawn.
LINES = (-0.35, -0.15, 0.05, 0.25)


def distorted_lines(calibration: CameraCalibration, transpose: bool = False) -> np.ndarray:
    """The image the lens makes of straight lines y = c (x = c if ``transpose``) on the plane
    Z = 1: points along each line projected with the distortion (cv2.projectPoints) and drawn
    as an antialiased polyline, 3 px wide."""
    K = calibration.intrinsics
    image = np.zeros((K.height, K.width), np.uint8)
    along = np.linspace(-1.2, 1.2, 4000)
    for c in LINES:
        x, y = (np.full_like(along, c), along) if transpose else (along, np.full_like(along, c))
        points = np.stack([x, y, np.ones_like(along)], axis=-1)
        pixels, _ = cv2.projectPoints(
            points, np.zeros(3), np.zeros(3), K.matrix(), np.array(calibration.distortion)
        )
        curve = np.round(pixels.reshape(-1, 1, 2) * 16).astype(np.int32)
        cv2.polylines(image, [curve], False, 255, 3, cv2.LINE_AA, shift=4)
    return image


def worst_offset(image: np.ndarray, rows: list[float], columns: slice) -> float:
    """Largest distance (pixels) between a drawn line's centre (its intensity-weighted row in
    a band of +-8 px, per column; infinite where the line leaves the band) and the row where
    a pinhole camera sees it."""
    worst = 0.0
    for row in rows:
        band = np.arange(round(row) - 8, round(row) + 9)
        weights = image[band, columns].astype(np.float64)
        total = weights.sum(axis=0)
        centre = (band[:, None] * weights).sum(axis=0) / np.where(total > 0, total, np.nan)
        worst = max(worst, float(np.nan_to_num(np.abs(centre - row), nan=np.inf).max()))
    return worst


@pytest.mark.parametrize("transpose", [False, True], ids=["horizontal", "vertical"])
def test_straight_lines_come_out_straight(transpose):
    K = LENS.intrinsics
    undistorted = Undistorter(LENS).image(distorted_lines(LENS, transpose))
    distorted = distorted_lines(LENS, transpose)
    if transpose:  # vertical lines x = c, at u = fx c + cx: the same check on the transpose
        undistorted, distorted = undistorted.T, distorted.T
        rows, inside = [K.fx * c + K.cx for c in LINES], slice(20, K.height - 20)
    else:
        rows, inside = [K.fy * c + K.cy for c in LINES], slice(20, K.width - 20)
    assert worst_offset(distorted, rows, inside) > 5  # the lens bends them
    assert worst_offset(undistorted, rows, inside) < 0.35  # antialiasing's noise
    assert undistorted.dtype == np.uint8


def test_a_resampled_frame_is_undistorted_with_the_scaled_camera():
    half = LENS.at_size(320, 240)
    image = cv2.resize(distorted_lines(LENS), (320, 240), interpolation=cv2.INTER_AREA)
    undistorted = Undistorter(half).image(image)
    rows = [half.intrinsics.fy * c + half.intrinsics.cy for c in LINES]
    assert worst_offset(undistorted, rows, slice(10, 310)) < 0.35


def precise_undistorted_pixels(calibration: CameraCalibration, pixels: np.ndarray) -> np.ndarray:
    """OpenCV's own answer for (u, v) pixels: cv2.undistortPoints with P = K, iterated to
    convergence (cv2.undistortPointsIter before OpenCV 5)."""
    K, dist = calibration.intrinsics.matrix(), np.array(calibration.distortion)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-9)
    undistort = getattr(cv2, "undistortPointsIter", cv2.undistortPoints)
    moved = undistort(pixels.reshape(-1, 1, 2), K, dist, R=None, P=K, criteria=criteria)
    return moved.reshape(-1, 2)


def test_returns_land_where_opencv_undistorts_them_and_outside_ones_are_dropped():
    rows = np.array([236, 100, 60, 400, 10, 0, 479])
    cols = np.array([322, 500, 80, 560, 15, 0, 639])
    expected = precise_undistorted_pixels(LENS, np.stack([cols, rows], -1).astype(np.float64))
    moved_rows, moved_cols, kept = Undistorter(LENS).returns(rows, cols)
    inside = (expected >= -0.5).all(axis=1) & (expected < [639.5, 479.5]).all(axis=1)
    np.testing.assert_array_equal(kept, inside)
    assert kept.tolist() == [True] * 4 + [False] * 3  # barrel: the corners go out
    np.testing.assert_array_equal(moved_cols, np.rint(expected[kept, 0]))
    np.testing.assert_array_equal(moved_rows, np.rint(expected[kept, 1]))
    assert moved_rows[0] == 236 and moved_cols[0] == 322  # the principal point stays
    # projected back through the lens, each kept return is its original pixel (rounding aside)
    normalised = (expected[kept] - [322.0, 236.5]) / [500.0, 520.0]
    points = np.concatenate([normalised, np.ones((len(normalised), 1))], axis=1)
    back, _ = cv2.projectPoints(
        points, np.zeros(3), np.zeros(3), LENS.intrinsics.matrix(), np.array(LENS.distortion)
    )
    np.testing.assert_allclose(back.reshape(-1, 2), np.stack([cols, rows], -1)[kept], atol=1e-3)
    assert [len(a) for a in Undistorter(LENS).returns(np.zeros(0), np.zeros(0))] == [0, 0, 0]


def test_image_and_returns_stay_pixel_aligned():
    """A bright spot where a return hits the distorted image is where the moved return is in
    the undistorted one, so the gray image and the sparse map still match pixel for pixel."""
    undistorter = Undistorter(LENS)
    rows, cols = np.array([60, 400, 240]), np.array([80, 560, 40])
    for row, col, new_row, new_col in zip(
        rows, cols, *undistorter.returns(rows, cols)[:2], strict=True
    ):
        spot = np.zeros((480, 640), np.uint16)
        spot[row - 1 : row + 2, col - 1 : col + 2] = [[20000, 40000, 20000]] * 3
        spot[row, col] = 65535
        image = undistorter.image(spot)
        assert image.dtype == np.uint16
        assert np.unravel_index(image.argmax(), image.shape) == (new_row, new_col)
