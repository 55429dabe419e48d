"""One request from its validated inputs to the arrays every protocol answers, run in a
worker thread; and ``POST /complete`` from uploaded bytes to answer bytes.

decode (bytes -> validated ``Frame``: ``sdcnet.service.decode`` for the multipart form,
``sdcnet.service.v2_decode`` for the Open Inference Protocol) -> queue (wait for the model) ->
inference (``sdcnet.pipeline.complete``: crop to the LIDAR-bounded region, model, paste back)
-> encode (point cloud, optional outlier removal, then the protocol's serialisation). Each
phase is timed. ``complete_frame`` is the one path both protocols share.
"""

from __future__ import annotations

import functools
import logging
import math
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from sdcnet.camera import Intrinsics, IntrinsicsError, check_intrinsics
from sdcnet.caveats import frame_caveats
from sdcnet.compact import mask_window
from sdcnet.frame_budget import (
    WINDOW_FRAMES,
    FrameBudget,
    ServedBudget,
    answer_in_process,
    calibrate,
    fixed,
)
from sdcnet.normals import cloud_normals
from sdcnet.pipeline import Completion, Region, complete
from sdcnet.pointcloud import (
    MAX_POINTS,
    back_project,
    cloud_stride,
    statistical_outliers,
    trusted_pixels,
)
from sdcnet.runtime.interface import ModelLoadError, Runtime
from sdcnet.service.camera import ServiceCamera, camera_frame
from sdcnet.service.decode import CompletionRequest, Frame, InputLimits, decode_form
from sdcnet.service.encode import MEDIA_TYPES, encode
from sdcnet.service.errors import ApiError
from sdcnet.service.schemas import (
    CameraIntrinsics,
    CompletionSummary,
    FrameSummary,
    ResponseFormat,
    Timings,
)
from sdcnet.service.spool import Spool, SpooledResponse

logger = logging.getLogger("sdcnet.service")

PHASES = ("decode", "queue", "inference", "encode")
SELF_TEST_SIZE = 64  # pixels, side of the frame the model completes once at start-up


#: The ``Server-Timing`` header of an inference answer, for the routes' OpenAPI declarations.
SERVER_TIMING_HEADER = {
    "Server-Timing": {
        "description": "milliseconds per phase: decode, queue (for the model), inference, "
        "encode, and wait (for an in-flight place, before decode)",
        "required": True,
        "schema": {"type": "string"},
    }
}


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

    def milliseconds(self, phases: tuple[str, ...] = PHASES) -> dict[str, float]:
        """{"PHASE_ms": milliseconds} of ``phases``, to the microsecond."""
        return {f"{p}_ms": round(self.seconds.get(p, 0.0) * 1e3, 3) for p in phases}

    def timings(self) -> Timings:
        return Timings(**self.milliseconds())

    def server_timing(self, phases: tuple[str, ...] = PHASES) -> str:
        """The ``Server-Timing`` header (milliseconds), shown by browsers' developer tools."""
        return ", ".join(f"{p};dur={self.seconds.get(p, 0.0) * 1e3:.3f}" for p in phases)


class Engine:
    """The model, loaded once, run one request at a time: the runtime already spreads one
    inference over all its intra-op threads, so running two at once only makes both slower;
    the working pixels a frame gets (``frame_budget``: ``sdcnet.frame_budget``, default the
    model's own; a calibrated one re-read from the frames served, the latest
    ``budget_window``: ``ServedBudget``) and the most points a frame's cloud holds
    (``max_points``: ``sdcnet.pointcloud``)."""

    def __init__(
        self,
        model: Runtime,
        max_points: int = MAX_POINTS,
        frame_budget: FrameBudget | None = None,
        budget_window: int = WINDOW_FRAMES,
    ):
        self.model = model
        self.max_points = max_points
        own = model.info.work_pixels
        self.served_budget = ServedBudget(frame_budget or fixed(own, own), budget_window)
        self._lock = threading.Lock()

    @property
    def frame_budget(self) -> FrameBudget:
        """The budget frames get now."""
        return self.served_budget.budget

    def complete(
        self, gray: np.ndarray, sparse: np.ndarray, focal_px: float, timer: PhaseTimer
    ) -> tuple[Completion, float]:
        """Complete a frame of a camera of focal length ``focal_px`` (pixels), on the frame
        budget of the moment (``sdcnet.pipeline``): the completion, and the share of its
        budget it got."""
        with timer("queue"):
            self._lock.acquire()
        try:
            budget = self.frame_budget
            with timer("inference"):
                result = complete(
                    self.model.run,
                    gray,
                    sparse,
                    focal_px,
                    self.model.info.stride,
                    budget.work_pixels,
                    frame_share=budget.frame_share,
                )
            return result, budget.frame_share
        finally:
            self._lock.release()


