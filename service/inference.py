"""One ``POST /complete`` from uploaded bytes to answer bytes, run in a worker thread.

decode (bytes -> validated arrays) -> queue (wait for the model) -> inference
(``sdcnet.pipeline.complete``: crop to the LIDAR-bounded region, model, paste back) ->
encode (point cloud, optional outlier removal, serialisation). Each phase is timed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.pipeline import Completion, complete
from sdcnet.pointcloud import back_project, statistical_outliers
from sdcnet.runtime import ModelLoadError, OnnxModel
from sdcnet.service.decode import check_same_size, decode_gray, decode_sparse
from sdcnet.service.encode import encode
from sdcnet.service.schemas import CameraIntrinsics, CompletionSummary, ResponseFormat, Timings

PHASES = ("decode", "queue", "inference", "encode")
SELF_TEST_SIZE = 64  # pixels, side of the frame the model completes once at start-up


class PhaseTimer:
    """Seconds spent per named phase."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, phase: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[phase] = self.seconds.get(phase, 0.0) + time.perf_counter() - start

    def timings(self) -> Timings:
        return Timings(**{f"{p}_ms": round(self.seconds.get(p, 0.0) * 1e3, 3) for p in PHASES})

    def server_timing(self, phases: tuple[str, ...] = PHASES) -> str:
        """The ``Server-Timing`` header (milliseconds), shown by browsers' developer tools."""
        return ", ".join(f"{p};dur={self.seconds.get(p, 0.0) * 1e3:.3f}" for p in phases)


class Engine:
    """The model, loaded once, run one request at a time: onnxruntime already spreads one
    inference over all its intra-op threads, so running two at once only makes both slower."""

    def __init__(self, model: OnnxModel):
        self.model = model
        self._lock = threading.Lock()

    def complete(
        self, gray: np.ndarray, sparse: np.ndarray, zoom: float, timer: PhaseTimer
    ) -> Completion:
        """Complete a frame, its crop resampled by ``zoom`` to the model's pixel scale."""
        with timer("queue"):
            self._lock.acquire()
        try:
            with timer("inference"):
                return complete(self.model.run, gray, sparse, self.model.stride, zoom=zoom)
        finally:
            self._lock.release()


