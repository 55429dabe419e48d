"""``estimate_pose``: the stages run in turn on one observed cloud (steps 1-2: ``search``,
3: ``observed``, 4: ``choice``), and the answer.

With an initial pose (tracking), steps 1-3 become one GICP refinement from it, then step 4
on it alone (its symmetric twins scored, not refined); if the refinement leaves the target
explaining the cloud poorly, or the returns lie off the target at it, the global search runs
after all, and the init's refined pose stays the answer unless another is more consistent by
``leave_init_margin`` and fits well
(``reliable_min_consistency``), then unless another fits the returns clearly better: a
tracker is not moved to a symmetric twin that fits as well, nor to a pose that fits poorly
too. An answer outside the init's basin (``init_basin_deg``, ``init_basin_of_longest``) is
not ``tracked``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.registration.choice import choose_searched, choose_tracked, polished
from sdcnet.registration.config import RegistrationConfig
from sdcnet.registration.covariance import covariance
from sdcnet.registration.observed import evenly, observe, span_m, thinned_to
from sdcnet.registration.refine import Hypothesis, refine_dense
from sdcnet.registration.search import search, seeded_by_returns
from sdcnet.registration.target import TargetModel, surface_fit
from sdcnet.registration.verdict import Evidence, judge
from sdcnet.rigid import Pose, pose_errors


@dataclass
class PoseEstimate:
    """The answer of ``estimate_pose``."""

    pose: Pose
    fitness: float  # share of the (downsampled) cloud within the inlier distance of the target
    rmse_m: float  # RMS distance of those inliers to the target's surface
    returns_rmse_m: float | None  # same for the LIDAR returns, when given
    converged: bool  # the last GICP met its convergence criteria
    consistency: float  # 0..1, step 3: ``sdcnet.registration.observed``
    covariance: np.ndarray  # (6, 6): rotation vector (rad, camera frame), then t (metres)
    ambiguous: bool
    alternatives: list[Hypothesis]
    hypotheses: int  # poses refined (1 when tracking held)
    tracked: bool  # from the initial pose, and still in its basin
    verdict: str  # "reliable", "ambiguous" or "unreliable": see ``judge``
    reasons: list[str]  # why it is not "reliable" (``REASONS``); empty when it is
    runner_up_consistency: float | None  # the best other pose's (>= alternative_deg away)
    points: int  # of the downsampled cloud registered
    returns: int  # LIDAR returns refined on (0: none)
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def rotation_sigma_deg(self) -> float:
        """Standard deviation of the rotation along its least certain axis, degrees."""
        return rotation_sigma_deg(self.covariance)

    @property
    def translation_sigma_m(self) -> float:
        """Standard deviation of t along its least certain axis, metres."""
        return _largest_deviation(self.covariance[3:, 3:])


def rotation_sigma_deg(covariance: np.ndarray) -> float:
    """Standard deviation (degrees) of the rotation along its least certain axis, of a pose's
    (6, 6) ``covariance`` (rotation vector in radians first)."""
    return float(np.degrees(_largest_deviation(covariance[:3, :3])))


def _largest_deviation(block: np.ndarray) -> float:
    """The square root of the largest eigenvalue of a (3, 3) covariance block; infinite when
    the covariance is not finite (a singular Hessian: the pose is free along some axis)."""
    if not np.all(np.isfinite(block)):
        return float("inf")
    return float(np.sqrt(max(np.linalg.eigvalsh(block)[-1], 0)))


class UnusableCloudError(ValueError):
    """The cloud cannot be registered: ``code`` "too_few_points", "too_large" (it spans far
    more than the target: wrong intrinsics, or not this target) or "no_pose" (diverged)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def in_basin(model: TargetModel, pose: Pose, init: Pose) -> bool:
    """Whether ``pose`` lies in the basin of ``init``: within ``init_basin_deg`` of its
    rotation and ``init_basin_of_longest`` x L of its translation."""
    config = model.config
    rotation_deg, translation_m = pose_errors(pose, init)
    return (
        rotation_deg <= config.init_basin_deg
        and translation_m <= config.init_basin_of_longest * model.longest_m
    )


