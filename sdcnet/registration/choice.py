"""The answer among the refined hypotheses, and its alternatives.

4. ``returns`` (the LIDAR's own points, centimetre-accurate where the completed cloud is
   decimetre-accurate) refine the candidates within ``returns_margin`` of the best
   consistency by point-to-plane ICP; the most consistent stays the answer unless another
   fits the returns clearly better. Those that fit about as well, far from it in rotation,
   make the answer ``ambiguous`` (a symmetric target) and are listed as alternatives; those
   they fit clearly worse are no close alternative, however consistent the cloud found them.
   The answer is then refined once more on more of the returns (``polished``).

When tracking held, the tracked pose is refined on the returns, and so is the init itself (the
cloud's refinement can slide a few decimetres along a large surface, the returns' cannot); the
tracked pose stays unless the init's fits the returns clearly better. Its symmetric twins are
scored, not refined.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import small_gicp

from sdcnet.registration.config import RegistrationConfig
from sdcnet.registration.observed import Observed, consistency, thinned_to
from sdcnet.registration.refine import Hypothesis, gicp
from sdcnet.registration.search import mirrored
from sdcnet.registration.target import TargetModel, surface_distances, surface_fit
from sdcnet.rigid import Pose, rotation_angle_deg


def _distinct(hypotheses: list[Hypothesis], separation_deg: float) -> list[Hypothesis]:
    """The first of each group of hypotheses less than ``separation_deg`` apart (several
    starts may converge to one pose)."""
    kept: list[Hypothesis] = []
    for h in hypotheses:
        if all(rotation_angle_deg(h.pose.R, k.pose.R) >= separation_deg for k in kept):
            kept.append(h)
    return kept


def _explains_as_well(
    model: TargetModel, other: Hypothesis, best: Hypothesis, returns: np.ndarray | None
) -> bool:
    """Whether ``other`` fits the returns (else the cloud) about as well as ``best``."""
    config = model.config
    if returns is None:
        return other.consistency >= best.consistency - config.ambiguity_margin
    other.returns_error_m = _returns_error(model, returns, other.pose)
    return _fits_as_well(config, other.returns_error_m, best.returns_error_m)


def _fits_as_well(config: RegistrationConfig, error_m: float, best_m: float) -> bool:
    """Whether returns lying ``error_m`` from one pose on average fit it about as well as
    those lying ``best_m`` from another: within ``returns_ambiguity_ratio`` of the larger of
    ``best_m`` and ``returns_error_floor_m`` (a few millimetres apart is the refinement's
    precision, not the poses'). A pose that does not is clearly worse."""
    return error_m <= config.returns_ambiguity_ratio * max(best_m, config.returns_error_floor_m)


def _icp_share(model: TargetModel, returns: np.ndarray, count: int) -> np.ndarray:
    """The returns an ICP moves: thinned to one per ``returns_voxel_of_longest`` (close
    returns, a near target: thousands), then at most ``count`` of those, evenly spaced."""
    voxels, _ = small_gicp.preprocess_points(
        returns,
        downsampling_resolution=model.longest_m * model.config.returns_voxel_of_longest,
        num_neighbors=6,
    )
    return thinned_to(np.asarray(voxels.points())[:, :3], count)


def _returns_error(model: TargetModel, returns: np.ndarray, pose: Pose) -> float:
    """The returns' mean distance to the target at ``pose``, truncated at a third of the
    correspondence gate (metres): a wrong pose's far returns count the same."""
    gate = model.config.returns_max_distance_m / 3
    distances = surface_distances(model, _scored(model, returns), pose)
    return float(np.mean(np.minimum(distances, gate)))


def _scored(model: TargetModel, returns: np.ndarray) -> np.ndarray:
    """The returns a pose's fit is measured on: every k-th, at most ``max_scored_returns``
    (their nearest-neighbour search on the target, once per candidate, was a third of a close
    target's registration time at 8,192 returns)."""
    return thinned_to(returns, model.config.max_scored_returns)


def _refine_on_returns(
    model: TargetModel, candidates: list[Hypothesis], returns: np.ndarray, reach: float = 1.0
) -> list[Hypothesis]:
    """Each candidate refined by point-to-plane ICP on the LIDAR returns and scored by their
    mean distance to the target's surface, truncated (the returns' noise is a few
    centimetres, the completed cloud's decimetres: they tell near-symmetric poses apart);
    best first. The ICP moves at most ``max_icp_returns`` of them, its precise stage for at
    most ``ranking_iterations``: enough to rank the candidates, and their ICP is most of a
    close target's registration time; every return still scores them, and the answer is
    polished on more, for longer (``polished``). A candidate refined on them already (the
    search ran again on the returns and found it again) keeps its refinement."""
    config = model.config
    gate = config.returns_max_distance_m
    thinned = _icp_share(model, returns, config.max_icp_returns)
    for h in candidates:
        if h.on_returns:
            continue
        h.on_returns = True
        # Only the returns near the target at this pose: far ones (another object, or a wrong
        # candidate) cannot match, and the k-d tree is slow to say so.
        near = thinned[model.field.near(h.pose.inverse().apply(thinned))]
        if len(near) < config.min_points:
            h.returns_error_m = float(gate / 3)
            continue
        source = small_gicp.PointCloud(near)
        pose, _ = gicp(
            model, source, h.pose, (reach * gate,), config.fine_iterations, kind="PLANE_ICP"
        )
        h.pose, h.result = _precise(model, near, pose, config.ranking_iterations)
        h.returns_error_m = _returns_error(model, returns, h.pose)
    return sorted(candidates, key=lambda h: h.returns_error_m)


def _precise(
    model: TargetModel, points: np.ndarray, start: Pose, iterations: int
) -> tuple[Pose, small_gicp.RegistrationResult]:
    """Point-to-plane ICP of ``points`` (N, 3, camera frame) onto the target's dense samples
    from ``start``, within a third of the returns' gate, for at most ``iterations`` or until a
    step moves less than ``final_step_*``. Only the points that may lie within that gate at
    ``start`` take part (all of them when fewer than ``min_points`` do): the others find no
    match, and the dense k-d tree is slow to say so (a wrong candidate's precise stage took
    four times its wide one)."""
    gate = model.config.returns_max_distance_m / 3
    near = model.field.near(start.inverse().apply(points), gate)
    if np.count_nonzero(near) >= model.config.min_points:
        points = points[near]
    source = small_gicp.PointCloud(points)
    return gicp(model, source, start, (gate,), iterations, precise=True, kind="PLANE_ICP")


#: The init's refinement on the returns starts with a gate this many times wider: a tracker's
#: prediction can be a metre off (a missed frame), the cloud's refinement of it decimetres.
INIT_REACH = 3.0


@dataclass
class _Choice:
    """The answer among the refined hypotheses, those that explain the frame as well, and
    the best consistency of the others at least ``alternative_deg`` from it."""

    best: Hypothesis
    alternatives: list[Hypothesis]
    runner_up_consistency: float | None
    returns_rmse_m: float | None = None


def _runner_up(model: TargetModel, best: Hypothesis, hypotheses: list[Hypothesis]) -> float | None:
    """The highest consistency among ``hypotheses`` at least ``alternative_deg`` from
    ``best`` in rotation; None when there is none."""
    far = [
        h.consistency
        for h in hypotheses
        if rotation_angle_deg(h.pose.R, best.pose.R) >= model.config.alternative_deg
    ]
    return max(far, default=None)


def choose_searched(
    model: TargetModel,
    hypotheses: list[Hypothesis],
    returns: np.ndarray | None,
    prior: Hypothesis | None = None,
) -> _Choice:
    """Among the hypotheses about as consistent as the best (within ``returns_margin``, or
    ``ambiguity_margin`` without returns): the most consistent (or the ``prior``, the init's
    refined pose, unless the best is more consistent by ``leave_init_margin`` and fits well:
    ``reliable_min_consistency``), unless another fits the returns clearly better once
    refined on them (so near-symmetric poses do not flip at random, and a near-twin a little
    more consistent on a coarse cloud does not win over the returns); the alternatives are
    those whose returns fit about as well (or, without returns, all of them), and the
    runner-up's consistency is the best of the hypotheses the returns did not rule out."""
    config = model.config
    top = hypotheses[0].consistency
    if prior is not None and (
        prior.consistency >= top - config.leave_init_margin or top < config.reliable_min_consistency
    ):
        top = prior.consistency
        hypotheses = [prior, *(h for h in hypotheses if h is not prior)]
    margin = config.ambiguity_margin if returns is None else config.returns_margin
    near_top = [h for h in hypotheses if h.consistency >= top - margin]
    if returns is None:
        candidates = _distinct(near_top, config.alternative_deg)[: config.max_candidates]
        runner_up = _runner_up(model, candidates[0], hypotheses)
        return _Choice(candidates[0], candidates[1:], runner_up)
    # Poses a few degrees apart are refined on the returns each (one may sit in the right
    # basin, the other beside it), then grouped: the best of the incumbent's group stands
    # for it.
    candidates = _distinct(near_top, config.duplicate_deg)[: config.max_candidates]
    incumbent = candidates[0]
    starts = [h.pose for h in candidates]
    ranked = _refine_on_returns(model, candidates, returns)
    own = next(h for h in ranked if _same_basin(model, h, incumbent))
    as_well = _fits_as_well(config, own.returns_error_m, ranked[0].returns_error_m)
    best = own if as_well else ranked[0]
    alternatives = [
        h
        for h in _distinct(ranked, config.alternative_deg)
        if not _same_basin(model, h, best)
        and _fits_as_well(config, h.returns_error_m, best.returns_error_m)
    ]
    rejected = {
        id(h): start
        for h, start in zip(candidates, starts, strict=True)
        if not _fits_as_well(config, h.returns_error_m, best.returns_error_m)
    }
    contenders = [h for h in hypotheses if not _ruled_out(model, h, rejected)]
    return _Choice(best, alternatives, _runner_up(model, best, contenders))


def _ruled_out(model: TargetModel, h: Hypothesis, rejected: dict[int, Pose]) -> bool:
    """Whether the returns ruled ``h`` out: it is one of the candidates they fit clearly worse
    than the answer (``rejected``: their poses before refinement, by id), or a hypothesis the
    search found within ``duplicate_deg`` of one (refined once for both). Such a pose is no
    close alternative, however consistent the completed cloud found it: the cloud is
    decimetres from the surface, the returns centimetres."""
    return id(h) in rejected or any(
        rotation_angle_deg(h.pose.R, start.R) < model.config.duplicate_deg
        for start in rejected.values()
    )


def _same_basin(model: TargetModel, a: Hypothesis, b: Hypothesis) -> bool:
    """Whether ``a`` and ``b`` are less than ``alternative_deg`` apart in rotation."""
    return rotation_angle_deg(a.pose.R, b.pose.R) < model.config.alternative_deg


def choose_tracked(
    model: TargetModel,
    tracked: Hypothesis,
    init: Pose,
    observed: Observed,
    returns: np.ndarray | None,
) -> _Choice:
    """The tracked pose refined on the returns, or ``init`` refined on them when it fits them
    clearly better (``returns_ambiguity_ratio``); its symmetric twins, scored as they are (no
    refinement: cheap), say whether the frame could tell them apart."""
    best = tracked
    if returns is not None:
        own = Hypothesis(init)
        _refine_on_returns(model, [tracked], returns)
        _refine_on_returns(model, [own], returns, reach=INIT_REACH)
        if not _fits_as_well(model.config, tracked.returns_error_m, own.returns_error_m):
            best = own
            best.consistency = consistency(model, best.pose, observed)
    twins = _distinct([best, *mirrored(model, best, observed)], model.config.alternative_deg)
    alternatives = [h for h in twins[1:] if _explains_as_well(model, h, best, returns)]
    return _Choice(best, alternatives, _runner_up(model, best, twins))


def polished(model: TargetModel, choice: _Choice, returns: np.ndarray | None) -> _Choice:
    """The answer refined once more on up to ``polish_icp_returns`` returns, for up to
    ``final_iterations`` (the candidates were refined on fewer, for fewer: enough to rank
    them, not for the last tenth of a degree), kept where the returns fit it at least as
    well; not where they lie farther from it than ``polish_max_returns_error_m`` (a wrong
    answer: polishing it was a fifth of such a frame's time, and never made it reliable);
    with the returns' RMS distance to the target at it. Unchanged without returns."""
    if returns is None:
        return choice
    config = model.config
    best = choice.best
    if best.returns_error_m <= config.polish_max_returns_error_m:
        share = _icp_share(model, returns, config.polish_icp_returns)
        near = share[model.field.near(best.pose.inverse().apply(share))]
        if len(near) >= config.min_points:
            pose, result = _precise(model, near, best.pose, config.final_iterations)
            error = _returns_error(model, returns, pose)
            if error <= best.returns_error_m:
                best.pose, best.result, best.returns_error_m = pose, result, error
    gate = config.returns_max_distance_m / 3
    choice.returns_rmse_m = surface_fit(model, _scored(model, returns), best.pose, gate)[1]
    return choice
