"""The pose of a known target from a camera-frame point cloud: global search, GICP, scoring.

``TargetModel`` prepares a target's triangle mesh once (surface samples, a GICP cloud with
covariances, a distance field, what the target shows from many view directions);
``estimate_pose`` finds ``p_camera = R p_target + t`` for one observed cloud.

From scratch (no initial pose):

1. Coarse search. The line of sight to the observed cloud's centroid is known, so a
   hypothesis is a view direction of the target (``views`` on a Fibonacci sphere) and a roll
   about the line of sight (``rolls`` steps). Its translation puts the centroid of what the
   target shows from that view (precomputed by a z-buffer of the surface samples: the cloud
   sees one side, a partial view) on the observed centroid. Each of the views x rolls
   hypotheses is scored at once, vectorised, by the mean truncated distance of a subset of
   observed points to the target's surface, read from the distance field.
2. The ``hypotheses`` best, at least ``separation_deg`` apart, are refined by VGICP
   (small_gicp) on the downsampled cloud, the ``finalists`` most consistent (step 3) again by
   GICP. When even the best explains the cloud poorly (consistency below
   ``retry_below_consistency``: the right basin was not among them), the next
   ``retry_hypotheses`` are refined too.
3. Each refined pose is scored by how well the target, drawn at that pose, explains the
   cloud as seen from the camera: on a grid across the line of sight, the cells where both
   hold a surface at the same depth, over the cells where either does (the target's cells
   count only outside the observed footprint, so a sparse cloud is not punished for its
   gaps). The target's self-symmetries (found once, ``TargetModel._symmetries``) turn the
   best into more candidates.
4. ``returns`` (the LIDAR's own points, centimetre-accurate where the completed cloud is
   decimetre-accurate) refine the candidates within ``returns_margin`` of the best
   consistency by point-to-plane ICP; the most consistent stays the answer unless another
   fits the returns clearly better. Those that fit about as well, far from it in rotation,
   make the answer ``ambiguous`` (a symmetric target) and are listed as alternatives.

With an initial pose (tracking), steps 1-3 become one GICP refinement from it, then step 4
on it alone (its symmetric twins scored, not refined); if the refinement leaves the target
explaining the cloud poorly, the global search runs after all, and the init's refined pose
stays the answer unless another is more consistent by ``leave_init_margin`` and fits well
(``reliable_min_consistency``), then unless another fits the returns clearly better: a
tracker is not moved to a symmetric twin that fits as well, nor to a pose that fits poorly
too. An answer outside the init's basin (``init_basin_deg``, ``init_basin_of_longest``) is
not ``tracked``.

Every answer carries a verdict (``judge``): "reliable" (use it as it is), "ambiguous" (a
plausible pose, but another competes: a symmetric twin, a close runner-up, the track's init)
or "unreliable" (the cloud does not support it), with the reasons.

Units: metres, radians inside, degrees where a name says so. Deterministic: the subsets are
drawn with fixed seeds.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
import small_gicp
import trimesh

from sdcnet.rigid import Pose, axis_angle, pose_errors, rotation_angle_deg


@dataclass(frozen=True)
class RegistrationConfig:
    """Knobs of the search, refinement and scoring; sizes relative to the target's longest
    extent ``L`` where a size is named ``*_of_longest``."""

    views: int = 96  # view directions of the coarse search (Fibonacci sphere)
    rolls: int = 24  # roll steps about the line of sight per view
    coarse_points: int = 128  # observed points scored per coarse hypothesis
    hypotheses: int = 6  # best distinct coarse hypotheses refined by GICP
    finalists: int = 2  # of those, the most consistent refined again, finely
    retry_below_consistency: float = 0.5  # when the best is below this, refine
    retry_hypotheses: int = 12  # ... this many more
    separation_deg: float = 25.0  # refined hypotheses start at least this far apart
    samples_per_longest: float = 500  # target surface samples about L / this apart,
    samples: tuple[int, int] = (100_000, 200_000)  # ... within these counts
    voxel_of_longest: float = 1 / 32  # the observed cloud is downsampled to this voxel
    coarse_voxel_of_longest: float = 1 / 16  # ... and to this one for the hypotheses' GICP
    max_cloud_points: int = 50_000  # larger clouds are thinned first
    max_input_points: int = 2**20  # a cloud given is thinned to this before anything else
    max_refine_returns: int = 8192  # LIDAR returns refined on, at most: more are thinned
    field_cell_of_longest: float = 1 / 48  # distance field cell
    coarse_truncation_of_longest: float = 0.05  # distances above it score the same
    grid_cell_of_longest: float = 1 / 40  # cell of the consistency grid
    ambiguity_margin: float = 0.04  # consistency within this of the best: an alternative
    returns_margin: float = 0.1  # ... with returns: within this, refined on them to choose
    alternative_deg: float = 10.0  # ... when at least this far from the best in rotation
    max_candidates: int = 6  # the answer and its alternatives, at most
    tracking_min_consistency: float = 0.5  # below it, tracking falls back to the search
    min_points: int = 12  # fewer observed points than this: no pose
    leave_init_margin: float = 0.05  # tracking leaves the init's pose for one this more consistent
    init_basin_deg: float = 25.0  # an answer within this rotation of init,
    init_basin_of_longest: float = 0.5  # ... and this translation (x L), is in the init's basin
    # The verdict (``judge``): below or within these, an answer is not "reliable".
    reliable_min_consistency: float = 0.5  # poor_fit below it (unreliable)
    reliable_min_points: int = 20  # too_few_points: downsampled cloud points (unreliable)
    reliable_min_returns: int = 12  # too_few_returns: LIDAR returns refined on (unreliable)
    reliable_min_lead: float = 0.06  # close_alternative: a pose >= alternative_deg away within this
    max_span_of_longest: float = 20.0  # a cloud wider than this (x L): no pose
    returns_max_distance_m: float = 0.5  # correspondence gate of the returns' refinement
    returns_ambiguity_ratio: float = 1.25  # alternatives whose returns fit this close
    returns_voxel_of_longest: float = 1 / 200
    voxelmap_of_longest: float = 1 / 24  # voxels of the target for the hypotheses' VGICP
    symmetry_tolerance_of_longest: float = 0.003  # see TargetModel._symmetries
    coarse_iterations: int = 8  # GICP iterations per hypothesis, then per finalist:
    fine_iterations: int = 15
    final_iterations: int = 20  # ... and on the returns, until a step moves less than
    final_step_deg: float = 1e-3
    final_step_m: float = 1e-5


DEFAULT_CONFIG = RegistrationConfig()


def fibonacci_sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * i / count)
    azimuth = np.pi * (1 + 5**0.5) * i
    return np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], 1
    )


def _basis(direction: np.ndarray) -> np.ndarray:
    """(3, 3) rows: two unit vectors across ``direction``, then ``direction`` itself."""
    helper = np.array([1.0, 0, 0]) if abs(direction[0]) < 0.9 else np.array([0, 1.0, 0])
    a = np.cross(direction, helper)
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(direction, a), direction])


def _zbuffer(points: np.ndarray, basis: np.ndarray, cell: float) -> np.ndarray:
    """Indices of the points nearest the viewer, one per ``cell``-sized square across the
    line of sight ``basis[2]`` (the viewer looks along it, from far behind)."""
    uvd = points @ basis.T
    cells = np.floor(uvd[:, :2] / cell).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (cells[:, 1].max() + 1) + cells[:, 1]
    order = np.lexsort((uvd[:, 2], key))
    first = np.ones(len(order), bool)
    first[1:] = key[order[1:]] != key[order[:-1]]
    return order[first]


@dataclass(frozen=True)
class DistanceField:
    """Distance (metres) from the cells of a regular grid to the target's surface, truncated;
    the grid's outer layer holds the truncation, so points beyond the grid read it too."""

    origin: np.ndarray  # (3,) corner of cell (0, 0, 0), target frame
    cell: float
    values: np.ndarray  # (X, Y, Z) float32
    truncation: float

    @classmethod
    def build(cls, surface: np.ndarray, cell: float) -> DistanceField:
        """From surface samples (N, 3), on cells of ``cell`` metres. Only cells within the
        truncation of a sample's cell are searched (a nearest-neighbour search far from the
        surface is slow, and its answer would be truncated anyway)."""
        reach = 6  # cells: truncation, and how far from the surface distances are searched
        truncation = reach * cell
        origin = surface.min(axis=0) - (reach + 1) * cell
        shape = tuple(
            np.ceil((surface.max(axis=0) + (reach + 1) * cell - origin) / cell).astype(int)
        )
        near = np.zeros(shape, bool)
        near[tuple(np.floor((surface - origin) / cell).astype(int).T)] = True
        for axis in range(3):  # grow by `reach` cells along each axis
            grown = near.copy()
            for shift in range(1, reach + 1):
                grown[(slice(None),) * axis + (slice(shift, None),)] |= near[
                    (slice(None),) * axis + (slice(None, -shift),)
                ]
                grown[(slice(None),) * axis + (slice(None, -shift),)] |= near[
                    (slice(None),) * axis + (slice(shift, None),)
                ]
            near = grown
        values = np.full(shape, truncation, np.float32)
        centres = origin + (np.argwhere(near) + 0.5) * cell
        tree = small_gicp.KdTree(surface)
        _, squared = tree.batch_nearest_neighbor_search(centres)
        values[near] = np.minimum(np.sqrt(squared), truncation)
        return cls(origin, cell, values, truncation)

    def near(self, points: np.ndarray) -> np.ndarray:
        """Whether target-frame ``points`` (N, 3) lie within the truncation of the surface."""
        return self.at_cells((points - self.origin) / self.cell) < self.truncation

    def at_cells(self, cells: np.ndarray) -> np.ndarray:
        """Distances at grid coordinates (..., 3) (target-frame position minus ``origin``,
        over ``cell``), float32."""
        X, Y, Z = self.values.shape
        index = cells.astype(np.int32)  # towards zero: negatives land on the outer layer
        np.clip(index, 0, (X - 1, Y - 1, Z - 1), out=index)
        flat = (index[..., 0] * Y + index[..., 1]) * Z + index[..., 2]
        return self.values.reshape(-1)[flat]