def _finite(points: np.ndarray) -> np.ndarray:
    """The rows of (N, 3) ``points`` that are finite, float64."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return points[np.isfinite(points).all(axis=1)]


def _returns_misfit(answer: Hypothesis, config: RegistrationConfig) -> bool:
    """Whether the LIDAR returns lie further from the target at the ``answer`` than their
    noise allows: their mean distance, truncated, above ``reliable_max_returns_error_m``
    (never without returns: the distance is then NaN)."""
    return answer.returns_error_m > config.reliable_max_returns_error_m


def estimate_pose(
    model: TargetModel,
    cloud: np.ndarray,
    returns: np.ndarray | None = None,
    init: Pose | None = None,
    view: Intrinsics | None = None,
) -> PoseEstimate:
    """The target's pose from ``cloud`` (N, 3) camera-frame points, metres (the completed
    cloud, or any cloud of the target's visible side), refined on ``returns`` (M, 3) (the
    LIDAR's own points) when given; from ``init`` when given (tracking), else from scratch.
    ``view``: the camera that saw the cloud (its intrinsics and image size, pixels), so that
    poses are scored on what it could see (``sdcnet.registration.observed``); without it, on
    the whole target. Points that are not finite are left out. Raises ``UnusableCloudError``
    when the cloud is too small, or too large, to register."""
    config = model.config
    timings: dict[str, float] = {}
    started, cpu_started = time.perf_counter(), time.thread_time()
    # Thinned first as ``observe`` thins it: checking and converting all of a completed cloud's
    # points (up to ~10^6) cost a third of a tracked frame's registration.
    cloud = _finite(evenly(cloud, config.max_cloud_points))
    if len(cloud) < config.min_points:
        raise UnusableCloudError(
            "too_few_points",
            f"{len(cloud)} points: at least {config.min_points} are needed for a pose",
        )
    span = span_m(cloud)
    if span > config.max_span_of_longest * model.longest_m:
        raise UnusableCloudError(
            "too_large",
            f"the cloud spans {span:.3g} m, more than {config.max_span_of_longest:g} times the "
            f"target's {model.longest_m:.3g} m (wrong intrinsics, or not this target?)",
        )
    observed = observe(cloud, model, view)
    if observed.cloud.size() < config.min_points:
        raise UnusableCloudError(
            "too_few_points",
            f"{len(cloud)} points fill only {observed.cloud.size()} voxels of "
            f"{model.longest_m * config.voxel_of_longest:.3f} m: at least {config.min_points} "
            "are needed for a pose",
        )
    if returns is not None:
        returns = _finite(thinned_to(returns, config.max_refine_returns))
        returns = returns if len(returns) >= config.min_points else None
    timings["prepare_ms"] = (time.perf_counter() - started) * 1e3
    refined = tracked = None
    if init is not None:  # the fine gate (3 voxels, ~L / 10) covers a tracker's error
        mark = time.perf_counter()
        refined = refine_dense(model, observed, init, fine=True)
        if refined.consistency >= config.tracking_min_consistency:
            tracked = refined
        timings["tracking_ms"] = (time.perf_counter() - mark) * 1e3
    choice = None
    if tracked is not None:
        mark = time.perf_counter()
        choice, hypotheses = choose_tracked(model, tracked, init, observed, returns), 1
        if _returns_misfit(choice.best, config):  # the returns contradict the track
            choice = None
    if choice is None:  # from scratch, or the tracked pose explains the frame poorly: search
        searched = search(model, observed, timings)
        if refined is not None:
            searched = sorted([refined, *searched], key=lambda h: -h.consistency)
        mark = time.perf_counter()
        choice = choose_searched(model, searched, returns, prior=refined)
        if returns is not None and choice.best.returns_error_m > config.returns_doubt_m:
            searched += seeded_by_returns(model, observed, returns, timings)
            searched.sort(key=lambda h: -h.consistency)
            choice = choose_searched(model, searched, returns, prior=refined)
        hypotheses = len(searched)
    choice = polished(model, choice, returns)
    timings["choice_ms"] = (time.perf_counter() - mark) * 1e3
    best = choice.best
    if not np.all(np.isfinite(best.pose.matrix())):
        raise UnusableCloudError("no_pose", "the registration diverged on this cloud")
    voxel = model.longest_m * config.voxel_of_longest
    fitness, rmse = surface_fit(model, observed.points, best.pose, 3 * voxel)
    left_init = init is not None and not in_basin(model, best.pose, init)
    pose_covariance = covariance(best.result, best.pose)
    evidence = Evidence(
        consistency=best.consistency,
        runner_up_consistency=choice.runner_up_consistency,
        twins=len(choice.alternatives),
        points=len(observed.points),
        returns=0 if returns is None else len(returns),
        left_init=left_init,
        returns_misfit=_returns_misfit(best, config),
        rotation_sigma_deg=rotation_sigma_deg(pose_covariance),
    )
    verdict, reasons = judge(evidence, config)
    timings["total_ms"] = (time.perf_counter() - started) * 1e3
    # CPU time of this thread: what the registration costs whatever else the cores run.
    timings["cpu_ms"] = (time.thread_time() - cpu_started) * 1e3
    return PoseEstimate(
        pose=best.pose,
        fitness=fitness,
        rmse_m=rmse,
        returns_rmse_m=choice.returns_rmse_m,
        converged=bool(best.result.converged),
        consistency=best.consistency,
        covariance=pose_covariance,
        ambiguous=bool(choice.alternatives),
        alternatives=choice.alternatives,
        hypotheses=hypotheses,
        tracked=init is not None and not left_init,
        verdict=verdict,
        reasons=reasons,
        runner_up_consistency=choice.runner_up_consistency,
        points=evidence.points,
        returns=evidence.returns,
        timings_ms={k: round(v, 3) for k, v in timings.items()},
    )
