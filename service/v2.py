"""The Open Inference Protocol v2 (KServe, Triton) for ``POST /v2/models/sdcnet/infer``, with
its binary tensor data extension: request bytes to a validated ``Frame``, and a completed
frame to answer bytes. Clients such as ``tritonclient.http`` talk to it unmodified.

A request is a JSON header, optionally followed by the raw little-endian bytes of the inputs
that say ``"parameters": {"binary_data_size": n}`` (in the order of ``inputs``); the
``Inference-Header-Content-Length`` HTTP header gives the JSON header's length when binary data
follows. Answers are built the same way: outputs asked with ``binary_data`` (or all of them,
with the request parameter ``binary_data_output``) follow the JSON header as raw bytes.

Inputs: ``gray`` (UINT8 or UINT16, [H, W]) and either ``sparse`` (FP32, [H, W], metres, 0 = no
return) or ``returns`` (FP32, [N, 3]: row, column, Z metres). Request parameters: ``fx``,
``fy``, ``cx``, ``cy`` (pixels), ``outlier_removal`` and ``max_sigma`` (metres). Outputs:
``depth`` (FP32, [H, W]), ``mask`` (UINT8, [H, W]), ``points`` (FP32, [N, 3]) and ``sigma``
(FP32, [H, W], metres). sdcnet's own output parameters ask for the compact layouts of
``sdcnet.compact``: ``region`` (depth, mask, sigma: only the spacecraft's region, the
smallest window holding the mask; the answer says where), ``bits`` (mask: 8 pixels a byte)
and ``fp16`` (depth: float16 residuals above ``depth_offset``).

The JSON header is validated by the pydantic models below (their JSON schema is the route's
OpenAPI request body); tensors are checked for datatype, shape and byte counts before any array
is made, then go through the same checks as ``POST /complete``'s files
(``sdcnet.service.decode.frame_of``). Every problem is an ``ApiError``, which the v2 routes
answer as ``{"error": "..."}``.
"""

from __future__ import annotations

import json
import math
import uuid
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from sdcnet.camera import MAX_FIELD_OF_VIEW_DEG, MAX_FOCAL_PX, GivenIntrinsics
from sdcnet.compact import crop, fp16_residuals, pack_mask
from sdcnet.formats.v2 import DTYPES, HEADER_LENGTH
from sdcnet.service.camera import ServiceCamera, camera_frame
from sdcnet.service.decode import Frame, InputLimits, frame_of
from sdcnet.service.deps import MODEL_NAME
from sdcnet.service.encode import array_slices
from sdcnet.service.errors import ApiError
from sdcnet.service.inference import Answer, Completed, Engine, PhaseTimer, complete_frame
from sdcnet.service.schemas import CompletionSummary
from sdcnet.service.spool import Spool
from sdcnet.service.v2_json import DataArray, JsonDataError, data_values, split_data

#: input name -> (datatypes it takes, shape it has: -1 = any size)
INPUTS = {
    "gray": (("UINT8", "UINT16"), (-1, -1)),
    "sparse": (("FP32",), (-1, -1)),
    "returns": (("FP32",), (-1, 3)),
}
#: output name -> (datatype, shape) in the full-frame layout
OUTPUTS = {
    "depth": ("FP32", (-1, -1)),
    "mask": ("UINT8", (-1, -1)),
    "points": ("FP32", (-1, 3)),
    "sigma": ("FP32", (-1, -1)),
}


# -- the JSON header (request) ---------------------------------------------------------


class _Strict(BaseModel):
    """Exactly the fields declared, with exactly their JSON types: what the OpenAPI schema
    says is refused is refused (no "12" for 12, no unknown key)."""

    model_config = ConfigDict(extra="forbid", strict=True)


#: Intrinsics (pixels) are checked once the image's size is known, alike on every route
#: (``sdcnet.camera.check_intrinsics``: 422 invalid_intrinsics); the schema states the part of
#: it that does not depend on the size.
FocalLength = Annotated[
    float, Field(json_schema_extra={"exclusiveMinimum": 0, "maximum": MAX_FOCAL_PX})
]
Pixels = float
_FOV = f"{MAX_FIELD_OF_VIEW_DEG:g}"


class InferParameters(_Strict):
    """Request parameters."""

    fx: FocalLength | None = Field(
        None, description=f"focal length along x, pixels (field of view < {_FOV} degrees)"
    )
    fy: FocalLength | None = Field(
        None, description=f"focal length along y, pixels (field of view < {_FOV} degrees)"
    )
    cx: Pixels | None = Field(
        None, description="principal point column, pixels, within half an image of it"
    )
    cy: Pixels | None = Field(
        None, description="principal point row, pixels, within half an image of it"
    )
    outlier_removal: bool = Field(
        False, description="statistical outlier removal on the point cloud (paper Fig. 7)"
    )
    max_sigma: Annotated[float, Field(json_schema_extra={"exclusiveMinimum": 0})] | None = Field(
        None,
        description="metres: points whose depth's 1-sigma uncertainty is above it are left "
        "out of the point cloud; depth, mask and sigma stay whole",
    )
    binary_data_output: bool = Field(
        False, description="every output as binary data unless its own binary_data says no"
    )

    def intrinsics(self) -> GivenIntrinsics:
        """The intrinsics these parameters give (pixels); the others are the default's."""
        return GivenIntrinsics(self.fx, self.fy, self.cx, self.cy)


