"""The global search, from scratch (no initial pose).

1. Coarse search. The line of sight to the observed cloud's centroid is known, so a
   hypothesis is a view direction of the target (``views`` on a Fibonacci sphere) and a roll
   about the line of sight (``rolls`` steps). Its translation puts the centroid of what the
   target shows from that view (precomputed by a z-buffer of the surface samples: the cloud
   sees one side, a partial view) on the observed centroid; when the cloud reaches the edge of
   the camera's image, also on the centroid of the part of that side the camera frames
   (``_framed_centroids``), and the better placed of the two is kept. Each of the views x rolls
   hypotheses is scored at once, vectorised, by the mean truncated distance of a subset of
   observed points to the target's surface, read from the distance field.
2. The ``hypotheses`` best, at least ``separation_deg`` apart, are refined by VGICP
   (small_gicp) on the downsampled cloud, the ``finalists`` most consistent (step 3,
   ``sdcnet.registration.observed``) again by GICP. When even the best explains the cloud
   poorly (consistency below ``retry_below_consistency``: the right basin was not among them),
   the next ``retry_hypotheses`` are refined too.

The target's self-symmetries (found once, ``TargetModel._symmetries``) turn the best into more
candidates, and so do its near twins (``TargetModel._near_twins``: 180-degree turns that map it
almost onto itself), which the returns then tell apart: the search's starts, 25 degrees apart
at least, seldom hold both a pose and its near twin.

When the LIDAR returns lie off the target at the answer (``returns_doubt_m``), the same search
runs on them alone (``seeded_by_returns``) and its best poses join the candidates, scored on
the cloud: the completed cloud's search can end in a basin that fits the cloud worse than the
true pose does (a dish's rim, a craft cut by the image border), and the returns, few but
centimetre-accurate, often find the right one.
"""

from __future__ import annotations

import time

import numpy as np

from sdcnet.registration.observed import Observed, consistency, framed_by, observe
from sdcnet.registration.refine import Hypothesis, refine_dense
from sdcnet.registration.target import TargetModel, sight_basis
from sdcnet.rigid import Pose, axis_angle, rotation_angle_deg