def self_test(model: Runtime) -> None:
    """Complete one small synthetic frame (``SELF_TEST_SIZE`` px, one LIDAR return at 100 m)
    through the service's own pipeline; raises ``ModelLoadError`` when that fails.

    Catches a file that loads but cannot serve (the right names and metadata on a graph of
    the wrong shapes or operators) before the service says it is ready, and warms it up.
    """
    gray = np.zeros((SELF_TEST_SIZE, SELF_TEST_SIZE), np.uint8)
    sparse = np.zeros_like(gray, dtype=np.float32)
    sparse[SELF_TEST_SIZE // 2, SELF_TEST_SIZE // 2] = 100.0
    try:
        result = complete(model.run, gray, sparse, 1000.0, model.stride, model.info.work_pixels)
    except Exception as exc:  # onnxruntime and numpy raise many types; all mean "cannot serve"
        raise ModelLoadError(
            f"{model.path} loads but cannot complete a {SELF_TEST_SIZE} x {SELF_TEST_SIZE} "
            f"test frame, so it would fail every request: {type(exc).__name__}: {exc}"
        ) from exc
    for name, array in (("depth", result.depth), ("sigma", result.sigma)):
        if array is None or array.dtype != np.float32:
            kind = "no" if array is None else array.dtype
            raise ModelLoadError(f"{model.path} answers {kind} {name}, not float32")


@dataclass
class Completed:
    """One completed frame, before any protocol serialises it: the pipeline's answer
    (``completion``: depth, mask and sigma, the region the network saw, and what the points'
    normals are taken from), points float32 (N, 3) metres of the ``kept`` pixels (bool (H, W))
    on every ``stride``-th row and column, the intrinsics used, the summary's counts and the
    sigma above which points left the cloud (metres; ``None``: no limit)."""

    completion: Completion
    points: np.ndarray
    kept: np.ndarray
    stride: int
    intrinsics: Intrinsics
    returns: int
    outliers_removed: int
    uncertain_removed: int
    sigma_limit: float | None

    @property
    def depth(self) -> np.ndarray:
        """float32 (H, W) metres, 0 off the mask."""
        return self.completion.depth

    @property
    def mask(self) -> np.ndarray:
        """bool (H, W), True = spacecraft."""
        return self.completion.mask

    @property
    def sigma(self) -> np.ndarray:
        """float32 (H, W) metres: the depth's 1-sigma uncertainty, 0 off the mask (every
        served model has one: ``load_model``'s self-test)."""
        return self.completion.sigma

    @property
    def region(self) -> Region:
        """The region the network saw: everything outside it is 0."""
        return self.completion.region

    @functools.cached_property
    def normals(self) -> np.ndarray:
        """float32 (N, 3): each point's unit surface normal, camera frame, facing the camera,
        in the order of ``points`` (``sdcnet.normals``)."""
        return cloud_normals(self.completion, self.kept, self.intrinsics, stride=self.stride)

    @functools.cached_property
    def point_sigma(self) -> np.ndarray:
        """float32 (N,) metres: each point's sigma, in the order of ``points``."""
        stride = self.stride
        return self.sigma[::stride, ::stride][self.kept[::stride, ::stride]]

    @functools.cached_property
    def window(self) -> tuple[int, int, int, int]:
        """(y0, x0, height, width): the smallest window holding the mask, outside which depth
        and mask are 0 (``sdcnet.compact.mask_window``, searched within the region)."""
        return mask_window(self.mask[self.region.slices], self.region.y0, self.region.x0)

    def frame_summary(self, model: Runtime) -> FrameSummary:
        """The frame's summary without timings (``POST /pose``'s ``completion``)."""
        K = self.intrinsics
        return FrameSummary(
            model_version=model.info.version,
            provider=model.provider,
            width=K.width,
            height=K.height,
            intrinsics=CameraIntrinsics(**K.pinhole_dict()),
            returns=self.returns,
            stray_returns=self.completion.stray_returns,
            foreground_px=int(np.count_nonzero(self.mask)),
            point_count=len(self.points),
            cloud_stride=self.stride,
            outliers_removed=self.outliers_removed,
            uncertain_removed=self.uncertain_removed,
            mask_iou_estimate=self.completion.mask_iou_estimate,
            caveats=frame_caveats(self.completion, self.returns),
        )

    def summary(self, model: Runtime, timer: PhaseTimer) -> CompletionSummary:
        """The completion protocols' summary: the frame's, and the timings."""
        return CompletionSummary(**dict(self.frame_summary(model)), timings=timer.timings())


def request_intrinsics(default: Intrinsics, width: int, height: int, frame: Frame) -> Intrinsics:
    """The request's intrinsics; each value not given is the configured camera's
    (``frame.camera``, at the image's size), else the model's ``default`` scaled to the
    image (a focal length given alone keeps that camera's pixel aspect:
    ``GivenIntrinsics.over``). 422 ``invalid_intrinsics`` for values that cannot describe the frame
    (``sdcnet.camera.check_intrinsics``, the one check of every route)."""
    K = frame.intrinsics.over(frame.camera or default.scaled(width, height))
    try:
        return check_intrinsics(K)
    except IntrinsicsError as exc:
        raise ApiError(422, "invalid_intrinsics", str(exc)) from None


def complete_frame(
    engine: Engine,
    frame: Frame,
    timer: PhaseTimer,
    cloud_phase: str = "encode",
    sigma_quantile: float | None = None,
) -> Completed:
    """Complete a validated frame (queue, inference) and back-project its points (timed as
    ``cloud_phase``): the pixels whose sigma is within the limit (``trusted_pixels``: the frame's
    ``max_sigma``, else its ``sigma_quantile`` when given), then the optional outlier removal
    on those, and of those the pixels on every k-th row and column where they are more than
    the engine's ``max_points`` (``cloud_stride``). What every protocol answers from, and what
    ``POST /pose`` registers. The frame's in-process milliseconds (the pipeline and the cloud)
    go to the engine's budget, which the latest frames' re-read (``ServedBudget``)."""
    height, width = frame.gray.shape
    K = request_intrinsics(engine.model.info.intrinsics, width, height, frame)
    result, share = engine.complete(frame.gray, frame.sparse, K.fx, timer)
    cloud_start = time.perf_counter()
    with timer(cloud_phase):
        depth, sigma = result.depth, result.sigma
        valid = result.mask & (depth > 0)
        trusted, limit = trusted_pixels(valid, sigma, frame.max_sigma, sigma_quantile)
        kept = statistical_outliers(depth, trusted, K) if frame.outlier_removal else trusted
        stride = cloud_stride(kept, engine.max_points)
        points = back_project(depth, kept, K, stride=stride)
        trusted_count = int(np.count_nonzero(trusted))
    in_process_s = timer.seconds["inference"] + time.perf_counter() - cloud_start
    engine.served_budget.observe(in_process_s * 1e3, share)
    return Completed(
        completion=result,
        points=points,
        kept=kept,
        stride=stride,
        intrinsics=K,
        returns=int(np.count_nonzero(frame.sparse)),
        outliers_removed=trusted_count - int(np.count_nonzero(kept)),
        uncertain_removed=int(np.count_nonzero(valid)) - trusted_count,
        sigma_limit=limit,
    )


def warm_up_frame(side: int) -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """(gray uint16, sparse metres, intrinsics) of a ``side`` x ``side`` frame that is all
    spacecraft, lit along a slope, with a return on every pixel at about 10 m: the most work and
    memory a frame of that side can ask of the pipeline."""
    slope = np.linspace(-1.0, 1.0, side, dtype=np.float32)[None, :]
    gray = np.broadcast_to((20000 + 10000 * slope).astype(np.uint16), (side, side)).copy()
    sparse = np.broadcast_to(10.0 + 0.5 * slope, (side, side)).astype(np.float32)
    centre = side / 2
    return gray, sparse, Intrinsics(1000.0, 1000.0, centre, centre, side, side)


def warm_up(model: Runtime, side: int, max_points: int = MAX_POINTS) -> None:
    """Answer two synthetic frames before the first request, not during it: one of ``side`` x
    ``side`` pixels (the largest the service accepts) that asks the most a frame of that side
    can (``warm_up_frame``), so that the allocator's heap grows to the full-resolution maps and
    every page of it is touched; one as large as the model's working budget, so that
    onnxruntime's arena grows to it (a frame as large as the first gets fewer working pixels:
    ``sdcnet.pipeline.frame_work_pixels``). Each is answered whole (``answer_in_process``: the
    pipeline, the cloud of at most ``max_points`` as the service's requests, and its normals).
    After a dark frame of sparse returns, or a lit one of a return every second pixel, the
    first 2048 x 2048 frames took 3-4 times a warm frame's milliseconds, the memory they wrote
    faulting in (``benchmarks.first_frames``; docs/development.md, "Measurements"). About 1.3
    s at 2048 px on two cores, longer on the process's first memory."""
    for frame_side in (side, math.isqrt(model.info.work_pixels)):
        gray, sparse, K = warm_up_frame(frame_side)
        answer_in_process(
            model.run, gray, sparse, K, model.stride, model.info.work_pixels, max_points=max_points
        )


def choose_frame_budget(model: Runtime, work_pixels: int | None, frame_ms: float) -> FrameBudget:
    """The budget the service's frames get: ``work_pixels`` working pixels at most when set
    (at most the model's own), else the model's own budget, a share of it where this CPU is
    too slow to keep its p95 frame within ``frame_ms`` (``sdcnet.frame_budget.calibrate``:
    about 0.5 s on two cores), or, for ``frame_ms`` 0, all of it unmeasured;
    ``ModelLoadError`` for more pixels than the model's."""
    own = model.info.work_pixels
    if work_pixels is not None:
        try:
            return fixed(work_pixels, own)
        except ValueError as exc:
            raise ModelLoadError(f"{model.path}: {exc}") from None
    if frame_ms == 0:
        return fixed(own, own)
    chosen = calibrate(model.run, model.stride, own, frame_ms)
    if not chosen.met:
        logger.warning(
            "this CPU completes the reference frame in %.0f ms: even at %.2f of their budget, "
            "frames are expected to take %.0f ms at p95, over --frame-ms %g",
            chosen.reference_ms,
            chosen.frame_share,
            chosen.expected_p95_ms,
            frame_ms,
        )
    return chosen


@dataclass(frozen=True)
class Answer:
    """What every inference route answers: its body (spooled), media type and extra headers,
    the time each phase took and the phases its ``Server-Timing`` names."""

    body: Spool
    timer: PhaseTimer
    headers: dict[str, str] = field(default_factory=dict)
    media_type: str = "application/octet-stream"
    phases: tuple[str, ...] = PHASES

    def response(self) -> SpooledResponse:
        """The answer to send, its ``Server-Timing`` first among its headers."""
        headers = {"Server-Timing": self.timer.server_timing(self.phases), **self.headers}
        return SpooledResponse(self.body, self.media_type, headers)


def answer(
    engine: Engine,
    req: CompletionRequest,
    limits: InputLimits,
    camera: ServiceCamera | None = None,
) -> Answer:
    """Decode (into the ``camera``'s frame), complete, encode one ``POST /complete``; raises
    ``ApiError`` for bad input."""
    timer = PhaseTimer()
    with timer("decode"):
        frame = camera_frame(decode_form(req, limits), camera)
    done = complete_frame(engine, frame, timer)
    spool = Spool()
    try:
        with timer("encode"):
            encoded = encode(req.format, done, done.frame_summary(engine.model), spool)
        encoded.finish(done.summary(engine.model, timer))
    except BaseException:
        spool.close()
        raise
    headers = {}
    if req.format is not ResponseFormat.json:
        headers["Content-Disposition"] = f'attachment; filename="sdcnet.{req.format.value}"'
    return Answer(spool, timer, headers, MEDIA_TYPES[req.format])
