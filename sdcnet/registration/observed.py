"""The observed cloud, prepared (downsampled with covariances, and its depth grid across the
line of sight), and the consistency that scores a pose against it.

3. Each refined pose is scored by how well the target, drawn at that pose, explains the
   cloud as seen from the camera: on a grid across the line of sight, the cells where both
   hold a surface at the same depth, over the cells where either does (the target's cells
   count only outside the observed footprint, so a sparse cloud is not punished for its
   gaps). When the camera's ``view`` is known, the target is drawn only where the camera
   could see it: in front of it and inside its image. A spacecraft that overflows the frame
   at docking range, or whose parts lie behind the camera, is then not scored down for the
   parts no camera could show (at the true pose of an 11.7 m docking frame the whole target
   scored 0.26, the part in the image 0.90).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import cv2
import numpy as np
import small_gicp

from sdcnet.camera import Intrinsics
from sdcnet.registration.target import TargetModel, sight_basis
from sdcnet.rigid import Pose


@dataclass(frozen=True)
class Observed:
    """The observed cloud, prepared: downsampled with covariances, and its depth grid."""

    cloud: small_gicp.PointCloud  # downsampled, with covariances
    points: np.ndarray  # (n, 3) the points of ``cloud``
    centroid: np.ndarray  # (3,) of the cloud thinned evenly (pixel-uniform), metres
    basis: np.ndarray  # rows: two axes across the line of sight, the line of sight
    cell: float
    origin: np.ndarray  # (2,) grid corner across the line of sight
    depth: np.ndarray  # (H, W) nearest depth along the line of sight, inf = none
    footprint: np.ndarray  # (H, W) bool: the observed cells, grown over the cloud's gaps
    tolerance: float  # depths closer than this agree, metres
    coarse_voxel: float  # metres, of ``coarse``
    view: Intrinsics | None = None  # the camera the cloud was seen by (None: unbounded)
    at_border: bool = False  # the cloud reaches the edge of the view's image

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


def evenly(cloud: np.ndarray, most: int) -> np.ndarray:
    """Every k-th point of ``cloud`` (N, 3), k = N // ``most`` (at least 1). A completed cloud
    holds a point per pixel (up to ~10^6); every k-th of them (pixel order: an even thinning of
    the image) still fills every voxel of L / 32."""
    return cloud[:: max(1, len(cloud) // most)]


def thinned_to(points: np.ndarray, most: int) -> np.ndarray:
    """Every k-th of (N, 3) ``points``, at most ``most`` of them (``evenly`` may keep up to
    twice ``most``). Bounds the time and memory of one registration: a bright 2048 x 2048
    frame's 4M points and 262,144 returns took 19 s (the returns' refinement, holding the
    interpreter all along), 0.7 s thinned."""
    return points[:: -(-len(points) // most)] if len(points) > most else points


def span_m(points: np.ndarray) -> float:
    """The largest extent of (N, 3) ``points`` along an axis, metres. Taken on a transposed
    copy: numpy reduces across the rows of a three-column array 20 times slower (2.3 ms for
    a completed cloud's 44,000 points)."""
    columns = np.ascontiguousarray(points.T)
    return float(np.max(columns.max(axis=1) - columns.min(axis=1)))


def observe(cloud: np.ndarray, model: TargetModel, view: Intrinsics | None = None) -> Observed:
    """``cloud`` (N, 3, camera frame, metres) prepared for scoring poses against it; ``view``:
    the camera (pixels) whose image bounds what the cloud could show, when known."""
    config = model.config
    L = model.longest_m
    points = np.asarray(evenly(cloud, config.max_cloud_points), np.float64)
    centroid = np.mean(points, axis=0)
    # Voxels of L / 32, or coarser when the cloud spans more than the target (a cloud that
    # is not of this target, or wrong intrinsics): at most ~48 across, so the cost stays bound.
    span = span_m(points)
    voxel = max(L * config.voxel_of_longest, span / 48)
    small, _ = small_gicp.preprocess_points(points, downsampling_resolution=voxel, num_neighbors=10)
    kept = np.asarray(small.points())[:, :3]
    basis = sight_basis(centroid / np.linalg.norm(centroid))
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
    return Observed(
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
        view,
        view is not None and _reaches_border(points, view),
    )


#: A cloud with a point within this many pixels of the image's edge reaches it.
BORDER_PX = 2


def _reaches_border(points: np.ndarray, view: Intrinsics) -> bool:
    """Whether any of (N, 3) camera-frame ``points`` projects within ``BORDER_PX`` of the edge
    of ``view``'s image: the camera may frame only part of the target."""
    inner = replace(
        view,
        cx=view.cx - BORDER_PX,
        cy=view.cy - BORDER_PX,
        width=view.width - 2 * BORDER_PX,
        height=view.height - 2 * BORDER_PX,
    )
    return not bool(np.all(framed_by(points, inner)))


def framed_by(points: np.ndarray, view: Intrinsics) -> np.ndarray:
    """Bool (...): which of the camera-frame ``points`` (..., 3), metres, the camera ``view``
    frames: in front of it and projected inside its image."""
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = view.project(points)
    inside = (u >= -0.5) & (u < view.width - 0.5) & (v >= -0.5) & (v < view.height - 0.5)
    return (points[..., 2] > 0) & inside


def in_view(points: np.ndarray, view: Intrinsics | None) -> np.ndarray:
    """The rows of (N, 3) camera-frame ``points`` the camera ``view`` frames (all of them when
    ``view`` is None)."""
    return points if view is None else points[framed_by(points, view)]


def consistency(model: TargetModel, pose: Pose, observed: Observed) -> float:
    """Share of the cells, where either the target at ``pose`` or the cloud shows a surface,
    in which both do at the same depth (step 3 of the module docstring); the target drawn
    only where ``observed.view`` sees."""
    uvd = in_view(pose.apply(model.render_points), observed.view) @ observed.basis.T
    drawn = _grid_depth(uvd, observed.origin, observed.cell, observed.depth.shape)
    seen = np.isfinite(observed.depth)
    has = np.isfinite(drawn)
    both = has & seen
    agree = np.count_nonzero(np.abs(drawn[both] - observed.depth[both]) < observed.tolerance)
    outside = np.count_nonzero(has & ~observed.footprint)
    union = np.count_nonzero(both) + np.count_nonzero(seen & ~has) + outside
    return agree / max(union, 1)