def _rotations_onto(vectors: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(V, 3, 3): for each unit vector of ``vectors``, the smallest rotation onto unit ``b``
    (Rodrigues, vectorised; an exactly opposite vector turns about an axis across it)."""
    axes = np.cross(vectors, b)
    sin = np.linalg.norm(axes, axis=1)
    cos = vectors @ b
    opposite = sin < 1e-9
    axes[opposite] = sight_basis(b)[0]
    sin[opposite] = 0.0
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    x, y, z = axes.T
    zero = np.zeros_like(x)
    K = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)
    angle = np.arctan2(sin, cos)
    return (
        np.eye(3) + np.sin(angle)[:, None, None] * K + (1 - np.cos(angle))[:, None, None] * (K @ K)
    )


def _framed_centroids(
    model: TargetModel, rotations: np.ndarray, centroids: np.ndarray, observed: Observed
) -> np.ndarray:
    """(H, 3) target-frame points to put on the observed centroid, one per hypothesis of
    ``rotations`` (H, 3, 3): the centroid of the visible points the camera
    ``observed.view`` frames once the hypothesis' ``centroids`` (H, 3) is on the observed
    centroid, found again from the placement that gives (``FRAMING_STEPS`` times): the cloud
    of a target that overflows the image is centred on the framed part, not on the whole
    visible side."""
    samples = np.repeat(model.visible_samples, model.config.rolls, axis=0)  # (H, S, 3)
    turn = np.transpose(rotations, (0, 2, 1)).astype(np.float32)
    centroids = centroids.astype(np.float32)
    for _ in range(FRAMING_STEPS):
        # camera-frame samples: R (x - centroid) + observed centroid
        points = np.matmul(samples - centroids[:, None], turn)
        points += observed.centroid.astype(np.float32)
        framed = framed_by(points, observed.view)
        count = framed.sum(axis=1)
        seen = count > 0  # a hypothesis that frames nothing keeps its centroid
        mean = (samples * framed[..., None]).sum(axis=1)[seen] / count[seen, None]
        centroids[seen] = mean
    return centroids.astype(np.float64)


#: Rounds of ``_framed_centroids``: the framed part moves with the centroid put on the cloud.
FRAMING_STEPS = 2


def _coarse_search(model: TargetModel, observed: Observed, count: int) -> list[Pose]:
    """The ``count`` best distinct coarse hypotheses, best first (step 1 of the module
    docstring)."""
    config = model.config
    rng = np.random.default_rng(0)
    pts = observed.points
    subset = pts[rng.choice(len(pts), min(config.coarse_points, len(pts)), replace=False)]
    sight = observed.basis[2]
    rolls = np.array([axis_angle(sight, 2 * np.pi * k / config.rolls) for k in range(config.rolls)])
    to_sight = _rotations_onto(model.views, sight)
    rotations = np.matmul(rolls[None], to_sight[:, None]).reshape(-1, 3, 3)  # roll @ to_sight
    # A point p's target-frame position is R^T (p - c) + visible centroid; as a row vector
    # (p - c)^T R + centroid^T, read in the distance field's grid coordinates.
    field = model.field
    scaled = (rotations / field.cell).astype(np.float32)
    turned = np.matmul((subset - observed.centroid).astype(np.float32)[None], scaled)
    truncation = config.coarse_truncation_of_longest * model.longest_m

    def scores(centroids: np.ndarray) -> np.ndarray:
        cells = turned + ((centroids - field.origin) / field.cell).astype(np.float32)[:, None]
        return np.minimum(field.at_cells(cells), truncation).mean(axis=1)

    centroids = np.repeat(model.visible_centroids, config.rolls, axis=0)
    score = scores(centroids)
    if observed.at_border:  # the camera may frame part of the target: the better placement
        framed = _framed_centroids(model, rotations, centroids, observed)
        framed_score = scores(framed)
        better = framed_score < score
        centroids[better], score[better] = framed[better], framed_score[better]
    chosen: list[Pose] = []
    for h in np.argsort(score):
        R = rotations[h]
        if all(rotation_angle_deg(R, p.R) >= config.separation_deg for p in chosen):
            chosen.append(Pose(R, observed.centroid - R @ centroids[h]))
            if len(chosen) == count:
                break
    return chosen


def turned(
    model: TargetModel, hypothesis: Hypothesis, observed: Observed, turns: list[np.ndarray]
) -> list[Hypothesis]:
    """``hypothesis`` turned by each of ``turns`` (4 x 4, target frame), scored."""
    poses = [Pose.from_matrix(hypothesis.pose.matrix() @ S) for S in turns]
    return [Hypothesis(p, consistency(model, p, observed), hypothesis.result) for p in poses]


def mirrored(model: TargetModel, hypothesis: Hypothesis, observed: Observed) -> list[Hypothesis]:
    """``hypothesis`` turned by each of the target's symmetries, scored."""
    return turned(model, hypothesis, observed, model.symmetries)


def search(model: TargetModel, observed: Observed, timings: dict) -> list[Hypothesis]:
    """Steps 1-2 of the module docstring, scored by step 3: refined hypotheses, most
    consistent first, with the best's symmetric and near twins."""
    config = model.config
    mark = time.perf_counter()
    starts = _coarse_search(model, observed, config.hypotheses + config.retry_hypotheses)
    timings["search_ms"] = (time.perf_counter() - mark) * 1e3
    mark = time.perf_counter()
    refined = [refine_dense(model, observed, s, fine=False) for s in starts[: config.hypotheses]]
    if max(h.consistency for h in refined) < config.retry_below_consistency:
        refined += [
            refine_dense(model, observed, s, fine=False) for s in starts[config.hypotheses :]
        ]
    refined.sort(key=lambda h: -h.consistency)
    finalists = [
        refine_dense(model, observed, h.pose, fine=True) for h in refined[: config.finalists]
    ]
    hypotheses = sorted(finalists + refined[config.finalists :], key=lambda h: -h.consistency)
    timings["refine_ms"] = (time.perf_counter() - mark) * 1e3
    twins = [*model.symmetries, *model.near_twins]
    return hypotheses + turned(model, hypotheses[0], observed, twins)


def seeded_by_returns(
    model: TargetModel, observed: Observed, returns: np.ndarray, timings: dict
) -> list[Hypothesis]:
    """The ``finalists`` most consistent poses of the search on the LIDAR ``returns`` (N, 3)
    alone (its best's symmetric twins among them), each scored on the ``observed`` cloud, so
    that step 4 weighs them beside the cloud's own (see the module docstring); none when the
    returns fill too few voxels to search on."""
    mark = time.perf_counter()
    on_returns = observe(returns, model, observed.view)
    if on_returns.cloud.size() < model.config.min_points:
        return []
    found = sorted(search(model, on_returns, {}), key=lambda h: -h.consistency)
    found = found[: model.config.finalists]  # the twins of the best included
    timings["returns_search_ms"] = (time.perf_counter() - mark) * 1e3
    return [Hypothesis(h.pose, consistency(model, h.pose, observed), h.result) for h in found]
