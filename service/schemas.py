"""Response bodies of the service (pydantic): what /docs shows and what clients parse."""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from pydantic import BaseModel, Field

from sdcnet.caveats import CAVEATS, CROP_CUT_IOU_FACTOR, MASK_IOU_EXPONENT, UNCERTAIN_MASK_IOU
from sdcnet.stray_returns import MIN_GROUP_RETURNS, MIN_RETURNS_TO_JUDGE, STRAY_SPACINGS


class ResponseFormat(StrEnum):
    """How ``POST /complete`` answers."""

    json = "json"  # arrays as base64 of .npy bytes, in a JSON document
    npz = "npz"  # one zip: depth.npy, mask.npy, points.npy, normals.npy, sigma.npy, meta.json
    ply = "ply"  # the point cloud alone, binary little-endian PLY: x, y, z, nx, ny, nz, sigma


class ErrorDetail(BaseModel):
    location: str = Field(description="'form', 'query', 'path' or 'header'")
    field: str
    message: str


class ErrorInfo(BaseModel):
    code: str = Field(description="stable, machine-readable reason, e.g. 'no_returns'")
    message: str = Field(description="what is wrong, for a person")
    details: list[ErrorDetail] | None = Field(
        default=None, description="one entry per invalid field (request validation errors)"
    )


class ErrorBody(BaseModel):
    """The one shape of every error answer, whatever the status."""

    error: ErrorInfo


class V2ErrorBody(BaseModel):
    """The Open Inference Protocol's error answer (the v2 routes); the stable code is in the
    ``Sdcnet-Error-Code`` header."""

    error: str = Field(description="what is wrong, for a person")


class EncodedArray(BaseModel):
    dtype: str = Field(description="numpy dtype, e.g. 'float32'")
    shape: list[int]
    npy_base64: str = Field(description="base64 of the array's .npy bytes (numpy.load reads it)")


class CameraIntrinsics(BaseModel):
    fx: float = Field(description="focal length along x, pixels")
    fy: float = Field(description="focal length along y, pixels")
    cx: float = Field(description="principal point column, pixels")
    cy: float = Field(description="principal point row, pixels")


class SizedIntrinsics(CameraIntrinsics):
    """Pinhole intrinsics and the image size they are for."""

    width: int = Field(description="image width, pixels")
    height: int = Field(description="image height, pixels")


class CameraInfo(BaseModel):
    """The camera of ``sdc-serve --camera``."""

    source: str = Field(description="the camera file's name and form")
    model: str = Field(
        description="lens distortion model: pinhole (none), plumb_bob or rational_polynomial"
    )
    intrinsics: SizedIntrinsics = Field(
        description="pinhole intrinsics at the calibrated size; scaled for a frame of another "
        "size and the same aspect ratio"
    )
    distortion: list[float] = Field(
        description="OpenCV's order: k1, k2, p1, p2[, k3[, k4, k5, k6]]; empty: none"
    )
    frame: str = Field(description="the frame answers are in")


class FrameTimings(BaseModel):
    """Server-side time per phase of completing a frame, milliseconds."""

    decode_ms: float = Field(description="image and depth bytes to validated arrays")
    queue_ms: float = Field(description="waiting for the model (one inference at a time)")
    inference_ms: float = Field(description="crop, model, paste back")


class Timings(FrameTimings):
    """Server-side time per phase, milliseconds."""

    encode_ms: float = Field(description="point cloud (and outlier removal), array encoding")


class FrameSummary(BaseModel):
    """One completed frame, its arrays and timings aside."""

    model_version: str
    provider: str = Field(description="onnxruntime execution provider that ran the model")
    width: int = Field(description="image width, pixels")
    height: int = Field(description="image height, pixels")
    intrinsics: CameraIntrinsics = Field(description="used to back-project the points")
    returns: int = Field(description="LIDAR returns in the sparse map")
    stray_returns: int = Field(
        default=0,
        description="of those, returns left out as strays: in groups of fewer than "
        f"{MIN_GROUP_RETURNS}, more than {STRAY_SPACINGS:g} return spacings from any other "
        f"(a flash array's dark counts, multipath), in a frame of at least "
        f"{MIN_RETURNS_TO_JUDGE} returns",
    )
    foreground_px: int = Field(description="pixels in the mask")
    point_count: int = Field(description="points in the cloud")
    cloud_stride: int = Field(
        description="the cloud holds the mask's pixels on every cloud_stride-th row and "
        "column from the frame's first: 1, every pixel; more where the mask holds more than "
        "the service's max_points"
    )
    outliers_removed: int = Field(description="points dropped by statistical outlier removal")
    uncertain_removed: int = Field(
        description="points left out for a sigma above max_sigma (POST /pose: or above the "
        "frame's own limit)"
    )
    mask_iou_estimate: float = Field(
        ge=0.0,
        le=1.0,
        description="the IOU the mask is likely to score against the spacecraft's true "
        "outline, from the network's own foreground probability p: (sum of p on the mask / "
        f"(mask pixels + sum of p off it)) ** {MASK_IOU_EXPONENT}, times "
        f"{CROP_CUT_IOU_FACTOR} with the caveat crop_cut; below "
        f"{UNCERTAIN_MASK_IOU} the caveat mask_uncertain (docs/service.md, Caveats: how it "
        "compares with the IOU measured)",
    )
    caveats: list[str] = Field(
        description="what the mask may not hold, by code (empty: nothing known; in the Open "
        "Inference Protocol's parameters, the codes joined by commas): "
        + "; ".join(f"{code}: {meaning}" for code, meaning in CAVEATS.items())
    )


