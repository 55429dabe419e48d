"""Uploaded bytes to a validated ``Frame``: the gray image and the LIDAR returns, as a dense
sparse map or as a list.

Every check answers with an ``ApiError`` (a 4xx and a stable code) and nothing here can crash
on hostile bytes: sizes are read from headers and checked against the limits and the frame
(``InputLimits``: the gray image's declared size bounds the sparse map and the returns)
before anything is decoded or parsed, images are decoded by OpenCV (``cv2.imdecode``,
IMREAD_UNCHANGED) only for the four formats accepted, and the files of returns are read by
their format's parser (``sdcnet.formats.sparse``), which declares their shape to
``Reading.check_shape`` before it reads their values. Messages are the service's own: a
library's words (and its hints on how to lift a limit) stay out of them. The checks on arrays
(``frame_of``) are the ones the Open Inference Protocol's tensors go through too
(``sdcnet.service.v2_decode``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from sdcnet.camera import GivenIntrinsics, Intrinsics
from sdcnet.formats import FormatError, InputFormat, Reading
from sdcnet.formats.image_header import ImageHeader, check_decoding_work, read_header
from sdcnet.formats.sparse import FORMATS, described, sparse_format
from sdcnet.pipeline import to_gray
from sdcnet.returns import ReturnsError, check_dense_depths, dense_from_returns
from sdcnet.service.errors import ApiError, format_error
from sdcnet.service.schemas import ResponseFormat

_GRAY_DTYPES = (np.uint8, np.uint16)


@dataclass(frozen=True)
class InputLimits:
    """How large a request's inputs may be: ``max_pixels`` per image, ``max_returns`` per
    list of returns (and never more than the frame's pixels)."""

    max_pixels: int
    max_returns: int

    def returns_for(self, width: int, height: int) -> int:
        """Returns a list may hold in a ``width`` x ``height`` frame."""
        return min(self.max_returns, width * height)


@dataclass(frozen=True)
class CompletionRequest:
    """The fields of one ``POST /complete``: file bytes (``sparse`` or ``returns``, one of
    the two), the intrinsics given (pixels; those not given are the default's), ``max_sigma``
    in metres (``None``: no limit), the answer's format."""

    gray: bytes
    sparse: bytes | None = None
    returns: bytes | None = None
    depth_scale: float | None = None
    intrinsics: GivenIntrinsics = field(default_factory=GivenIntrinsics)
    outlier_removal: bool = False
    max_sigma: float | None = None
    format: ResponseFormat = ResponseFormat.json


@dataclass(frozen=True)
class Frame:
    """One request's validated inputs, whatever protocol brought them: gray uint8/uint16
    (H, W); sparse float32 (H, W) metres, 0 = no return, at least one return; the intrinsics
    given (pixels), each value not given the default's: ``camera``, the configured camera's at
    the frame's size (``sdcnet.service.camera``), else the model's, scaled to the image;
    ``max_sigma``, metres: points whose depth's uncertainty is above it leave the cloud
    (``None``: no limit)."""

    gray: np.ndarray
    sparse: np.ndarray
    intrinsics: GivenIntrinsics = field(default_factory=GivenIntrinsics)
    outlier_removal: bool = False
    max_sigma: float | None = None
    camera: Intrinsics | None = None


def check_max_sigma(max_sigma: float | None) -> float | None:
    """``max_sigma`` (metres) when it is a positive finite number or ``None``, else 422
    ``invalid_max_sigma``: the one check of every route."""
    if max_sigma is None or (math.isfinite(max_sigma) and max_sigma > 0):
        return max_sigma
    raise ApiError(
        422,
        "invalid_max_sigma",
        f"max_sigma must be a positive finite number of metres, got {max_sigma!r}",
    )


def decode_form(req: CompletionRequest, limits: InputLimits) -> Frame:
    """The frame of a ``POST /complete`` form: image bytes, and a sparse map or returns; the
    sizes of both are checked against the image's declared size before either is decoded."""
    max_sigma = check_max_sigma(req.max_sigma)
    if (req.sparse is None) == (req.returns is None):
        given = "both" if req.sparse is not None else "neither"
        raise ApiError(
            422,
            "invalid_request",
            f"send the LIDAR returns once: the form field sparse (dense map) or returns "
            f"(list), not {given}",
        )
    if req.returns is not None and req.depth_scale is not None:
        raise ApiError(
            422,
            "invalid_request",
            "depth_scale applies to 16-bit PNG sparse maps only; returns hold metres",
        )
    _not_empty("gray", req.gray)
    header = _header("gray", req.gray, limits.max_pixels)
    if req.sparse is not None:
        frame = (header.width, header.height)
        sparse = decode_sparse(req.sparse, req.depth_scale, limits.max_pixels, frame)
        gray = decode_gray(req.gray, limits.max_pixels, header)
        check_same_size(gray, sparse)
    else:
        most = limits.returns_for(header.width, header.height)
        returns = decode_returns(req.returns, most, (header.width, header.height))
        gray = decode_gray(req.gray, limits.max_pixels, header)
        sparse = sparse_from_returns(returns, gray.shape)
    return Frame(gray, sparse, req.intrinsics, req.outlier_removal, max_sigma=max_sigma)


def frame_of(
    gray: np.ndarray,
    sparse: np.ndarray | None,
    returns: np.ndarray | None,
    limits: InputLimits,
    **options,
) -> Frame:
    """The frame of arrays already in memory (Open Inference Protocol tensors): gray uint8 or
    uint16 (H, W), and a float32 sparse map (H, W) or float32 returns (N, 3), checked as the
    form's files are; ``options`` are ``Frame``'s ``intrinsics``, ``outlier_removal`` and
    ``max_sigma``."""
    check_max_sigma(options.get("max_sigma"))
    height, width = gray.shape
    _too_large("gray", width, height, limits.max_pixels)
    if sparse is not None:
        check_same_size(gray, sparse)
        check_depths(sparse)
    else:
        sparse = sparse_from_returns(returns, gray.shape)
    return Frame(gray, sparse, **options)


def _too_large(field: str, width: int, height: int, max_pixels: int) -> None:
    if width * height > max_pixels:
        raise ApiError(
            413,
            "too_large",
            f"{field} is {width} x {height} = {width * height} pixels, above this service's "
            f"limit of {max_pixels}",
        )


def _not_empty(field: str, data: bytes) -> None:
    if not data:
        raise ApiError(400, "unreadable_file", f"{field} is an empty file")


def _header(field: str, data: bytes, max_pixels: int) -> ImageHeader:
    """The image's header, checked against the pixel limit and for decoding work beyond it."""
    try:
        header = read_header(data)
        _too_large(field, header.width, header.height, max_pixels)
        check_decoding_work(data, header)
    except FormatError as exc:
        raise format_error(exc, field) from exc
    return header


def _imdecode(field: str, data: bytes, header: ImageHeader) -> np.ndarray:
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None or image.shape[:2] != (header.height, header.width):
        raise ApiError(
            400,
            "unreadable_file",
            f"{field}: cannot decode the {header.format.upper()} image (truncated or corrupt)",
        )
    return image


def decode_gray(data: bytes, max_pixels: int, header: ImageHeader | None = None) -> np.ndarray:
    """PNG/TIFF/JPEG/BMP bytes -> uint8 or uint16 (H, W); colour is converted to gray.
    ``header``: the image's, when already read and checked (``_header``)."""
    _not_empty("gray", data)
    header = header or _header("gray", data, max_pixels)
    image = _imdecode("gray", data, header)
    if image.dtype not in _GRAY_DTYPES:
        raise ApiError(
            422, "wrong_dtype", f"gray must be an 8- or 16-bit image, got {image.dtype} pixels"
        )
    return to_gray(image)


def decode_sparse(
    data: bytes,
    depth_scale: float | None,
    max_pixels: int,
    frame: tuple[int, int] | None = None,
) -> np.ndarray:
    """A file of a dense map (``sdcnet.formats.sparse``: float32/float64 metres, or units times
    ``depth_scale`` metres per unit) -> float32 (H, W) metres, 0 = no return; values checked.
    ``frame``: the gray image's (width, height), which the file's declared size must be,
    checked before its values are read."""
    _not_empty("sparse", data)
    format_ = _format("sparse", data, "map")
    if depth_scale is not None and not format_.scaled:
        scaled = " or ".join(f.name for f in FORMATS if f.scaled)
        raise ApiError(
            422,
            "invalid_request",
            f"depth_scale applies to {scaled} sparse maps only; a {format_.name} holds metres",
        )

    def dense_map(shape: tuple) -> None:
        if len(shape) != 2:
            raise ApiError(
                422, "wrong_shape", f"sparse must be 2-D (height, width), got shape {shape}"
            )
        _too_large("sparse", shape[1], shape[0], max_pixels)
        if frame is not None:
            _same_size(frame, (shape[1], shape[0]))

    sparse = _parse(format_, data, Reading("sparse", dense_map, depth_scale), "map")
    check_depths(sparse)
    return sparse


def _format(field: str, data: bytes, carried: str) -> InputFormat:
    """The format of a file of returns, which must carry a ``"map"`` or a ``"list"``."""
    format_ = sparse_format(data)
    if carried not in format_.carries:
        raise _unsupported(field, carried)
    return format_


def _unsupported(field: str, carried: str) -> ApiError:
    return ApiError(415, "unsupported_media_type", f"{field} must be {described(carried)}")


def _parse(format_: InputFormat, data: bytes, reading: Reading, carried: str) -> np.ndarray:
    """``format_.parse`` of a file of a ``"map"`` or a ``"list"``, its errors answered in the
    service's shape."""
    try:
        return format_.parse(data, reading)
    except FormatError as exc:
        if exc.code == "unsupported_media_type":
            raise _unsupported(reading.field, carried) from None
        raise format_error(exc) from None
    except ReturnsError as exc:
        raise ApiError(422, exc.code, str(exc)) from None


def _returns_shape_check(most: int, frame: tuple[int, int]) -> Callable[[tuple[int, ...]], None]:
    """The check of a list's shape once its file declares it, before the values are read:
    (N, 3) (row, col, z_m) with N at most ``most`` for ``frame`` = (width, height)."""

    def check(shape: tuple[int, ...]) -> None:
        if len(shape) != 2 or shape[1] != 3:
            raise ApiError(
                422, "wrong_shape", f"returns must be (N, 3): row, col, z_m; got shape {shape}"
            )
        if shape[0] > most:
            width, height = frame
            raise ApiError(
                413,
                "too_large",
                f"more than {most} returns, the most this service takes for a {width} x "
                f"{height} frame (at most one per pixel, and max_returns)",
            )

    return check


def decode_returns(data: bytes, most: int, frame: tuple[int, int]) -> np.ndarray:
    """A file of a list of returns (``sdcnet.formats.sparse``) -> float32 (N, 3): row, column
    (pixel indices), Z metres; at most ``most`` of them, counted before they are parsed (a
    ``frame`` = (width, height) holds that many). Checked against the frame by
    ``sparse_from_returns``."""
    _not_empty("returns", data)
    format_ = _format("returns", data, "list")
    return _parse(format_, data, Reading("returns", _returns_shape_check(most, frame)), "list")


def sparse_from_returns(returns: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The dense float32 map of checked ``returns`` in a frame of ``shape`` (the nearest
    return wins a pixel); 422 with the problem's code for returns that cannot be."""
    try:
        return dense_from_returns(returns, shape)
    except ReturnsError as exc:
        raise ApiError(422, exc.code, str(exc)) from None


def check_depths(sparse: np.ndarray) -> None:
    """A dense map's depths: those ``check_dense_depths`` accepts, at least one return."""
    try:
        check_dense_depths(sparse)
    except ReturnsError as exc:
        raise ApiError(422, exc.code, str(exc)) from None
    if not sparse.any():
        raise ApiError(
            422, "no_returns", "sparse has no LIDAR return (all zero): nothing to complete from"
        )


def check_same_size(gray: np.ndarray, sparse: np.ndarray) -> None:
    """Gray and sparse must be pixel-aligned: the same height and width."""
    _same_size((gray.shape[1], gray.shape[0]), (sparse.shape[1], sparse.shape[0]))


def _same_size(gray: tuple[int, int], sparse: tuple[int, int]) -> None:
    """Gray's and sparse's (width, height) must be the same."""
    if gray != sparse:
        raise ApiError(
            422,
            "wrong_shape",
            f"gray is {gray[0]} x {gray[1]} but sparse is {sparse[0]} x {sparse[1]} (width x "
            "height): they must match",
        )
