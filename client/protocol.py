"""What ``Client.complete`` sends and how it reads the answer: the service's Open Inference
Protocol route (``POST /v2/models/sdcnet/infer``) with binary tensors, and sdcnet's compact
answer layouts (``sdcnet.compact``) turned back into full-frame arrays.

The request is a small JSON header followed by the raw gray image (1 byte a pixel) and the
LIDAR returns as a list (12 bytes a return): no image codec, no multipart form, no dense map.
The answer holds the depth, the mask and the depth's uncertainty (sigma) of the spacecraft's
region (the smallest window that holds the mask: everything outside it is 0), the mask 8
pixels a byte, and the points with their normals; ``read_answer`` pastes them into full
frames, equal to the service's full-frame answer bit for bit (float16 depth, on request, is
not).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from sdcnet.camera import PINHOLE_FIELDS
from sdcnet.caveats import from_text
from sdcnet.compact import depth_from_fp16, paste, unpack_mask
from sdcnet.formats.v2 import DTYPES, HEADER_LENGTH

PATH = "/v2/models/sdcnet/infer"
_GRAY_DATATYPES = {DTYPES[name]: name for name in ("UINT8", "UINT16")}
_TIMINGS = ("decode_ms", "queue_ms", "inference_ms", "encode_ms")


class AnswerError(ValueError):
    """The answer is not what the protocol and the request say it must be."""


def request_body(
    gray: np.ndarray,
    returns: np.ndarray,
    parameters: dict[str, Any],
    float16_depth: bool = False,
) -> tuple[bytes, dict[str, str]]:
    """(body, headers) of one request: gray uint8/uint16 (H, W), returns float32 (N, 3) (row,
    column, Z metres), ``parameters`` (intrinsics in pixels, ``outlier_removal``,
    ``max_sigma`` in metres); depth as float16 residuals when ``float16_depth``."""
    gray = np.ascontiguousarray(gray)
    returns = np.ascontiguousarray(returns, "<f4")
    depth_parameters = {"binary_data": True, "region": True, "fp16": float16_depth}
    header = {
        "inputs": [
            {
                "name": "gray",
                "datatype": _GRAY_DATATYPES[gray.dtype],
                "shape": list(gray.shape),
                "parameters": {"binary_data_size": gray.nbytes},
            },
            {
                "name": "returns",
                "datatype": "FP32",
                "shape": list(returns.shape),
                "parameters": {"binary_data_size": returns.nbytes},
            },
        ],
        "parameters": parameters,
        "outputs": [
            {"name": "depth", "parameters": depth_parameters},
            {"name": "mask", "parameters": {"binary_data": True, "region": True, "bits": True}},
            {"name": "points", "parameters": {"binary_data": True}},
            {"name": "normals", "parameters": {"binary_data": True}},
            {"name": "sigma", "parameters": {"binary_data": True, "region": True}},
        ],
    }
    encoded = json.dumps(header).encode()
    body = b"".join([encoded, gray.reshape(-1).view(np.uint8), returns.reshape(-1).view(np.uint8)])
    headers = {HEADER_LENGTH: str(len(encoded)), "Content-Type": "application/octet-stream"}
    return body, headers


@dataclass
class Answer:
    """The arrays and summary of one answer, full frame."""

    depth: np.ndarray  # float32 (H, W) metres
    mask: np.ndarray  # bool (H, W)
    points: np.ndarray  # float32 (N, 3) metres
    sigma: np.ndarray  # float32 (H, W) metres
    normals: np.ndarray  # float32 (N, 3) unit vectors, one a point
    meta: dict[str, Any]  # the summary, shaped as POST /complete's (meta.json)


def _tensor(output: dict, binary: bytes, offset: int) -> tuple[np.ndarray, int]:
    """The output's array from the binary data at ``offset``, and the offset after it."""
    size = output["parameters"]["binary_data_size"]
    if offset + size > len(binary):
        raise AnswerError(f"output {output['name']} runs past the end of the binary data")
    dtype = DTYPES[output["datatype"]]
    array = np.frombuffer(binary, dtype, size // dtype.itemsize, offset)
    return array, offset + size


def _full_frame(array: np.ndarray, output: dict, shape: tuple[int, int]) -> np.ndarray:
    """An output's compact layout back as a full (H, W) frame."""
    parameters = output["parameters"]
    window = (parameters["region_height"], parameters["region_width"])
    if parameters.get("bits"):
        array = unpack_mask(array, window)
    array = array.reshape(window)
    if "depth_offset" in parameters:
        array = depth_from_fp16(array, parameters["depth_offset"])
    return paste(array, parameters["region_y0"], parameters["region_x0"], shape)


def summary(document: dict) -> dict[str, Any]:
    """The answer's parameters as ``POST /complete``'s summary (nested intrinsics, timings)."""
    p = document["parameters"]
    nested = set(_TIMINGS) | set(PINHOLE_FIELDS)
    meta = {k: v for k, v in p.items() if k not in nested}
    meta["model_version"] = document["model_version"]
    meta["intrinsics"] = {k: p[k] for k in PINHOLE_FIELDS}
    meta["timings"] = {k: p[k] for k in _TIMINGS}
    meta["caveats"] = from_text(str(p.get("caveats", "")))
    return meta


def read_answer(body: bytes, header_length: str | None, shape: tuple[int, int]) -> Answer:
    """The full-frame arrays of an answer to ``request_body``'s request on a frame of
    ``shape`` (H, W); raises ``AnswerError`` when it is not such an answer."""
    try:
        length = int(header_length or "")
        document = json.loads(body[:length])
        binary = memoryview(body)[length:]
        outputs = {output["name"]: output for output in document["outputs"]}
        arrays, offset = {}, 0
        for output in document["outputs"]:
            arrays[output["name"]], offset = _tensor(output, binary, offset)
        depth = _full_frame(arrays["depth"], outputs["depth"], shape)
        mask = _full_frame(arrays["mask"], outputs["mask"], shape).astype(bool, copy=False)
        points = arrays["points"].reshape(-1, 3).copy()  # writable, not a view of the body
        sigma = _full_frame(arrays["sigma"], outputs["sigma"], shape)
        normals = arrays["normals"].reshape(-1, 3).copy()
        return Answer(depth, mask, points, sigma, normals, summary(document))
    except (ValueError, KeyError, TypeError) as exc:
        raise AnswerError(f"{type(exc).__name__}: {exc}") from exc
