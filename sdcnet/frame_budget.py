"""A frame's budget on this machine: the model's own, or a share of it where this CPU is too
slow to answer every frame within the LIDAR's period.

A model file carries the working pixels it was trained and timed for (``work_pixels``, chosen
on the AMD EPYC docs/benchmarks.md names, where the robustness suite's p95 frame took 78-87
ms), and each frame's budget follows from it (``sdcnet.pipeline.frame_work_pixels``: the
network's pixels and the frame's own work at its resolution together). On a slower CPU the
same frames take longer: on an Intel Xeon of two cores that p95 was 102-115 ms
(docs/development.md, "Measurements"). So the service measures its CPU once, at start-up
(``calibrate``), and gives frames a share of their budget (``frame_share``): the network
still sees up to all its pixels where a frame's own work is small, and the frames of large
crops and many points, the slowest, get fewer.

- the suite's p95 frame, on the CPU the constants were measured on, takes about
  ``SUITE_P95_MS[0] + SUITE_P95_MS[1] * share`` milliseconds at a share of the budget
  (``python -m benchmarks.pipeline_latency --shares``);
- a synthetic frame (``reference_frame``: a lit disc, returns on a grid across it), completed,
  back-projected and given its normals as every answer is, tells how much slower or faster
  this CPU is than that one (its milliseconds over ``REFERENCE_MS``, the same frame's there);
- the share is the largest whose p95, so scaled, is within ``DEADLINE_SHARE`` of the
  deadline, at most 1 and at least ``MIN_SHARE``: a CPU slower than that misses the deadline,
  and ``FrameBudget.met`` says so.

One reference frame at one moment is a rough reading: on an Intel Xeon whose reference frame
took 87-92 ms, the suite's p95 frame at the share so chosen took 101 ms where 90 were expected
(docs/development.md, "Measurements"), and a machine's speed changes with what else runs on
it. So the served frames themselves re-read it (``ServedBudget``): every few frames, the p95
of the latest frames' milliseconds, each scaled by the share it was served at, stands for the
reference frame's (``implied_reference_ms``), and the share is chosen again from it; the share
then holds the p95 of the frames this service is sent, whatever their mix.
"""

from __future__ import annotations

import logging
import statistics
import threading
import time
from collections import deque
from dataclasses import asdict, dataclass, replace

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.normals import cloud_normals
from sdcnet.pipeline import ModelFn, complete
from sdcnet.pointcloud import MAX_POINTS, back_project, cloud_stride

#: The robustness suite's p95 frame, milliseconds, as ``a + b * share`` of the frames' budget,
#: and the reference frame's milliseconds at the whole budget, on one CPU (docs/development.md,
#: "Measurements").
SUITE_P95_MS = (34.9, 71.7)
REFERENCE_MS = 89.0
#: Share of the deadline the expected p95 is held to: the rest is the machine's noise.
DEADLINE_SHARE = 0.9
#: Least share of the frames' budget a calibration chooses: a frame whose own work is small
#: still gets 0.7 of the network's pixels, one whose work is large a quarter of them.
MIN_SHARE = 0.5
#: Side of the reference frame, pixels; the disc's radius, the returns' spacing (pixels) and
#: their depth (metres) ...
REFERENCE_SIDE = 1024
REFERENCE_RADIUS = 300
REFERENCE_RETURN_STEP = 8
REFERENCE_DEPTH_M = 20.0
#: ... and the focal length it is seen with (pixels).
REFERENCE_FOCAL_PX = 1000.0
#: Timed runs of the reference frame (their median counts), after one untimed run.
REPEATS = 5
logger = logging.getLogger(__name__)

#: Served frames whose milliseconds the share is re-read from, the latest (``ServedBudget``;
#: ``sdc-serve --budget-window``): at 10 Hz, the last 6.4 s. It is re-read every quarter of
#: them.
WINDOW_FRAMES = 64
#: Most a share rises at one re-reading (falling, it goes at once): frames read at a small
#: share can understate what a large one costs them (an earth frame at 0.50 took 50.6 ms, at
#: 0.94 105.3), so the share climbs in steps that the next frames re-read.
MAX_RISE = 0.1
#: A re-read share this far from the one before is logged (as is a deadline newly missed or
#: met again).
LOGGED_CHANGE = 0.05


