"""A user's camera: its calibration file read, and its lens distortion removed from frames.

``load_camera_file`` reads, by content rather than by extension, the files calibration tools
write: OpenCV's calibration output (``cv2.FileStorage`` YAML, JSON or XML: ``camera_matrix``,
``distortion_coefficients``, ``image_width``, ``image_height``), ROS ``camera_info`` YAML
(camera_calibration, camera_info_manager), a ROS / ROS 2 ``CameraInfo`` message (``width``,
``height``, ``k``, ``d``, ``distortion_model``; ``K``, ``D`` in ROS 1) and a plain JSON of
``fx``, ``fy``, ``cx``, ``cy``, ``width``, ``height`` (optionally ``distortion``).

Conventions are ``sdcnet.camera``'s, which are OpenCV's and therefore those of every file
above: pixel (u, v) = (column, row), the centre of pixel (i, j) at coordinates (i, j).

``Undistorter`` maps a frame into the pinhole camera of the calibration's own matrix K (the
new camera matrix of ``cv2.initUndistortRectifyMap`` is K): the undistorted frame has the
calibration's fx, fy, cx, cy, and its pixels whose rays the lens did not see are 0.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sdcnet.camera import PINHOLE_FIELDS, Intrinsics, IntrinsicsError, check_intrinsics

#: Distortion models taken, and how many coefficients each has (OpenCV's order k1, k2, p1, p2,
#: k3, k4, k5, k6; plumb_bob is ROS's name for the first 4 or 5, rational_polynomial for 8).
MODELS = {"pinhole": (0,), "plumb_bob": (4, 5), "rational_polynomial": (8,)}
#: Distortion models refused with their own message: OpenCV's cv2.fisheye is not supported.
FISHEYE_MODELS = ("equidistant", "fisheye", "kannala_brandt")
#: Relative difference of aspect ratio below which a frame of another size is the camera's
#: image resampled (binned or resized) rather than another camera or a crop.
ASPECT_TOLERANCE = 0.01

_MATRIX_KEYS = ("camera_matrix", "cameraMatrix", "K", "k")
_DISTORTION_KEYS = ("distortion_coefficients", "dist_coeffs", "distCoeffs", "D", "d", "distortion")
_SIZE_KEYS = (("image_width", "image_height"), ("width", "height"))
_OPENCV_HEADERS = ("%YAML", "<?xml", "<opencv_storage>")


class CalibrationError(ValueError):
    """A camera file that cannot be used, or a frame its camera does not fit; the message
    names the file and what is wrong."""


@dataclass(frozen=True)
class CameraCalibration:
    """A calibrated camera: pinhole ``intrinsics`` (pixels, at the calibrated image size) and
    lens ``distortion`` coefficients in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6]];
    empty = none) of the distortion ``model`` (see ``MODELS``); ``source`` says which file
    and format it came from."""

    intrinsics: Intrinsics
    distortion: tuple[float, ...] = ()
    model: str = "pinhole"
    source: str = ""

    def describe(self) -> dict[str, Any]:
        """The calibration as JSON values: source, model, intrinsics (pixels, with the image
        size) and distortion."""
        return {
            "source": self.source,
            "model": self.model,
            "intrinsics": self.intrinsics.as_dict(),
            "distortion": list(self.distortion),
        }

    def at_size(self, width: int, height: int) -> CameraCalibration:
        """The calibration of this camera's frames at ``width`` x ``height`` pixels: itself at
        its own size; at the same aspect ratio (within ``ASPECT_TOLERANCE``) the image
        resampled, so the intrinsics scaled (``Intrinsics.scaled``) and the distortion, which
        acts on normalised coordinates, unchanged. Raises ``CalibrationError`` for another
        aspect ratio: another camera, or a crop, which the file does not describe."""
        K = self.intrinsics
        if (width, height) == (K.width, K.height):
            return self
        if abs((width / height) / (K.width / K.height) - 1) > ASPECT_TOLERANCE:
            raise CalibrationError(
                f"the frame is {width} x {height} pixels, not of the aspect ratio of the "
                f"camera's {K.width} x {K.height} ({self.source})"
            )
        return replace(self, intrinsics=K.scaled(width, height))


def load_camera_file(path: str | Path) -> CameraCalibration:
    """The calibration in a camera file (any form of the module's docstring, recognised by
    its content); raises ``CalibrationError`` naming the file and what is wrong with it."""
    path = Path(path)
    text = _read_text(path)
    syntax, fields = _parse(path, text)
    width, height = _image_size(fields, path)
    intrinsics = _intrinsics(_camera_matrix(fields, path), width, height, path)
    distortion, model = _distortion(fields, path)
    source = f"{path.name} ({_form(syntax, fields)})"
    return CameraCalibration(intrinsics, distortion, model, source)


def _error(path: Path, problem: str) -> CalibrationError:
    return CalibrationError(f"camera file {path}: {problem}")


def _read_text(path: Path) -> str:
    if not path.exists():
        raise CalibrationError(f"camera file not found: {path}")
    if path.is_dir():
        raise _error(path, "is a directory, not a calibration file")
    try:
        return path.read_bytes().decode("utf-8-sig")
    except OSError as exc:
        raise _error(path, f"cannot be read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise _error(path, "is not a text file (a calibration is YAML, JSON or XML)") from None


def _parse(path: Path, text: str) -> tuple[str, dict]:
    """(syntax, top-level fields) of a calibration file's text: OpenCV's (``cv2.FileStorage``)
    when it starts with OpenCV's YAML or XML header or holds an ``opencv-matrix``, else JSON
    when it starts with ``{``, else YAML."""
    head = text.lstrip()
    if head.startswith(_OPENCV_HEADERS) or "opencv-matrix" in text:
        kind = "XML" if head.startswith("<") else "JSON" if head.startswith("{") else "YAML"
        return f"OpenCV {kind}", _read_opencv(path, text, f"OpenCV {kind}")
    if head.startswith("{"):
        return "JSON", _mapping(path, _read_json(path, text))
    return "YAML", _mapping(path, _read_yaml(path, text))


def _mapping(path: Path, document: Any) -> dict:
    if not isinstance(document, dict):
        raise _error(path, "holds no calibration fields (a mapping of names to values)")
    return document


def _read_opencv(path: Path, text: str, syntax: str) -> dict:
    """The top-level fields of an OpenCV FileStorage text, matrices as arrays."""
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        if not storage.isOpened():
            raise cv2.error
        return _node_value(storage.root())
    except (cv2.error, SystemError):  # the bindings raise SystemError for some parse errors
        raise _error(path, f"is not valid {syntax}: OpenCV cannot parse it") from None


def _node_value(node: cv2.FileNode) -> Any:
    """A FileStorage node as Python values: an opencv-matrix as a float64 array, maps as
    dicts, sequences as lists, numbers, strings, None."""
    if node.isMap():
        keys = node.keys()
        if {"rows", "cols", "dt", "data"} <= set(keys):
            return np.asarray(node.mat(), np.float64)
        return {key: _node_value(node.getNode(key)) for key in keys}
    if node.isSeq():
        return [_node_value(node.at(i)) for i in range(node.size())]
    if node.isInt():
        return int(node.real())
    if node.isReal():
        return node.real()
    if node.isString():
        return node.string()
    return None


def _read_json(path: Path, text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise _error(
            path, f"is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from None


def _read_yaml(path: Path, text: str) -> Any:
    """The first document of a YAML text (``ros2 topic echo`` ends each message with ---)."""
    import yaml

    try:
        documents = [d for d in yaml.safe_load_all(text) if d is not None]
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        raise _error(path, f"is neither JSON nor valid YAML ({where}{exc.problem})") from None
    except yaml.YAMLError:
        raise _error(path, "is neither JSON nor valid YAML") from None
    return documents[0] if documents else None


def _form(syntax: str, fields: dict) -> str:
    """The file's form, for ``CameraCalibration.source``."""
    if syntax.startswith("OpenCV"):
        return syntax
    if "camera_matrix" in fields:
        return f"ROS camera_info {syntax}"
    if "k" in fields or "K" in fields:
        return f"ROS CameraInfo {syntax}"
    return f"plain {syntax}"


def _first_key(fields: dict, keys: tuple[str, ...]) -> str | None:
    return next((key for key in keys if key in fields), None)


def _image_size(fields: dict, path: Path) -> tuple[int, int]:
    """(width, height) in pixels: image_width and image_height, or width and height."""
    for keys in _SIZE_KEYS:
        if all(key in fields for key in keys):
            return tuple(_pixel_count(fields[key], key, path) for key in keys)
    raise _error(
        path,
        "does not give the image size: expected image_width and image_height (OpenCV, ROS "
        "camera_info) or width and height (pixels)",
    )


def _number(value: Any, name: str, path: Path) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise _error(path, f"{name} must be a finite number, got {value!r}")
    return float(value)


def _pixel_count(value: Any, name: str, path: Path) -> int:
    pixels = _number(value, name, path)
    if pixels != int(pixels) or pixels < 1:
        raise _error(path, f"{name} must be a whole number of pixels >= 1, got {value!r}")
    return int(pixels)


def _values(value: Any, name: str, path: Path) -> np.ndarray:
    """The numbers of a matrix field as float64, shaped as the file declares them: an array
    (OpenCV), ``{rows, cols, data}`` (ROS, OpenCV JSON), a nested or a flat list."""
    declared = None
    if isinstance(value, dict):
        if "data" not in value:
            raise _error(path, f"{name} has no data")
        if "rows" in value and "cols" in value:
            declared = (value["rows"], value["cols"])
        value = value["data"]
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise _error(path, f"{name} must hold numbers, got {value!r}") from None
    if declared is not None:
        rows, cols = declared
        if not all(isinstance(n, int) and n >= 0 for n in declared) or rows * cols != array.size:
            raise _error(path, f"{name} declares {rows} x {cols} values but holds {array.size}")
        array = array.reshape(rows, cols)
    if not np.isfinite(array).all():
        raise _error(path, f"{name} holds values that are not finite numbers")
    return array


def _camera_matrix(fields: dict, path: Path) -> np.ndarray:
    """The 3 x 3 camera matrix K: camera_matrix, K or k (9 values, row-major), or fx, fy,
    cx, cy."""
    key = _first_key(fields, _MATRIX_KEYS)
    if key is None:
        if not all(name in fields for name in PINHOLE_FIELDS):
            raise _error(
                path,
                "has no camera matrix: expected camera_matrix (OpenCV, ROS camera_info), k or K "
                "(ROS CameraInfo), or fx, fy, cx and cy (pixels)",
            )
        fx, fy, cx, cy = (_number(fields[name], name, path) for name in PINHOLE_FIELDS)
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    K = _values(fields[key], key, path)
    if K.shape != (3, 3) and not (K.ndim == 1 and K.size == 9):
        shape = " x ".join(str(n) for n in K.shape) or "a single value"
        raise _error(path, f"{key} is {shape}; a camera matrix is 3 x 3 (9 values, row-major)")
    return K.reshape(3, 3)


def _intrinsics(K: np.ndarray, width: int, height: int, path: Path) -> Intrinsics:
    """Pinhole intrinsics of a checked camera matrix: no skew, and what every request's
    intrinsics must be (``sdcnet.camera.check_intrinsics``: focal lengths of a field of view
    under 150 degrees, the principal point within half an image of the image)."""
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        rows = "; ".join(" ".join(f"{v:g}" for v in row) for row in K)
        raise _error(path, f"is not a camera matrix (fx 0 cx; 0 fy cy; 0 0 1): {rows}")
    skew = K[0, 1]
    if abs(skew) > 1e-9 * abs(K[0, 0]):
        raise _error(path, f"the camera matrix has a skew of {skew:g}; sdcnet takes none")
    try:
        return check_intrinsics(Intrinsics.from_matrix(K, width, height))
    except IntrinsicsError as exc:
        raise _error(path, str(exc)) from None


def _named_model(fields: dict, path: Path) -> str | None:
    """The distortion model a file names: ROS's distortion_model, or equidistant for OpenCV's
    fisheye_model flag; None when it names none."""
    if fields.get("fisheye_model"):
        return "equidistant"
    name = fields.get("distortion_model")
    if name is None or name == "":
        return None
    if not isinstance(name, str):
        raise _error(path, f"distortion_model must be a name, got {name!r}")
    return name.lower()


def _distortion(fields: dict, path: Path) -> tuple[tuple[float, ...], str]:
    """(coefficients, model) of a file; no coefficients, or all zero, is the pinhole."""
    key = _first_key(fields, _DISTORTION_KEYS)
    values = np.zeros(0) if key is None else _values(fields[key], key, path)
    if values.ndim == 2 and 1 not in values.shape:
        raise _error(path, f"{key} is {values.shape[0]} x {values.shape[1]}, not a vector")
    coefficients = tuple(float(v) for v in values.reshape(-1))
    named = _named_model(fields, path)
    if named in FISHEYE_MODELS:
        raise _error(
            path,
            f"uses the {named} (fisheye) distortion model, which sdcnet does not support: "
            "calibrate with the plumb_bob or rational_polynomial model",
        )
    if named is not None and named not in MODELS:
        raise _error(
            path, f"unsupported distortion model {named!r}; supported: {', '.join(MODELS)}"
        )
    if not any(coefficients):
        return (), "pinhole"
    model = named or next((m for m, counts in MODELS.items() if len(coefficients) in counts), None)
    if model is None or len(coefficients) not in MODELS[model]:
        counts = "; ".join(f"{m}: {' or '.join(map(str, n))}" for m, n in MODELS.items())
        raise _error(
            path,
            f"{len(coefficients)} distortion coefficients do not fit "
            f"{model or 'any supported model'} (coefficients per model: {counts})",
        )
    return coefficients, model


class Undistorter:
    """Removes a calibration's lens distortion from frames of its image size: the image by
    remapping it, LIDAR returns by moving their pixels. The maps are computed once, here; the
    undistorted frame is the pinhole camera of the calibration's own K."""

    #: Inverse distortion of returns: up to 100 iterations, until within 0.001 px (OpenCV's
    #: default of 5 iterations leaves pixels of error near a strong lens's corners).
    CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-3)

    def __init__(self, calibration: CameraCalibration):
        K = calibration.intrinsics
        self.width, self.height = K.width, K.height
        self._K = K.matrix()
        self._D = np.asarray(calibration.distortion, np.float64)
        # float maps (8 bytes a pixel): cv2.remap runs faster on them than on fixed-point
        # CV_16SC2 ones here (docs/development.md, "Measurements")
        self._map1, self._map2 = cv2.initUndistortRectifyMap(
            self._K, self._D, None, self._K, (self.width, self.height), cv2.CV_32FC1
        )

    def image(self, gray: np.ndarray) -> np.ndarray:
        """The undistorted image (H, W) of the same dtype, bilinear; 0 where the lens saw
        nothing."""
        if gray.shape[:2] != (self.height, self.width):
            raise ValueError(
                f"a {gray.shape[1]} x {gray.shape[0]} image for a {self.width} x {self.height} "
                "undistorter"
            )
        return cv2.remap(
            gray, self._map1, self._map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
        )

    def returns(
        self, rows: np.ndarray, cols: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where returns seen at pixels (``rows``, ``cols``) of the distorted image lie in the
        undistorted one, rounded to the nearest pixel: (rows, cols) of the returns kept and
        ``kept``, a bool (N,) that is False for those that land outside the frame."""
        if len(rows) == 0:
            empty = np.zeros(0, np.intp)
            return empty, empty, np.zeros(0, bool)
        seen = np.stack([cols, rows], axis=-1).astype(np.float64).reshape(-1, 1, 2)
        moved = cv2.undistortImagePoints(seen, self._K, self._D, None, self.CRITERIA)
        u, v = np.rint(moved.reshape(-1, 2)).T
        kept = (u >= 0) & (u < self.width) & (v >= 0) & (v < self.height)
        return v[kept].astype(np.intp), u[kept].astype(np.intp), kept