def self_test(model: OnnxModel) -> None:
    """Complete one small synthetic frame (``SELF_TEST_SIZE`` px, one LIDAR return at 100 m)
    through the service's own pipeline; raises ``ModelLoadError`` when that fails.

    Catches a file that loads but cannot serve (the right names and metadata on a graph of
    the wrong shapes or operators) before the service says it is ready, and warms it up.
    """
    gray = np.zeros((SELF_TEST_SIZE, SELF_TEST_SIZE), np.uint8)
    sparse = np.zeros_like(gray, dtype=np.float32)
    sparse[SELF_TEST_SIZE // 2, SELF_TEST_SIZE // 2] = 100.0
    try:
        result = complete(model.run, gray, sparse, model.stride)
    except Exception as exc:  # onnxruntime and numpy raise many types; all mean "cannot serve"
        raise ModelLoadError(
            f"{model.path} loads but cannot complete a {SELF_TEST_SIZE} x {SELF_TEST_SIZE} "
            f"test frame, so it would fail every request: {type(exc).__name__}: {exc}"
        ) from exc
    if result.depth.dtype != np.float32:
        raise ModelLoadError(f"{model.path} answers {result.depth.dtype} depth, not float32")


@dataclass(frozen=True)
class CompletionRequest:
    """The fields of one request; intrinsics in pixels, ``None`` = the model's, scaled."""

    gray: bytes
    sparse: bytes
    depth_scale: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    outlier_removal: bool = False
    format: ResponseFormat = ResponseFormat.json


@dataclass(frozen=True)
class Answer:
    body: bytes
    timer: PhaseTimer


def request_intrinsics(
    default: Intrinsics, width: int, height: int, req: CompletionRequest
) -> Intrinsics:
    """The request's intrinsics; each value not given is the model's, scaled to the image."""
    base = default.scaled(width, height)
    return Intrinsics(
        base.fx if req.fx is None else req.fx,
        base.fy if req.fy is None else req.fy,
        base.cx if req.cx is None else req.cx,
        base.cy if req.cy is None else req.cy,
        width,
        height,
    )


#: Widest resampling to the model's pixel scale (model fx / image fx) the service applies.
MAX_ZOOM = 4.0


def pixel_scale(model_fx: float, fx: float, pixels: int, max_pixels: int) -> float:
    """How much to resample the crop so its pixels match the model's (model fx / image fx),
    kept within [1/MAX_ZOOM, MAX_ZOOM] and so that the resampled frame stays under
    ``max_pixels``: odd intrinsics degrade the answer, never the service."""
    zoom = model_fx / fx
    return float(np.clip(zoom, 1 / MAX_ZOOM, min(MAX_ZOOM, (max_pixels / pixels) ** 0.5)))


@dataclass(frozen=True)
class CompletedFrame:
    """One request's frame, decoded and completed: what ``POST /complete`` encodes and
    ``POST /pose`` registers."""

    sparse: np.ndarray  # (H, W) float32 metres, the request's LIDAR returns
    result: Completion
    intrinsics: Intrinsics


def complete_request(
    engine: Engine, req: CompletionRequest, max_pixels: int, timer: PhaseTimer
) -> CompletedFrame:
    """Decode and complete one request; raises ``ApiError`` for bad input."""
    with timer("decode"):
        gray = decode_gray(req.gray, max_pixels)
        sparse = decode_sparse(req.sparse, req.depth_scale, max_pixels)
        check_same_size(gray, sparse)
    height, width = gray.shape
    K = request_intrinsics(engine.model.info.intrinsics, width, height, req)
    zoom = pixel_scale(engine.model.info.intrinsics.fx, K.fx, width * height, max_pixels)
    return CompletedFrame(sparse, engine.complete(gray, sparse, zoom, timer), K)


def completed_cloud(frame: CompletedFrame, outlier_removal: bool) -> tuple[np.ndarray, int]:
    """(points (N, 3) camera frame, metres; how many the outlier removal dropped)."""
    result, K = frame.result, frame.intrinsics
    valid = result.mask & (result.depth > 0)
    kept = statistical_outliers(result.depth, valid, K) if outlier_removal else valid
    points = back_project(result.depth, kept, K)
    return points, int(np.count_nonzero(valid)) - len(points)


def frame_summary(
    engine: Engine, frame: CompletedFrame, point_count: int, outliers_removed: int
) -> dict:
    """The fields of ``FrameSummary`` for one completed frame."""
    height, width = frame.sparse.shape
    K = frame.intrinsics
    return {
        "model_version": engine.model.info.version,
        "provider": engine.model.provider,
        "width": width,
        "height": height,
        "intrinsics": CameraIntrinsics(fx=K.fx, fy=K.fy, cx=K.cx, cy=K.cy),
        "returns": int(np.count_nonzero(frame.sparse)),
        "foreground_px": int(np.count_nonzero(frame.result.mask)),
        "point_count": point_count,
        "outliers_removed": outliers_removed,
    }


def answer(engine: Engine, req: CompletionRequest, max_pixels: int) -> Answer:
    """Decode, complete, encode one request; raises ``ApiError`` for bad input."""
    timer = PhaseTimer()
    frame = complete_request(engine, req, max_pixels, timer)
    with timer("encode"):
        points, removed = completed_cloud(frame, req.outlier_removal)
        mask = frame.result.mask.astype(np.uint8)
        encoded = encode(req.format, frame.result.depth, mask, points)
    summary = CompletionSummary(
        **frame_summary(engine, frame, len(points), removed), timings=timer.timings()
    )
    return Answer(encoded.finish(summary), timer)
