"""Uploaded bytes to validated arrays: the gray image and the sparse LIDAR depth map.

Every check answers with an ``ApiError`` (a 4xx and a stable code) and nothing here can crash
on hostile bytes: sizes are read from headers and checked before anything is decoded, images
are decoded by OpenCV (``cv2.imdecode``, IMREAD_UNCHANGED) only for the four formats accepted,
and ``.npy`` files are loaded with ``allow_pickle=False`` after their header says they hold
plain floats.
"""

from __future__ import annotations

import io

import cv2
import numpy as np

from sdcnet.service.errors import ApiError
from sdcnet.service.image_header import (
    PNG_SIGNATURE,
    HeaderError,
    ImageHeader,
    UnknownFormatError,
    check_decoding_work,
    read_header,
)

NPY_MAGIC = b"\x93NUMPY"
_GRAY_DTYPES = (np.uint8, np.uint16)


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
    except UnknownFormatError as exc:
        raise ApiError(415, "unsupported_media_type", f"{field}: {exc}") from exc
    except HeaderError as exc:
        raise ApiError(400, "unreadable_file", f"{field}: {exc}") from exc
    _too_large(field, header.width, header.height, max_pixels)
    try:
        check_decoding_work(data, header)
    except HeaderError as exc:
        raise ApiError(400, "unreadable_file", f"{field}: {exc}") from exc
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


def decode_gray(data: bytes, max_pixels: int) -> np.ndarray:
    """PNG/TIFF/JPEG/BMP bytes -> uint8 or uint16 (H, W); colour is converted to gray."""
    _not_empty("gray", data)
    header = _header("gray", data, max_pixels)
    image = _imdecode("gray", data, header)
    if image.dtype not in _GRAY_DTYPES:
        raise ApiError(
            422, "wrong_dtype", f"gray must be an 8- or 16-bit image, got {image.dtype} pixels"
        )
    if image.ndim == 3:
        conversion = {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}.get(image.shape[2])
        image = cv2.cvtColor(image, conversion) if conversion is not None else image[..., 0]
    return np.ascontiguousarray(image)


def decode_sparse(data: bytes, depth_scale: float | None, max_pixels: int) -> np.ndarray:
    """``.npy`` (float32/float64 metres) or 16-bit PNG (times ``depth_scale`` metres per unit)
    bytes -> float32 (H, W) metres, 0 = no return; values checked."""
    _not_empty("sparse", data)
    if data.startswith(NPY_MAGIC):
        if depth_scale is not None:
            raise ApiError(
                422,
                "invalid_request",
                "depth_scale applies to 16-bit PNG sparse maps only; a .npy holds metres",
            )
        sparse = _npy(data, max_pixels)
    elif data.startswith(PNG_SIGNATURE):
        if depth_scale is None:
            raise ApiError(
                422,
                "invalid_request",
                "a 16-bit PNG sparse map needs the depth_scale form field (metres per unit)",
            )
        sparse = _png_depth(data, depth_scale, max_pixels)
    else:
        raise ApiError(
            415,
            "unsupported_media_type",
            "sparse must be a .npy file (float32 or float64 metres) or a 16-bit PNG with "
            "depth_scale",
        )
    _check_depths(sparse)
    return sparse


def _npy(data: bytes, max_pixels: int) -> np.ndarray:
    stream = io.BytesIO(data)
    try:
        major, _ = np.lib.format.read_magic(stream)
        read = (
            np.lib.format.read_array_header_1_0
            if major == 1
            else np.lib.format.read_array_header_2_0
        )
        shape, _, dtype = read(stream)
    except Exception as exc:  # numpy parses the header dict with tokenize/ast: any error type
        raise ApiError(400, "unreadable_file", f"sparse: not a valid .npy header ({exc})") from exc
    if dtype.hasobject:
        raise ApiError(
            400,
            "pickle_not_allowed",
            "sparse .npy holds Python objects, which would need unpickling; this service never "
            "unpickles: send float32 or float64 metres",
        )
    if dtype.kind != "f" or dtype.itemsize not in (4, 8):
        raise ApiError(
            422, "wrong_dtype", f"sparse .npy must hold float32 or float64 metres, got {dtype}"
        )
    if len(shape) != 2:
        raise ApiError(
            422, "wrong_shape", f"sparse .npy must be 2-D (height, width), got shape {shape}"
        )
    _too_large("sparse", shape[1], shape[0], max_pixels)
    try:
        array = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, EOFError, OSError) as exc:
        raise ApiError(
            400, "unreadable_file", f"sparse: cannot read the .npy data (truncated?): {exc}"
        ) from exc
    return array.astype(np.float32)


def _png_depth(data: bytes, depth_scale: float, max_pixels: int) -> np.ndarray:
    header = _header("sparse", data, max_pixels)
    image = _imdecode("sparse", data, header)
    if image.dtype != np.uint16 or image.ndim != 2:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise ApiError(
            422,
            "wrong_dtype",
            f"a sparse PNG must be single-channel 16-bit, got {channels}-channel {image.dtype}",
        )
    return image.astype(np.float32) * np.float32(depth_scale)


def _check_depths(sparse: np.ndarray) -> None:
    if not np.isfinite(sparse).all():
        bad = int(np.count_nonzero(~np.isfinite(sparse)))
        raise ApiError(422, "invalid_depth", f"sparse has {bad} NaN or infinite values")
    if (sparse < 0).any():
        raise ApiError(
            422,
            "invalid_depth",
            f"sparse has {int(np.count_nonzero(sparse < 0))} negative depths: metres >= 0, "
            "0 = no return",
        )
    if not sparse.any():
        raise ApiError(
            422, "no_returns", "sparse has no LIDAR return (all zero): nothing to complete from"
        )


def check_same_size(gray: np.ndarray, sparse: np.ndarray) -> None:
    """Gray and sparse must be pixel-aligned: the same height and width."""
    if gray.shape != sparse.shape:
        raise ApiError(
            422,
            "wrong_shape",
            f"gray is {gray.shape[1]} x {gray.shape[0]} but sparse is "
            f"{sparse.shape[1]} x {sparse.shape[0]} (width x height): they must match",
        )
