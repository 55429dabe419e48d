"""Request bytes of the Open Inference Protocol to a validated ``Frame`` and the outputs asked
for: the JSON header split from the binary data, validated by ``sdcnet.service.v2_schemas``;
tensors checked for datatype, shape and byte counts before any array is made, then through the
same checks as ``POST /complete``'s files (``sdcnet.service.decode.frame_of``). Every problem is
an ``ApiError``, which the v2 routes answer as ``{"error": "..."}``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import ValidationError

from sdcnet.formats.v2 import DTYPES, HEADER_LENGTH
from sdcnet.service.decode import Frame, InputLimits, frame_of
from sdcnet.service.errors import ApiError
from sdcnet.service.v2_json import DataArray, JsonDataError, data_values, split_data
from sdcnet.service.v2_schemas import (
    PROTOCOL_INPUTS,
    AnyOutput,
    DepthOutput,
    InferenceRequest,
    InferParameters,
    MaskOutput,
    NormalsOutput,
    PointsOutput,
    RequestInput,
    SigmaOutput,
)


def _bad(message: str, code: str = "invalid_request", status: int = 400) -> ApiError:
    return ApiError(status, code, message)


def split_body(
    body: bytes | bytearray, header_length: str | None
) -> tuple[bytes | bytearray, memoryview]:
    """The JSON header and the binary data of a request body (without a copy of the body)."""
    if header_length is None:
        return body, memoryview(b"")
    try:
        length = int(header_length)
    except ValueError:
        raise _bad(f"{HEADER_LENGTH} must be a number of bytes, got {header_length!r}") from None
    if not 0 < length <= len(body):
        raise _bad(
            f"{HEADER_LENGTH} is {length} but the body holds {len(body)} bytes: the JSON "
            "header's length must be between 1 and the body's"
        )
    return bytes(memoryview(body)[:length]), memoryview(body)[length:]


def _validation_message(exc: ValidationError) -> str:
    """One line per problem: where in the JSON header and what."""
    problems = []
    for error in exc.errors(include_url=False):
        if error["type"] == "json_invalid":
            return f"the inference header is not valid JSON: {error['msg']}"
        where = ".".join(str(part) for part in error["loc"]) or "the inference header"
        problems.append(f"{where}: {error['msg']}")
    return "invalid inference request: " + "; ".join(problems)


@dataclass(frozen=True)
class ParsedRequest:
    """A request's validated JSON header, its inputs' JSON data aside (``data`` of an input
    is ``[k]``: ``arrays[k]`` holds its bytes; ``sdcnet.service.v2_json``)."""

    request: InferenceRequest
    arrays: list[DataArray]


def parse_request(header: bytes | bytearray) -> ParsedRequest:
    try:
        split = split_data(header)
    except JsonDataError as exc:
        raise _bad(str(exc), exc.code) from None
    try:
        return ParsedRequest(InferenceRequest.model_validate_json(split.skeleton), split.arrays)
    except ValidationError as exc:
        raise _bad(_validation_message(exc)) from None


def _from_json(
    name: str, parsed: ParsedRequest, data: list, datatype: str, shape: tuple[int, ...]
) -> np.ndarray:
    """The tensor of an input's JSON ``data`` (flat or nested by rows, row-major) as
    ``datatype``: its values counted against ``shape`` before they are parsed."""
    (k,) = data  # split_data put every data array aside
    try:
        return data_values(name, parsed.arrays[k], DTYPES[datatype], datatype, shape)
    except JsonDataError as exc:
        raise _bad(str(exc), exc.code) from None


def _input_shape(inp: RequestInput) -> tuple[int, ...]:
    """The input's shape, once its datatype and rank are the ones its name takes."""
    datatypes, expected = PROTOCOL_INPUTS[inp.name]
    if inp.datatype not in datatypes:
        raise _bad(
            f"input {inp.name} has datatype {inp.datatype}; it takes {' or '.join(datatypes)}",
            "wrong_dtype",
        )
    shape = tuple(inp.shape)
    if len(shape) != len(expected) or (expected[-1] == 3 and shape[-1] != 3):
        wanted = "[N, 3]" if expected[-1] == 3 else "[H, W]"
        raise _bad(f"input {inp.name} has shape {list(shape)}; it must be {wanted}", "wrong_shape")
    return shape