class InputParameters(_Strict):
    binary_data_size: Annotated[int, Field(ge=0)] | None = Field(
        None, description="bytes of this input in the binary data after the JSON header"
    )


class RequestInput(_Strict):
    """One input tensor: its values in ``data`` (row-major, flat or nested) or as
    ``binary_data_size`` bytes of the binary data."""

    name: str = Field(description="gray, sparse or returns")
    shape: list[Annotated[int, Field(ge=0)]]
    datatype: str = Field(description="gray: UINT8 or UINT16; sparse, returns: FP32")
    parameters: InputParameters | None = None
    data: list[Any] | None = None


class BinaryOutputParameters(_Strict):
    binary_data: bool | None = Field(
        None, description="this output as binary data (default: binary_data_output)"
    )


class RegionOutputParameters(BinaryOutputParameters):
    region: bool = Field(
        False, description="only the smallest window holding the mask, 0 outside (sdcnet)"
    )


class DepthOutputParameters(RegionOutputParameters):
    fp16: bool = Field(
        False,
        description="FP16 residuals above the output parameter depth_offset (metres), -1 "
        "where the depth is 0; within 8 mm for a spacecraft < 32 m deep (sdcnet)",
    )


class MaskOutputParameters(RegionOutputParameters):
    bits: bool = Field(False, description="8 pixels a byte, numpy.packbits order (sdcnet)")


class DepthOutput(_Strict):
    name: Literal["depth"]
    parameters: DepthOutputParameters | None = None


class MaskOutput(_Strict):
    name: Literal["mask"]
    parameters: MaskOutputParameters | None = None


class PointsOutput(_Strict):
    name: Literal["points"]
    parameters: BinaryOutputParameters | None = None


class SigmaOutput(_Strict):
    name: Literal["sigma"]
    parameters: RegionOutputParameters | None = None


AnyOutput = DepthOutput | MaskOutput | PointsOutput | SigmaOutput
RequestOutput = Annotated[AnyOutput, Field(discriminator="name")]


class InferenceRequest(_Strict):
    """The JSON header of ``POST /v2/models/sdcnet/infer``."""

    id: str | None = Field(None, description="echoed in the answer")
    parameters: InferParameters | None = None
    inputs: list[RequestInput] = Field(description="gray, and sparse or returns")
    outputs: list[RequestOutput] | None = Field(
        None, description="depth, mask, points, sigma, each at most once (default: all four)"
    )


# -- the JSON header (answer) ----------------------------------------------------------

Scalar = bool | int | float | str


class ResponseOutput(BaseModel):
    name: str
    datatype: str
    shape: list[int]
    parameters: dict[str, Scalar] | None = Field(
        None,
        description="binary_data_size; for a compact layout region_y0, region_x0, "
        "region_height, region_width (pixels) and depth_offset (metres)",
    )
    data: list[Any] | None = None


class InferenceResponse(BaseModel):
    """The answer's JSON header; the summary of ``POST /complete`` is in ``parameters``
    (timings in milliseconds, intrinsics in pixels)."""

    model_name: str
    model_version: str
    id: str | None = None
    parameters: dict[str, Scalar]
    outputs: list[ResponseOutput]


# -- request bytes to a frame ----------------------------------------------------------


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
    datatypes, expected = INPUTS[inp.name]
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
        if inp.name not in INPUTS:
            raise _bad(f"unknown input {inp.name!r}: the inputs are {', '.join(INPUTS)}")
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


# -- a completed frame to answer bytes -------------------------------------------------


@dataclass(frozen=True)
class Tensor:
    """One output as it travels: the array, its datatype and its output parameters."""

    array: np.ndarray
    datatype: str
    parameters: dict[str, Scalar]


def output_tensor(output: AnyOutput, done: Completed) -> Tensor:
    """``output`` of a completed frame, in the layout its parameters ask for."""
    if isinstance(output, PointsOutput):
        return Tensor(done.points, "FP32", {})
    params = output.parameters
    if isinstance(output, MaskOutput):
        array = done.mask.view(np.uint8)
    else:
        array = done.depth if isinstance(output, DepthOutput) else done.sigma
    extra: dict[str, Scalar] = {}
    if params is not None and params.region:
        y0, x0, height, width = done.window
        array = crop(array, y0, x0, height, width)
        extra = {"region_y0": y0, "region_x0": x0, "region_height": height}
        extra["region_width"] = width
    if isinstance(output, SigmaOutput):
        return Tensor(array, "FP32", extra)
    if isinstance(output, DepthOutput):
        if params is not None and params.fp16:
            array, offset = fp16_residuals(array)
            return Tensor(array, "FP16", {**extra, "depth_offset": offset})
        return Tensor(array, "FP32", extra)
    if params is not None and params.bits:
        return Tensor(pack_mask(array), "UINT8", {**extra, "bits": True})
    return Tensor(array, "UINT8", extra)