@dataclass(frozen=True)
class FrameBudget:
    """What frames get: at most ``work_pixels`` working pixels (the model's own
    ``model_work_pixels`` unless an operator set fewer) and ``frame_share`` of a frame's budget
    (``sdcnet.pipeline.frame_work_pixels``); and how the share was chosen: the deadline
    (``deadline_ms``; 0 when none was set), the reference frame's milliseconds at the whole
    budget on this CPU (timed at start-up, or implied by the served frames since), the suite's
    p95 frame expected at that share (``expected_p95_ms``) and whether it is within the
    deadline (None when nothing was measured); the frames served so far (``served_frames``)
    and the p95 milliseconds of the latest ones the share was last re-read from
    (``served_p95_ms``, None before the first re-reading)."""

    work_pixels: int
    model_work_pixels: int
    frame_share: float = 1.0
    deadline_ms: float = 0.0
    reference_ms: float | None = None
    expected_p95_ms: float | None = None
    met: bool | None = None
    served_frames: int = 0
    served_p95_ms: float | None = None

    def describe(self) -> dict:
        """Plain values (JSON-ready)."""
        return asdict(self)


def fixed(work_pixels: int, model_work_pixels: int) -> FrameBudget:
    """The budget of ``work_pixels`` working pixels at most, set by the operator (or the
    model's own), whole: not measured."""
    if not 0 < work_pixels <= model_work_pixels:
        raise ValueError(
            f"work_pixels must be between 1 and the model's {model_work_pixels}, not {work_pixels}"
        )
    return FrameBudget(work_pixels, model_work_pixels)


def reference_frame() -> tuple[np.ndarray, np.ndarray, Intrinsics]:
    """(gray uint8, sparse metres, intrinsics): a lit disc of ``REFERENCE_RADIUS`` pixels in a
    ``REFERENCE_SIDE`` square frame, shaded along a slope, with returns every
    ``REFERENCE_RETURN_STEP`` pixels on it at about ``REFERENCE_DEPTH_M``. Deterministic."""
    side, radius = REFERENCE_SIDE, REFERENCE_RADIUS
    rows, cols = np.mgrid[0:side, 0:side].astype(np.float32)
    centre = side / 2
    disc = (rows - centre) ** 2 + (cols - centre) ** 2 <= radius**2
    slope = (cols - centre) / radius  # -1 .. 1 across the disc
    gray = np.where(disc, 120 + 60 * slope, 0).astype(np.uint8)
    depth = np.where(disc, REFERENCE_DEPTH_M + 2.0 * slope, 0).astype(np.float32)
    sparse = np.zeros_like(depth)
    step = REFERENCE_RETURN_STEP
    sparse[::step, ::step] = depth[::step, ::step]
    K = Intrinsics(REFERENCE_FOCAL_PX, REFERENCE_FOCAL_PX, centre, centre, side, side)
    return gray, sparse, K


def answer_in_process(
    model_fn: ModelFn,
    gray: np.ndarray,
    sparse: np.ndarray,
    K: Intrinsics,
    stride: int,
    work_pixels: int,
    frame_share: float = 1.0,
    max_points: int = MAX_POINTS,
) -> None:
    """A frame's whole in-process answer, what the deadline holds: the pipeline at
    ``work_pixels`` and ``frame_share``, the cloud of at most ``max_points`` (the service's
    default) and its normals (the service's work between decoding and encoding)."""
    result = complete(model_fn, gray, sparse, K.fx, stride, work_pixels, frame_share=frame_share)
    valid = result.mask & (result.depth > 0)
    step = cloud_stride(valid, max_points)
    back_project(result.depth, valid, K, stride=step)
    cloud_normals(result, valid, K, stride=step)


def frame_milliseconds(model_fn: ModelFn, stride: int, work_pixels: int) -> float:
    """Median milliseconds of the reference frame's whole answer (``answer_in_process``) at
    ``work_pixels``, over ``REPEATS`` runs after one untimed run."""
    gray, sparse, K = reference_frame()
    answer_in_process(model_fn, gray, sparse, K, stride, work_pixels)
    times = []
    for _ in range(REPEATS):
        start = time.perf_counter()
        answer_in_process(model_fn, gray, sparse, K, stride, work_pixels)
        times.append((time.perf_counter() - start) * 1e3)
    return statistics.median(times)


def share_within(reference_ms: float, deadline_ms: float) -> float:
    """The share of the frames' budget (``MIN_SHARE`` to 1) whose expected p95 on a CPU that
    completes the reference frame in ``reference_ms`` (``expected_p95_ms``) is within
    ``DEADLINE_SHARE`` of ``deadline_ms``."""
    a, b = SUITE_P95_MS
    share = (DEADLINE_SHARE * deadline_ms * REFERENCE_MS / reference_ms - a) / b
    return float(min(1.0, max(MIN_SHARE, share)))