class TargetModel:
    """A target's mesh (target frame, metres) prepared once for ``estimate_pose``."""

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        config: RegistrationConfig = DEFAULT_CONFIG,
        seed: int = 0,
    ):
        mesh = trimesh.Trimesh(np.asarray(vertices, np.float64), faces, process=False)
        if len(mesh.faces) == 0 or not mesh.area > 0:
            raise ValueError("the target mesh has no surface")
        self.config = config
        self.longest_m = L = float(np.max(mesh.extents))
        # GICP's precision on a noise-free view is bounded by how densely the target is
        # sampled: 60k samples gave 0.02-0.17 degrees on small procedural craft, 200k below
        # 0.015 degrees and 0.1 mm.
        count = int(np.clip(mesh.area / (L / config.samples_per_longest) ** 2, *config.samples))
        surface, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
        self.surface = np.asarray(surface, np.float64)
        self.cloud, self.tree = small_gicp.preprocess_points(
            self.surface, downsampling_resolution=L / 1000, num_neighbors=10
        )
        self.points = np.asarray(self.cloud.points())[:, :3].copy()
        self.normals = _normals(self.points, self.tree)
        self.spacing_m = L / 1000
        # A sparser copy for the refinements on the decimetre-accurate completed cloud: the
        # dense one's deeper k-d tree costs them 3-5 times more for no gain there.
        self.sparse_cloud, self.sparse_tree = small_gicp.preprocess_points(
            self.surface, downsampling_resolution=L / 250, num_neighbors=10
        )
        self.voxelmap = small_gicp.GaussianVoxelMap(L * config.voxelmap_of_longest)
        self.voxelmap.insert(self.cloud)
        self.field = DistanceField.build(self.surface, L * config.field_cell_of_longest)
        self.views = fibonacci_sphere(config.views)
        thinned = self.surface[:: max(1, len(self.surface) // 10_000)]
        self.visible_centroids = np.array(
            [thinned[_zbuffer(thinned, _basis(w), L / 64)].mean(axis=0) for w in self.views]
        )
        render = small_gicp.voxelgrid_sampling(
            small_gicp.PointCloud(self.surface), L * config.grid_cell_of_longest / 2.5
        )
        self.render_points = np.asarray(render.points())[:, :3]
        self.symmetries = self._symmetries(_dominant_normals(mesh))

    def _symmetries(self, normals: np.ndarray) -> list[np.ndarray]:
        """Rigid motions S (4 x 4, target frame) with S(target) ~ target: if P is the pose,
        P S explains any view as well. Candidates are turns by 360/n degrees (n = 2, 3, 4,
        6) about the principal axes through the centroid and about the dominant face
        ``normals`` (a cube's principal axes are arbitrary). The distance field screens out
        clear misses (at 4 times its own floor: a nearest-neighbour search far from the
        surface is slow); the others are refined by GICP of the target onto itself and kept
        when the moved samples lie, on average, at most ``symmetry_tolerance_of_longest`` x L
        farther from the surface than unmoved ones do (sampling sets that floor).

        On the NASA meshes: Dawn's 180-degree turns move the samples 0.03 % of L more,
        Juno's 120-degree turn 0.19 %, TDRS's 180-degree turn 0.10 %; the nearest misses
        (Messenger, Juno turned 180 degrees) 0.38-0.44 %."""
        config = self.config
        L = self.longest_m
        probe, _ = small_gicp.preprocess_points(
            self.surface, downsampling_resolution=L / 48, num_neighbors=10
        )
        points = np.asarray(probe.points())[:, :3]

        def moved(T: np.ndarray) -> np.ndarray:
            return points @ T[:3, :3].T + T[:3, 3]

        def coarse_spread(T: np.ndarray) -> float:
            return float(
                np.mean(self.field.at_cells((moved(T) - self.field.origin) / self.field.cell))
            )

        def spread(T: np.ndarray) -> float:
            _, squared = self.tree.batch_nearest_neighbor_search(moved(T))
            return float(np.mean(np.minimum(np.sqrt(squared), L / 50)))

        floors = coarse_spread(np.eye(4)), spread(np.eye(4))
        tolerance = floors[1] + config.symmetry_tolerance_of_longest * L
        centre = self.surface.mean(axis=0)
        _, _, principal = np.linalg.svd(self.surface - centre, full_matrices=False)
        found: list[np.ndarray] = []
        for axis in [*principal, *normals]:
            for n in (2, 3, 4, 6):
                turn = axis_angle(axis, 2 * np.pi / n)
                T = Pose(turn, centre - turn @ centre).matrix()
                if coarse_spread(T) > 4 * floors[0]:
                    continue
                T = small_gicp.align(
                    self.sparse_cloud,
                    probe,
                    self.sparse_tree,
                    T,
                    max_correspondence_distance=L / 20,
                ).T_target_source
                for S in (T, np.linalg.inv(T)):
                    angles = [rotation_angle_deg(S[:3, :3], F[:3, :3]) for F in [np.eye(4), *found]]
                    if min(angles) >= config.alternative_deg and spread(S) <= tolerance:
                        found.append(S)
        for A, B in [(A, B) for A in found for B in found]:  # compositions: a box's third turn
            S = A @ B
            angles = [rotation_angle_deg(S[:3, :3], F[:3, :3]) for F in [np.eye(4), *found]]
            if min(angles) >= config.alternative_deg and spread(S) <= tolerance:
                found.append(S)
        return found


def _normals(points: np.ndarray, tree: small_gicp.KdTree, neighbours: int = 10) -> np.ndarray:
    """(N, 3) unit normals of a sampled surface: the least spread direction of each point's
    nearest neighbours (sign arbitrary)."""
    index, _ = tree.batch_knn_search(points, neighbours)
    near = points[index.astype(np.int64)]
    near -= near.mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.einsum("nki,nkj->nij", near, near))
    return vectors[:, :, 0]


def _dominant_normals(mesh: trimesh.Trimesh, count: int = 3) -> np.ndarray:
    """Up to ``count`` axes (unit, sign-free) that the most face area faces, at least 20
    degrees apart: a box's three face axes."""
    bins = fibonacci_sphere(1000)
    bins = bins[bins[:, 2] >= 0]  # one hemisphere: an axis and its opposite are one
    nearest = np.argmax(np.abs(mesh.face_normals @ bins.T), axis=1)
    area = np.bincount(nearest, weights=mesh.area_faces, minlength=len(bins))
    axes: list[np.ndarray] = []
    for k in np.argsort(-area):
        if area[k] <= 0 or len(axes) == count:
            break
        if all(abs(bins[k] @ a) < np.cos(np.radians(20)) for a in axes):
            axes.append(bins[k])
    return np.array(axes).reshape(-1, 3)


@dataclass
class Hypothesis:
    """A pose under consideration and how well it explains the cloud."""

    pose: Pose
    consistency: float = 0.0  # see module docstring, step 3; 0..1
    result: small_gicp.RegistrationResult | None = None
    returns_error_m: float = float("nan")  # mean truncated distance of the returns


@dataclass
class PoseEstimate:
    """The answer of ``estimate_pose``."""

    pose: Pose
    fitness: float  # share of the (downsampled) cloud within the inlier distance of the target
    rmse_m: float  # RMS distance of those inliers to the target's surface
    returns_rmse_m: float | None  # same for the LIDAR returns, when given
    converged: bool  # the last GICP met its convergence criteria
    consistency: float  # 0..1, step 3 of the module docstring
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
        return float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(self.covariance[:3, :3])[-1], 0))))

    @property
    def translation_sigma_m(self) -> float:
        """Standard deviation of t along its least certain axis, metres."""
        return float(np.sqrt(max(np.linalg.eigvalsh(self.covariance[3:, 3:])[-1], 0)))