def summary_parameters(summary: CompletionSummary) -> dict[str, Scalar]:
    """The summary of ``POST /complete`` as flat protocol parameters (scalars only)."""
    flat = summary.model_dump(exclude={"intrinsics", "timings", "model_version"})
    return {**flat, **summary.intrinsics.model_dump(), **summary.timings.model_dump()}


def requested_outputs(request: InferenceRequest) -> list[AnyOutput]:
    """The outputs asked for, each once (default: depth, mask, points and sigma)."""
    if request.outputs is None:
        return [
            DepthOutput(name="depth"),
            MaskOutput(name="mask"),
            PointsOutput(name="points"),
            SigmaOutput(name="sigma"),
        ]
    names = [o.name for o in request.outputs]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise _bad(f"output {', '.join(repeated)} is asked for more than once")
    if not names:
        raise _bad(
            "outputs is empty: ask for depth, mask, points or sigma, or leave it out for all"
        )
    return list(request.outputs)


#: Values written as JSON text at a time (``write_json_values``).
JSON_VALUES_STEP = 2**16


@dataclass(frozen=True)
class Output:
    """One output as it leaves: its JSON entry (``data`` aside) and its tensor, sent as
    binary data or as JSON ``data``."""

    entry: dict[str, Any]
    tensor: Tensor
    binary: bool


def encode_outputs(outputs: list[AnyOutput], done: Completed, binary_default: bool) -> list[Output]:
    """The outputs in the layouts asked for, and how each is sent."""
    encoded = []
    for output in outputs:
        tensor = output_tensor(output, done)
        asked = output.parameters.binary_data if output.parameters else None
        binary = binary_default if asked is None else asked
        entry: dict[str, Any] = {"name": output.name, "datatype": tensor.datatype}
        entry["shape"] = list(tensor.array.shape)
        parameters = dict(tensor.parameters)
        if binary:
            parameters["binary_data_size"] = tensor.array.size * DTYPES[tensor.datatype].itemsize
        if parameters:
            entry["parameters"] = parameters
        encoded.append(Output(entry, tensor, binary))
    return encoded


def write_json_values(spool: Spool, array: np.ndarray) -> None:
    """``array``'s values as a flat JSON array, ``JSON_VALUES_STEP`` at a time."""
    flat = array.reshape(-1)
    spool.write(b"[")
    for start in range(0, flat.size, JSON_VALUES_STEP):
        text = json.dumps(flat[start : start + JSON_VALUES_STEP].tolist())[1:-1]
        spool.write((", " if start else "").encode() + text.encode())
    spool.write(b"]")


def write_answer(spool: Spool, document: dict[str, Any], outputs: list[Output]) -> int:
    """The answer into ``spool``: the JSON header (``document`` and the outputs, JSON data
    written as text from the arrays, never as Python lists), then the binary data; returns
    the JSON header's length, bytes."""
    marks = [f"sdcnet-data-{uuid.uuid4().hex}" for _ in outputs]
    entries = [
        output.entry if output.binary else {**output.entry, "data": mark}
        for output, mark in zip(outputs, marks, strict=True)
    ]
    text = json.dumps({**document, "outputs": entries})
    for output, mark in zip(outputs, marks, strict=True):
        if not output.binary:
            before, text = text.split(f'"{mark}"', 1)
            spool.write(before.encode())
            write_json_values(spool, output.tensor.array)
    spool.write(text.encode())
    header_length = spool.size
    for output in outputs:
        if output.binary:
            array = np.ascontiguousarray(output.tensor.array, DTYPES[output.tensor.datatype])
            for piece in array_slices(array):
                spool.write(piece)
    return header_length


def answer(
    engine: Engine,
    body: bytes | bytearray,
    header_length: str | None,
    limits: InputLimits,
    camera: ServiceCamera | None = None,
) -> Answer:
    """Parse (into the ``camera``'s frame), complete, encode one inference request; raises
    ``ApiError`` for bad input. The encode phase times the outputs' layouts; their bytes are
    written with the header, which carries the timings."""
    timer = PhaseTimer()
    with timer("decode"):
        header, binary = split_body(body, header_length)
        parsed = parse_request(header)
        outputs = requested_outputs(parsed.request)
        frame = camera_frame(frame_of_request(parsed, binary, limits), camera)
    done = complete_frame(engine, frame, timer)
    request = parsed.request
    parameters = request.parameters or InferParameters()
    with timer("encode"):
        encoded = encode_outputs(outputs, done, parameters.binary_data_output)
    document: dict[str, Any] = {
        "model_name": MODEL_NAME,
        "model_version": engine.model.info.version,
    }
    if request.id is not None:
        document["id"] = request.id
    document["parameters"] = summary_parameters(done.summary(engine.model, timer))
    spool = Spool()
    try:
        length = write_answer(spool, document, encoded)
    except BaseException:
        spool.close()
        raise
    if not any(output.binary for output in encoded):
        return Answer(spool, timer, media_type="application/json")
    return Answer(
        spool,
        timer,
        headers={HEADER_LENGTH: str(length)},
        media_type="application/octet-stream",
    )
