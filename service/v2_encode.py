"""A completed frame to the answer bytes of the Open Inference Protocol: each output asked for
in its layout (full frame, or sdcnet's compact ones: ``sdcnet.compact``), then the JSON header
with the summary of ``POST /complete`` as its parameters, then the outputs sent as binary data.
JSON ``data`` is written from the arrays as text, never through Python lists.
"""

from __future__ import annotations

import json
import uuid
from dataclasses import dataclass
from typing import Any

import numpy as np

from sdcnet.caveats import as_text
from sdcnet.compact import crop, fp16_residuals, pack_mask
from sdcnet.formats.v2 import DTYPES
from sdcnet.service.encode import array_slices
from sdcnet.service.inference import Completed
from sdcnet.service.schemas import CompletionSummary
from sdcnet.service.spool import Spool
from sdcnet.service.v2_schemas import (
    AnyOutput,
    DepthOutput,
    MaskOutput,
    NormalsOutput,
    PointsOutput,
    Scalar,
    SigmaOutput,
)


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
    if isinstance(output, NormalsOutput):
        return Tensor(done.normals, "FP32", {})
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
    flat = summary.model_dump(exclude={"intrinsics", "timings", "model_version", "caveats"})
    flat["caveats"] = as_text(summary.caveats)
    return {**flat, **summary.intrinsics.model_dump(), **summary.timings.model_dump()}


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