class UnusableCloudError(ValueError):
    """The cloud cannot be registered: ``code`` "too_few_points", "too_large" (it spans far
    more than the target: wrong intrinsics, or not this target) or "no_pose" (diverged)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


#: Why an answer is not "reliable": the code, whether it makes the answer "unreliable" (else
#: "ambiguous"), and what it means.
REASONS: dict[str, tuple[bool, str]] = {
    "poor_fit": (True, "the target at this pose explains the cloud poorly (low consistency)"),
    "too_few_points": (True, "too few points of the cloud to register"),
    "too_few_returns": (True, "too few LIDAR returns to check the pose against"),
    "symmetric_twins": (False, "other poses (a symmetric target) fit the frame as well"),
    "close_alternative": (False, "another pose fits the frame almost as well"),
    "left_init": (False, "the answer left the basin of the tracker's init"),
}


@dataclass(frozen=True)
class Evidence:
    """What the verdict is drawn from: the answer's scores (see ``PoseEstimate``)."""

    consistency: float
    runner_up_consistency: float | None
    twins: int  # alternatives that fit as well
    points: int
    returns: int
    left_init: bool


def judge(evidence: Evidence, config: RegistrationConfig = DEFAULT_CONFIG) -> tuple[str, list[str]]:
    """The verdict on an answer and its reasons (``REASONS``), from its ``evidence`` and the
    ``reliable_*`` thresholds of ``config``: "unreliable" when a reason says so, else
    "ambiguous" when any reason holds, else "reliable"."""
    e = evidence
    lead = None if e.runner_up_consistency is None else e.consistency - e.runner_up_consistency
    checks = {
        "poor_fit": e.consistency < config.reliable_min_consistency,
        "too_few_points": e.points < config.reliable_min_points,
        "too_few_returns": e.returns < config.reliable_min_returns,
        "symmetric_twins": e.twins > 0,
        "close_alternative": e.twins == 0 and lead is not None and lead < config.reliable_min_lead,
        "left_init": e.left_init,
    }
    reasons = [code for code, holds in checks.items() if holds]
    if any(REASONS[code][0] for code in reasons):
        return "unreliable", reasons
    return ("ambiguous" if reasons else "reliable"), reasons