class CompletionSummary(FrameSummary):
    """Everything about one answer except its arrays (npz: meta.json)."""

    timings: Timings


class CompletionResponse(CompletionSummary):
    """``POST /complete?format=json``: the summary plus the arrays."""

    depth: EncodedArray = Field(description="float32 (H, W) metres, 0 outside the mask")
    mask: EncodedArray = Field(description="uint8 (H, W), 1 = spacecraft")
    points: EncodedArray = Field(description="float32 (N, 3) camera frame, metres")
    normals: EncodedArray = Field(
        description="float32 (N, 3): each point's unit surface normal, camera frame, facing the "
        "camera"
    )
    sigma: EncodedArray = Field(
        description="float32 (H, W) metres: the depth's 1-sigma uncertainty, 0 outside the mask"
    )


class Liveness(BaseModel):
    live: bool


class Readiness(BaseModel):
    ready: bool


class ServerMetadata(BaseModel):
    """``GET /v2``: the Open Inference Protocol's server metadata."""

    name: str
    version: str
    extensions: list[str]


class TensorMetadata(BaseModel):
    """An input or output of ``POST /v2/models/sdcnet/infer`` (Open Inference Protocol)."""

    name: str
    datatype: str = Field(description="KServe v2 datatype, e.g. 'FP32'")
    shape: list[int] = Field(description="-1 = any size")
    description: str = ""


class TargetInfo(BaseModel):
    """A known target (``sdc-serve --targets``)."""

    name: str = Field(description="its file's stem: POST /pose's `target`")
    file: str
    longest_m: float = Field(description="longest bounding-box extent, metres")
    bounds_m: list[list[float]] = Field(description="[min xyz, max xyz] in its frame, metres")
    faces: int
    symmetries: int = Field(description="self-symmetries found (turns that map it onto itself)")
    near_twins: int = Field(
        description="turns that map it almost onto itself: the returns tell those poses apart"
    )


class FrameBudgetInfo(BaseModel):
    """How the working pixels a frame gets were chosen (``sdcnet.frame_budget``)."""

    work_pixels: int = Field(description="working pixels frames get at most")
    model_work_pixels: int = Field(description="the model's own, trained and timed for")
    frame_share: float = Field(
        description="the share of a frame's budget (the network's pixels and its own work at "
        "its resolution) frames get: 1, or less on a CPU too slow for deadline_ms at all of "
        "it, where frames of large crops and many points get fewer working pixels"
    )
    deadline_ms: float = Field(
        description="the p95 in-process milliseconds held to (--frame-ms); 0: none"
    )
    reference_ms: float | None = Field(
        description="this CPU's milliseconds for the reference frame at the model's budget, "
        "measured at start-up, or implied by the p95 of the latest frames served since (see "
        "served_p95_ms); null: not measured (a fixed budget)"
    )
    expected_p95_ms: float | None = Field(
        description="the p95 frame expected at frame_share on this CPU; null: not measured"
    )
    met: bool | None = Field(
        description="whether expected_p95_ms is within deadline_ms; false: this CPU is too "
        "slow even at half the budget; null: not measured"
    )
    served_frames: int = Field(description="frames served since start-up")
    served_p95_ms: float | None = Field(
        description="p95 in-process milliseconds (the pipeline and the cloud) of the latest "
        "frames (--budget-window), from which frame_share was last chosen again; null: not "
        "yet re-read (fewer frames served, a fixed budget, or --budget-window 0)"
    )


class ModelMetadata(BaseModel):
    """``GET /model`` and ``GET /v2/models/sdcnet``: KServe v2 model metadata plus sdcnet's."""

    name: str
    versions: list[str]
    platform: str
    inputs: list[TensorMetadata]
    outputs: list[TensorMetadata]
    version: str
    provider: str
    threads: int = Field(description="onnxruntime intra-op threads")
    stride: int = Field(description="the network's input sides are padded to this many pixels")
    work_pixels: int = Field(
        description="pixels the network sees per frame at most, whatever the camera: the "
        "spacecraft's crop is resampled to about this many, fewer (down to half) where the "
        "frame's own work at its resolution is large (a large crop, many points), so that "
        "every frame keeps to one cost; the model's own unless sdc-serve --work-pixels set "
        "fewer"
    )
    frame_budget: FrameBudgetInfo = Field(
        description="how work_pixels was chosen (sdc-serve --frame-ms, --work-pixels)"
    )
    intrinsics: CameraIntrinsics = Field(
        description="the paper's camera at 1024 x 1024: requests' default when no camera is "
        "configured, scaled to each request's image size"
    )
    default_intrinsics: SizedIntrinsics = Field(
        description="what a request without fx, fy, cx, cy gets: the camera's (sdc-serve "
        "--camera), else the model's, at width x height; scaled to each request's image size"
    )
    camera: CameraInfo | None = Field(
        default=None, description="the camera of sdc-serve --camera; null: none configured"
    )
    metrics: dict[str, Any] = Field(description="the model card's headline metrics")
    limits: dict[str, int] = Field(
        description="max_pixels, max_returns, max_upload_bytes, max_points, max_in_flight, "
        "max_requests"
    )
    targets: list[TargetInfo] = Field(
        default_factory=list, description="known targets of POST /pose (sdc-serve --targets)"
    )