def input_shapes(request: InferenceRequest, limits: InputLimits) -> dict[str, tuple[int, ...]]:
    """name -> shape of every input, checked against the limits and against the gray image's
    size (the returns it may have) before any value is read."""
    shapes: dict[str, tuple[int, ...]] = {}
    for inp in request.inputs:
        if inp.name not in PROTOCOL_INPUTS:
            raise _bad(f"unknown input {inp.name!r}: the inputs are {', '.join(PROTOCOL_INPUTS)}")
        if inp.name in shapes:
            raise _bad(f"input {inp.name} is given twice")
        shape = shapes[inp.name] = _input_shape(inp)
        if inp.name != "returns" and shape[0] * shape[1] > limits.max_pixels:
            raise _bad(
                f"input {inp.name} is {shape[1]} x {shape[0]} = {shape[0] * shape[1]} pixels, "
                f"above this service's limit of {limits.max_pixels}",
                "too_large",
                413,
            )
    if "gray" not in shapes:
        raise _bad("missing input gray (UINT8 or UINT16, [H, W])")
    if ("sparse" in shapes) == ("returns" in shapes):
        given = "both" if "sparse" in shapes else "neither"
        raise _bad(
            f"send the LIDAR returns once: input sparse (FP32 [H, W]) or returns (FP32 "
            f"[N, 3]), not {given}"
        )
    if "returns" in shapes:
        height, width = shapes["gray"]
        most = limits.returns_for(width, height)
        if shapes["returns"][0] > most:
            raise _bad(
                f"input returns holds {shapes['returns'][0]} returns, more than the {most} this "
                f"service takes for a {width} x {height} frame (at most one per pixel, and "
                "max_returns)",
                "too_large",
                413,
            )
    return shapes


def input_tensors(parsed: ParsedRequest, binary: memoryview, limits: InputLimits) -> dict:
    """name -> array of every input, from its JSON data or its slice of the binary data."""
    shapes = input_shapes(parsed.request, limits)
    tensors: dict[str, np.ndarray] = {}
    offset = 0
    for inp in parsed.request.inputs:
        shape = shapes[inp.name]
        size = inp.parameters.binary_data_size if inp.parameters else None
        if size is not None and inp.data is not None:
            raise _bad(f"input {inp.name} has both data and binary_data_size: give one")
        if size is None and inp.data is None:
            raise _bad(f"input {inp.name} has no values: give data or binary_data_size")
        if size is None:
            tensors[inp.name] = _from_json(inp.name, parsed, inp.data, inp.datatype, shape)
            continue
        dtype = DTYPES[inp.datatype]
        expected = math.prod(shape) * dtype.itemsize
        if size != expected:
            raise _bad(
                f"input {inp.name}: binary_data_size is {size} bytes but a {inp.datatype} "
                f"{list(shape)} tensor holds {expected}"
            )
        if offset + size > len(binary):
            raise _bad(
                f"input {inp.name} needs bytes {offset}..{offset + size} of the binary data, "
                f"which holds {len(binary)} (is {HEADER_LENGTH} right?)"
            )
        tensors[inp.name] = np.frombuffer(binary, dtype, math.prod(shape), offset).reshape(shape)
        offset += size
    if offset != len(binary):
        raise _bad(
            f"{len(binary) - offset} bytes of binary data follow the last input's (the inputs' "
            f"binary_data_size add up to {offset})"
        )
    return tensors


def frame_of_request(parsed: ParsedRequest, binary: memoryview, limits: InputLimits) -> Frame:
    """The validated frame of a parsed request and its binary data."""
    tensors = input_tensors(parsed, binary, limits)
    parameters = parsed.request.parameters or InferParameters()
    return frame_of(
        tensors["gray"],
        tensors.get("sparse"),
        tensors.get("returns"),
        limits,
        intrinsics=parameters.intrinsics(),
        outlier_removal=parameters.outlier_removal,
        max_sigma=parameters.max_sigma,
    )


def requested_outputs(request: InferenceRequest) -> list[AnyOutput]:
    """The outputs asked for, each once (default: depth, mask, points, normals and sigma)."""
    if request.outputs is None:
        return [
            DepthOutput(name="depth"),
            MaskOutput(name="mask"),
            PointsOutput(name="points"),
            NormalsOutput(name="normals"),
            SigmaOutput(name="sigma"),
        ]
    names = [o.name for o in request.outputs]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise _bad(f"output {', '.join(repeated)} is asked for more than once")
    if not names:
        raise _bad(
            "outputs is empty: ask for depth, mask, points, normals or sigma, or leave it out "
            "for all"
        )
    return list(request.outputs)