def in_basin(model: TargetModel, pose: Pose, init: Pose) -> bool:
    """Whether ``pose`` lies in the basin of ``init``: within ``init_basin_deg`` of its
    rotation and ``init_basin_of_longest`` x L of its translation."""
    config = model.config
    rotation_deg, translation_m = pose_errors(pose, init)
    return (
        rotation_deg <= config.init_basin_deg
        and translation_m <= config.init_basin_of_longest * model.longest_m
    )


@dataclass(frozen=True)
class _Observed:
    """The observed cloud, prepared: downsampled with covariances, and its depth grid."""

    cloud: small_gicp.PointCloud  # downsampled, with covariances
    points: np.ndarray  # (n, 3) the points of ``cloud``
    centroid: np.ndarray  # (3,) of the full cloud (pixel-uniform), metres
    basis: np.ndarray  # rows: two axes across the line of sight, the line of sight
    cell: float
    origin: np.ndarray  # (2,) grid corner across the line of sight
    depth: np.ndarray  # (H, W) nearest depth along the line of sight, inf = none
    footprint: np.ndarray  # (H, W) bool: the observed cells, grown over the cloud's gaps
    tolerance: float  # depths closer than this agree, metres
    coarse_voxel: float  # metres, of ``coarse``

    @functools.cached_property
    def coarse(self) -> small_gicp.PointCloud:
        """More coarsely downsampled, with covariances: for the hypotheses (made on demand,
        tracking needs none)."""
        cloud, _ = small_gicp.preprocess_points(
            self.points, downsampling_resolution=self.coarse_voxel, num_neighbors=8
        )
        return cloud


