"""The Open Inference Protocol's data models for ``POST /v2/models/sdcnet/infer``: the tensors
it takes and answers, and its JSON header, request and answer (pydantic; the request's JSON
schema is the route's OpenAPI request body). Decoded by ``sdcnet.service.v2_decode``, answered
by ``sdcnet.service.v2_encode``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from sdcnet.camera import MAX_FIELD_OF_VIEW_DEG, MAX_FOCAL_PX, GivenIntrinsics

PROTOCOL_INPUTS = {
    "gray": (("UINT8", "UINT16"), (-1, -1)),
    "sparse": (("FP32",), (-1, -1)),
    "returns": (("FP32",), (-1, 3)),
}
#: output name -> (datatype, shape) in the full-frame layout
PROTOCOL_OUTPUTS = {
    "depth": ("FP32", (-1, -1)),
    "mask": ("UINT8", (-1, -1)),
    "points": ("FP32", (-1, 3)),
    "normals": ("FP32", (-1, 3)),
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


class NormalsOutput(_Strict):
    name: Literal["normals"]
    parameters: BinaryOutputParameters | None = None


AnyOutput = DepthOutput | MaskOutput | PointsOutput | NormalsOutput | SigmaOutput
RequestOutput = Annotated[AnyOutput, Field(discriminator="name")]


class InferenceRequest(_Strict):
    """The JSON header of ``POST /v2/models/sdcnet/infer``."""

    id: str | None = Field(None, description="echoed in the answer")
    parameters: InferParameters | None = None
    inputs: list[RequestInput] = Field(description="gray, and sparse or returns")
    outputs: list[RequestOutput] | None = Field(
        None,
        description="depth, mask, points, normals, sigma, each at most once (default: all five)",
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