def expected_p95_ms(reference_ms: float, share: float) -> float:
    """The suite's p95 frame, milliseconds, at ``share`` of the frames' budget on a CPU that
    completes the reference frame in ``reference_ms``."""
    a, b = SUITE_P95_MS
    return reference_ms / REFERENCE_MS * (a + b * share)


def budget_at(
    reference_ms: float, model_work_pixels: int, deadline_ms: float, most: float = 1.0
) -> FrameBudget:
    """The budget of a CPU that completes the reference frame in ``reference_ms``: the share
    within the deadline (``share_within``), at most ``most``, and the p95 expected at it."""
    share = min(share_within(reference_ms, deadline_ms), most)
    expected = expected_p95_ms(reference_ms, share)
    return FrameBudget(
        work_pixels=model_work_pixels,
        model_work_pixels=model_work_pixels,
        frame_share=round(share, 4),
        deadline_ms=deadline_ms,
        reference_ms=round(reference_ms, 3),
        expected_p95_ms=round(expected, 3),
        met=expected <= deadline_ms,
    )


def calibrate(
    model_fn: ModelFn, stride: int, model_work_pixels: int, deadline_ms: float
) -> FrameBudget:
    """The budget that keeps this machine's p95 frame within ``deadline_ms``: the reference
    frame timed at the whole budget (about 0.5 s on two cores), then ``budget_at``."""
    reference_ms = frame_milliseconds(model_fn, stride, model_work_pixels)
    return budget_at(reference_ms, model_work_pixels, deadline_ms)


def implied_reference_ms(ms: float, share: float) -> float:
    """The reference frame's milliseconds on a CPU whose suite p95 frame takes ``ms`` at
    ``share`` of the budget: ``expected_p95_ms`` the other way round."""
    a, b = SUITE_P95_MS
    return ms * REFERENCE_MS / (a + b * share)


class ServedBudget:
    """A calibrated budget (``calibrate``) re-read from the frames served with it: every
    ``window // 4`` frames, the p95 of the latest ``window`` frames' in-process milliseconds,
    each as the reference frame's it implies at the share it was served at
    (``implied_reference_ms``), chooses the share again (``budget_at``), up by at most
    ``MAX_RISE`` at a time, down as far as it takes. A budget not measured
    (``fixed``: an operator's working pixels, or no deadline) and a ``window`` of 0 hold as
    they are. Safe to call from the service's threads at once."""

    def __init__(self, budget: FrameBudget, window: int = WINDOW_FRAMES):
        if window < 0:
            raise ValueError(f"window must be 0 (never re-read) or more frames, not {window}")
        self._budget = budget
        self._adapts = window > 0 and budget.reference_ms is not None and budget.deadline_ms > 0
        self.window = window
        #: Frames between two re-readings.
        self.every = max(1, window // 4)
        self._latest: deque[tuple[float, float]] = deque(maxlen=max(window, 1))
        self._lock = threading.Lock()

    @property
    def budget(self) -> FrameBudget:
        """The budget frames get now."""
        return self._budget

    def observe(self, milliseconds: float, share: float) -> None:
        """Count one served frame that took ``milliseconds`` in process at ``share`` of its
        budget, and re-read the share when its turn comes."""
        with self._lock:
            budget = self._budget
            served = budget.served_frames + 1
            if not self._adapts:
                self._budget = replace(budget, served_frames=served)
                return
            self._latest.append((milliseconds, implied_reference_ms(milliseconds, share)))
            if served % self.every or len(self._latest) < self.every:
                self._budget = replace(budget, served_frames=served)
                return
            served_ms, implied = np.array(self._latest).T
            reference_ms = float(np.percentile(implied, 95))
            most = budget.frame_share + MAX_RISE
            chosen = budget_at(reference_ms, budget.model_work_pixels, budget.deadline_ms, most)
            p95 = round(float(np.percentile(served_ms, 95)), 3)
            self._budget = replace(chosen, served_frames=served, served_p95_ms=p95)
        moved = abs(chosen.frame_share - budget.frame_share) >= LOGGED_CHANGE
        if moved or chosen.met != budget.met:
            logger.info(
                "frames now get %.2f of their budget (was %.2f): the latest %d frames' p95 "
                "%.1f ms; %.1f ms expected at p95 for --frame-ms %g",
                chosen.frame_share,
                budget.frame_share,
                len(served_ms),
                p95,
                chosen.expected_p95_ms,
                chosen.deadline_ms,
            )