def _grid_depth(uvd: np.ndarray, origin: np.ndarray, cell: float, shape) -> np.ndarray:
    """(H, W) nearest depth per cell of points given as (across, across, along) rows."""
    depth = np.full(shape, np.inf)
    ij = np.floor((uvd[:, :2] - origin) / cell).astype(np.int64)
    inside = np.all((ij >= 0) & (ij < shape), axis=1)
    ij, d = ij[inside], uvd[inside, 2]
    order = np.argsort(-d)  # nearest written last, so it stays
    depth[ij[order, 0], ij[order, 1]] = d[order]
    return depth


def _observe(cloud: np.ndarray, model: TargetModel) -> _Observed:
    config = model.config
    L = model.longest_m
    centroid = np.mean(cloud, axis=0, dtype=np.float64)
    # A completed cloud holds a point per pixel (up to ~10^6); every k-th of them (pixel
    # order: an even thinning of the image) still fills every voxel of L / 32.
    step = max(1, len(cloud) // config.max_cloud_points)
    points = np.asarray(cloud[::step], np.float64)
    # Voxels of L / 32, or coarser when the cloud spans more than the target (a cloud that
    # is not of this target, or wrong intrinsics): at most ~48 across, so the cost stays bound.
    span = float(np.max(np.ptp(points, axis=0)))
    voxel = max(L * config.voxel_of_longest, span / 48)
    small, _ = small_gicp.preprocess_points(points, downsampling_resolution=voxel, num_neighbors=10)
    kept = np.asarray(small.points())[:, :3]
    basis = _basis(centroid / np.linalg.norm(centroid))
    cell = L * config.grid_cell_of_longest
    uvd = kept @ basis.T
    origin = uvd[:, :2].min(axis=0) - 1.2 * L
    shape = tuple(np.ceil((uvd[:, :2].max(axis=0) + 1.2 * L - origin) / cell).astype(int))
    depth = _grid_depth(uvd, origin, cell, shape)
    # Grow the footprint over the gaps between neighbouring points (LIDAR returns are
    # decimetres apart): by the median distance to the nearest other point.
    tree = small_gicp.KdTree(kept)
    _, squared = tree.batch_knn_search(kept, 2)
    spacing = float(np.median(np.sqrt(squared[:, 1]))) if len(kept) > 1 else cell
    radius = int(np.clip(np.ceil(spacing / cell), 1, 12))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    footprint = cv2.dilate(np.isfinite(depth).astype(np.uint8), kernel) > 0
    return _Observed(
        small,
        kept,
        centroid,
        basis,
        cell,
        origin,
        depth,
        footprint,
        2 * cell,
        L * config.coarse_voxel_of_longest,
    )


def _consistency(model: TargetModel, pose: Pose, observed: _Observed) -> float:
    """Share of the cells, where either the target at ``pose`` or the cloud shows a surface,
    in which both do at the same depth (step 3 of the module docstring)."""
    uvd = pose.apply(model.render_points) @ observed.basis.T
    drawn = _grid_depth(uvd, observed.origin, observed.cell, observed.depth.shape)
    seen = np.isfinite(observed.depth)
    has = np.isfinite(drawn)
    both = has & seen
    agree = np.count_nonzero(np.abs(drawn[both] - observed.depth[both]) < observed.tolerance)
    outside = np.count_nonzero(has & ~observed.footprint)
    union = np.count_nonzero(both) + np.count_nonzero(seen & ~has) + outside
    return agree / max(union, 1)


def _rotations_onto(vectors: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(V, 3, 3): for each unit vector of ``vectors``, the smallest rotation onto unit ``b``
    (Rodrigues, vectorised; an exactly opposite vector turns about an axis across it)."""
    axes = np.cross(vectors, b)
    sin = np.linalg.norm(axes, axis=1)
    cos = vectors @ b
    opposite = sin < 1e-9
    axes[opposite] = _basis(b)[0]
    sin[opposite] = 0.0
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    x, y, z = axes.T
    zero = np.zeros_like(x)
    K = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=1).reshape(-1, 3, 3)
    angle = np.arctan2(sin, cos)
    return (
        np.eye(3) + np.sin(angle)[:, None, None] * K + (1 - np.cos(angle))[:, None, None] * (K @ K)
    )


def _coarse_search(model: TargetModel, observed: _Observed, count: int) -> list[Pose]:
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
    centroids = np.repeat(model.visible_centroids, config.rolls, axis=0)
    offsets = ((centroids - field.origin) / field.cell).astype(np.float32)
    scaled = (rotations / field.cell).astype(np.float32)
    cells = np.matmul((subset - observed.centroid).astype(np.float32)[None], scaled)
    cells += offsets[:, None, :]
    truncation = config.coarse_truncation_of_longest * model.longest_m
    score = np.minimum(field.at_cells(cells), truncation).mean(axis=1)
    chosen: list[Pose] = []
    for h in np.argsort(score):
        R = rotations[h]
        if all(rotation_angle_deg(R, p.R) >= config.separation_deg for p in chosen):
            chosen.append(Pose(R, observed.centroid - R @ centroids[h]))
            if len(chosen) == count:
                break
    return chosen


def _gicp(
    model: TargetModel,
    source: small_gicp.PointCloud,
    start: Pose,
    distances: tuple[float, ...],
    iterations: int,
    voxelmap: bool = False,
    precise: bool = False,
    kind: str = "GICP",
) -> tuple[Pose, small_gicp.RegistrationResult]:
    """GICP of ``source`` (camera frame) onto the target from ``start``, once per
    correspondence distance (coarse to fine): on the target's voxel map (VGICP), or its
    dense samples when ``precise`` (small_gicp stops once a step moves less than 0.1 degree
    and 1 mm; ``precise`` waits for steps of ``final_step_*``), else its sparser samples.
    ``kind`` "PLANE_ICP" matches points to the target's planes without the source's
    covariances: for the LIDAR returns, too sparse for a point's neighbours to describe its
    surface (on 48 real frames tracked from 3 degrees off: mean error 0.20 degrees against
    GICP's 0.47)."""
    T = start.inverse().matrix()  # target <- camera
    result = None
    stop = {}
    if precise:
        stop = {
            "rotation_epsilon": np.radians(model.config.final_step_deg),
            "translation_epsilon": model.config.final_step_m,
        }
    for distance in distances:
        if voxelmap:  # VGICP: correspondences by voxel, several times faster, coarser
            result = small_gicp.align(
                model.voxelmap,
                source,
                T,
                max_correspondence_distance=distance,
                max_iterations=iterations,
                **stop,
            )
        else:
            cloud, tree = (
                (model.cloud, model.tree) if precise else (model.sparse_cloud, model.sparse_tree)
            )
            result = small_gicp.align(
                cloud,
                source,
                tree,
                T,
                registration_type=kind,
                max_correspondence_distance=distance,
                max_iterations=iterations,
                **stop,
            )
        T = result.T_target_source
    return Pose.from_matrix(np.linalg.inv(T)), result


def _near_points(model: TargetModel, observed: _Observed, pose: Pose) -> small_gicp.PointCloud:
    """The observed cloud, or only its points near the target at ``pose`` (with their
    covariances) when many are far: a k-d tree search far from the target is slow."""
    near = model.field.near(pose.inverse().apply(observed.points))
    if near.mean() > 0.8 or np.count_nonzero(near) < model.config.min_points:
        return observed.cloud
    cloud = small_gicp.PointCloud(observed.points[near])
    small_gicp.estimate_covariances(cloud, num_neighbors=10)
    return cloud


def _refine_dense(model: TargetModel, observed: _Observed, start: Pose, fine: bool) -> Hypothesis:
    """GICP of the downsampled cloud from ``start``: coarsely (a wide correspondence gate,
    few iterations) or finely (a gate of a few voxels), then scored."""
    config = model.config
    if fine:
        gate, iterations = 3 * model.longest_m * config.voxel_of_longest, config.fine_iterations
        source = _near_points(model, observed, start)
    else:
        gate, iterations = 0.1 * model.longest_m, config.coarse_iterations
        source = observed.coarse
    pose, result = _gicp(model, source, start, (gate,), iterations, voxelmap=not fine)
    return Hypothesis(pose, _consistency(model, pose, observed), result)


#: GICP's Hessian counts every point of the cloud as an independent measurement of the pose;
#: the completed cloud's points are interpolated between far fewer returns, and the target's
#: mesh is not the flying spacecraft's surface, so it is too confident by about these factors
#: (rotation, translation standard deviations), chosen so that the median error of the answers
#: marked reliable on the test split's spacecraft is chi(3)'s median, 1.54 sigma, as for an
#: isotropic Gaussian error (the fit and its coverage: docs/pose/README.md, "Sigma").
SIGMA_INFLATION = (3.5, 4.4)


def _covariance(result: small_gicp.RegistrationResult, pose: Pose) -> np.ndarray:
    """(6, 6) covariance of (rotation vector in the camera frame, t) from GICP's Hessian,
    inflated by ``SIGMA_INFLATION``.

    small_gicp perturbs T_target_camera on the right, T exp(d), d = (rotation, translation)
    in the camera frame; the pose (its inverse) then moves by exp(-d) on the left:
    R -> exp(-w) R, t -> exp(-w) t - v ~ t + t x w - v. The Hessian is scaled by the
    residual variance per degree of freedom (its error is half the sum of squares).
    """
    inliers = max(int(result.num_inliers), 7)
    scale = 2 * float(result.error) / (inliers - 6)
    try:
        cov_d = np.linalg.inv(np.asarray(result.H)) * scale
    except np.linalg.LinAlgError:
        return np.full((6, 6), np.inf)
    t = pose.t
    skew_t = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    J = np.zeros((6, 6))
    J[:3, :3] = -np.eye(3)
    J[3:, :3] = skew_t
    J[3:, 3:] = -np.eye(3)
    inflation = np.diag(np.repeat(SIGMA_INFLATION, 3))
    return inflation @ J @ cov_d @ J.T @ inflation


def surface_distances(model: TargetModel, points: np.ndarray, pose: Pose) -> np.ndarray:
    """Distances (metres) of camera-frame ``points`` to the target's surface at ``pose``:
    along the normal of the nearest target sample (so the samples' spacing does not count),
    or to the sample itself when the point lies beyond it across the surface (off an edge);
    the distance field's truncation (L / 8) for points beyond it."""
    local = pose.inverse().apply(points)
    distances = np.full(len(local), model.field.truncation)  # far: at least this
    near = model.field.near(local)  # (a nearest-neighbour search far away is slow)
    index, squared = model.tree.batch_nearest_neighbor_search(local[near])
    offset = local[near] - model.points[index]
    along = np.abs(np.einsum("ij,ij->i", offset, model.normals[index]))
    across = np.maximum(squared - along**2, 0)
    distances[near] = np.where(across <= (2 * model.spacing_m) ** 2, along, np.sqrt(squared))
    return distances


def _distances(model: TargetModel, points: np.ndarray, pose: Pose, gate: float):
    """(share of points within ``gate`` of the surface, RMS distance of those)."""
    d = surface_distances(model, points, pose)
    inliers = d < gate
    rmse = float(np.sqrt(np.mean(d[inliers] ** 2))) if inliers.any() else float("inf")
    return float(inliers.mean()), rmse


def _distinct(hypotheses: list[Hypothesis], separation_deg: float) -> list[Hypothesis]:
    """The first of each group of hypotheses less than ``separation_deg`` apart (several
    starts may converge to one pose)."""
    kept: list[Hypothesis] = []
    for h in hypotheses:
        if all(rotation_angle_deg(h.pose.R, k.pose.R) >= separation_deg for k in kept):
            kept.append(h)
    return kept


def _mirrored(model: TargetModel, hypothesis: Hypothesis, observed: _Observed) -> list[Hypothesis]:
    """``hypothesis`` turned by each of the target's symmetries, scored."""
    poses = [Pose.from_matrix(hypothesis.pose.matrix() @ S) for S in model.symmetries]
    return [Hypothesis(p, _consistency(model, p, observed), hypothesis.result) for p in poses]


def _explains_as_well(
    model: TargetModel, other: Hypothesis, best: Hypothesis, returns: np.ndarray | None
) -> bool:
    """Whether ``other`` fits the returns (else the cloud) about as well as ``best``."""
    config = model.config
    if returns is None:
        return other.consistency >= best.consistency - config.ambiguity_margin
    gate = config.returns_max_distance_m / 3
    error = float(np.mean(np.minimum(surface_distances(model, returns, other.pose), gate)))
    other.returns_error_m = error
    return error <= config.returns_ambiguity_ratio * best.returns_error_m


def _refine_on_returns(
    model: TargetModel, candidates: list[Hypothesis], returns: np.ndarray
) -> list[Hypothesis]:
    """Each candidate refined by GICP on the LIDAR returns and scored by their mean distance
    to the target's surface, truncated (the returns' noise is a few centimetres, the
    completed cloud's decimetres: they tell near-symmetric poses apart); best first. Close
    returns (a near target: thousands) are thinned to one per ``returns_voxel_of_longest``."""
    config = model.config
    source, _ = small_gicp.preprocess_points(
        returns,
        downsampling_resolution=model.longest_m * config.returns_voxel_of_longest,
        num_neighbors=6,
    )
    gate = config.returns_max_distance_m
    thinned = np.asarray(source.points())[:, :3]
    for h in candidates:
        # Only the returns near the target at this pose: far ones (another object, or a wrong
        # candidate) cannot match, and the k-d tree is slow to say so.
        near = model.field.near(h.pose.inverse().apply(thinned))
        if np.count_nonzero(near) < config.min_points:
            h.returns_error_m = float(gate / 3)
            continue
        source = small_gicp.PointCloud(thinned[near])
        pose, _ = _gicp(model, source, h.pose, (gate,), config.fine_iterations, kind="PLANE_ICP")
        h.pose, h.result = _gicp(
            model,
            source,
            pose,
            (gate / 3,),
            config.final_iterations,
            precise=True,
            kind="PLANE_ICP",
        )
        distances = surface_distances(model, returns, h.pose)
        h.returns_error_m = float(np.mean(np.minimum(distances, gate / 3)))
    return sorted(candidates, key=lambda h: h.returns_error_m)


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


def _search(model: TargetModel, observed: _Observed, timings: dict) -> list[Hypothesis]:
    """Steps 1-3 of the module docstring: refined hypotheses, most consistent first, with
    the best's symmetric twins."""
    config = model.config
    mark = time.perf_counter()
    starts = _coarse_search(model, observed, config.hypotheses + config.retry_hypotheses)
    timings["search_ms"] = (time.perf_counter() - mark) * 1e3
    mark = time.perf_counter()
    refined = [_refine_dense(model, observed, s, fine=False) for s in starts[: config.hypotheses]]
    if max(h.consistency for h in refined) < config.retry_below_consistency:
        refined += [
            _refine_dense(model, observed, s, fine=False) for s in starts[config.hypotheses :]
        ]
    refined.sort(key=lambda h: -h.consistency)
    finalists = [
        _refine_dense(model, observed, h.pose, fine=True) for h in refined[: config.finalists]
    ]
    hypotheses = sorted(finalists + refined[config.finalists :], key=lambda h: -h.consistency)
    timings["refine_ms"] = (time.perf_counter() - mark) * 1e3
    return hypotheses + _mirrored(model, hypotheses[0], observed)


def _choose_searched(
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
    those whose returns fit about as well (or, without returns, all of them)."""
    config = model.config
    top = hypotheses[0].consistency
    if prior is not None and (
        prior.consistency >= top - config.leave_init_margin or top < config.reliable_min_consistency
    ):
        top = prior.consistency
        hypotheses = [prior, *(h for h in hypotheses if h is not prior)]
    margin = config.ambiguity_margin if returns is None else config.returns_margin
    candidates = _distinct(
        [h for h in hypotheses if h.consistency >= top - margin], config.alternative_deg
    )[: config.max_candidates]
    if returns is None:
        runner_up = _runner_up(model, candidates[0], hypotheses)
        return _Choice(candidates[0], candidates[1:], runner_up)
    incumbent = candidates[0]
    ranked = _refine_on_returns(model, candidates, returns)
    ratio = config.returns_ambiguity_ratio
    best = ranked[0] if ranked[0].returns_error_m * ratio < incumbent.returns_error_m else incumbent
    alternatives = [
        h for h in ranked if h is not best and h.returns_error_m <= ratio * best.returns_error_m
    ]
    runner_up = _runner_up(model, best, hypotheses)
    return _Choice(best, alternatives, runner_up, _returns_rmse(model, returns, best))


def _choose_tracked(
    model: TargetModel, tracked: Hypothesis, observed: _Observed, returns: np.ndarray | None
) -> _Choice:
    """The tracked pose, refined on the returns; its symmetric twins, scored as they are (no
    refinement: cheap), say whether the frame could tell them apart."""
    best = _refine_on_returns(model, [tracked], returns)[0] if returns is not None else tracked
    twins = _distinct([best, *_mirrored(model, best, observed)], model.config.alternative_deg)
    alternatives = [h for h in twins[1:] if _explains_as_well(model, h, best, returns)]
    return _Choice(
        best,
        alternatives,
        _runner_up(model, best, twins),
        None if returns is None else _returns_rmse(model, returns, best),
    )


def _returns_rmse(model: TargetModel, returns: np.ndarray, best: Hypothesis) -> float:
    return _distances(model, returns, best.pose, model.config.returns_max_distance_m / 3)[1]


def _thinned(points: np.ndarray, most: int) -> np.ndarray:
    """Every k-th of (N, 3) ``points``, at most ``most`` of them: an even thinning of a cloud
    in pixel order. Bounds the time and memory of one registration: a bright 2048 x 2048
    frame's 4M points and 262,144 returns took 19 s (the returns' refinement, holding the
    interpreter all along), 0.7 s thinned."""
    return points[:: -(-len(points) // most)] if len(points) > most else points


def _finite(points: np.ndarray) -> np.ndarray:
    """The rows of (N, 3) ``points`` that are finite, float64."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    return points[np.isfinite(points).all(axis=1)]


def estimate_pose(
    model: TargetModel,
    cloud: np.ndarray,
    returns: np.ndarray | None = None,
    init: Pose | None = None,
) -> PoseEstimate:
    """The target's pose from ``cloud`` (N, 3) camera-frame points, metres (the completed
    cloud, or any cloud of the target's visible side), refined on ``returns`` (M, 3) (the
    LIDAR's own points) when given; from ``init`` when given (tracking), else from scratch.
    Points that are not finite are left out. Raises ``UnusableCloudError`` when the cloud is
    too small, or too large, to register."""
    config = model.config
    timings: dict[str, float] = {}
    started, cpu_started = time.perf_counter(), time.thread_time()
    cloud = _finite(_thinned(cloud, config.max_input_points))
    if len(cloud) < config.min_points:
        raise UnusableCloudError(
            "too_few_points",
            f"{len(cloud)} points: at least {config.min_points} are needed for a pose",
        )
    span = float(np.max(np.ptp(cloud, axis=0)))
    if span > config.max_span_of_longest * model.longest_m:
        raise UnusableCloudError(
            "too_large",
            f"the cloud spans {span:.3g} m, more than {config.max_span_of_longest:g} times the "
            f"target's {model.longest_m:.3g} m (wrong intrinsics, or not this target?)",
        )
    observed = _observe(cloud, model)
    if observed.cloud.size() < config.min_points:
        raise UnusableCloudError(
            "too_few_points",
            f"{len(cloud)} points fill only {observed.cloud.size()} voxels of "
            f"{model.longest_m * config.voxel_of_longest:.3f} m: at least {config.min_points} "
            "are needed for a pose",
        )
    if returns is not None:
        returns = _finite(_thinned(returns, config.max_refine_returns))
        returns = returns if len(returns) >= config.min_points else None
    timings["prepare_ms"] = (time.perf_counter() - started) * 1e3
    refined = tracked = None
    if init is not None:  # the fine gate (3 voxels, ~L / 10) covers a tracker's error
        mark = time.perf_counter()
        refined = _refine_dense(model, observed, init, fine=True)
        if refined.consistency >= config.tracking_min_consistency:
            tracked = refined
        timings["tracking_ms"] = (time.perf_counter() - mark) * 1e3
    if tracked is not None:
        mark = time.perf_counter()
        choice, hypotheses = _choose_tracked(model, tracked, observed, returns), 1
    else:  # from scratch, or the tracked pose explains the cloud poorly: search (keeping it)
        searched = _search(model, observed, timings)
        if refined is not None:
            searched = sorted([refined, *searched], key=lambda h: -h.consistency)
        mark = time.perf_counter()
        choice = _choose_searched(model, searched, returns, prior=refined)
        hypotheses = len(searched)
    timings["choice_ms"] = (time.perf_counter() - mark) * 1e3
    best = choice.best
    if not np.all(np.isfinite(best.pose.matrix())):
        raise UnusableCloudError("no_pose", "the registration diverged on this cloud")
    voxel = model.longest_m * config.voxel_of_longest
    fitness, rmse = _distances(model, observed.points, best.pose, 3 * voxel)
    left_init = init is not None and not in_basin(model, best.pose, init)
    evidence = Evidence(
        consistency=best.consistency,
        runner_up_consistency=choice.runner_up_consistency,
        twins=len(choice.alternatives),
        points=len(observed.points),
        returns=0 if returns is None else len(returns),
        left_init=left_init,
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
        covariance=_covariance(best.result, best.pose),
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
