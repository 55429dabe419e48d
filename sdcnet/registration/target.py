"""A target's mesh prepared once for the registration (``TargetModel``): surface samples, GICP
clouds with covariances, a distance field, what the target shows from many view directions,
its self-symmetries and near twins; and the distances of observed points to its surface."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import small_gicp
import trimesh

from sdcnet.registration.config import DEFAULT_CONFIG, RegistrationConfig
from sdcnet.rigid import Pose, axis_angle, rotation_angle_deg


def fibonacci_sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere."""
    i = np.arange(count) + 0.5
    polar = np.arccos(1 - 2 * i / count)
    azimuth = np.pi * (1 + 5**0.5) * i
    return np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], 1
    )


def sight_basis(direction: np.ndarray) -> np.ndarray:
    """(3, 3) rows: two unit vectors across ``direction``, then ``direction`` itself."""
    helper = np.array([1.0, 0, 0]) if abs(direction[0]) < 0.9 else np.array([0, 1.0, 0])
    a = np.cross(direction, helper)
    a /= np.linalg.norm(a)
    return np.stack([a, np.cross(direction, a), direction])


#: Visible points kept per view direction for the coarse search's framing (``visible_samples``).
VISIBLE_SAMPLES = 128


def _evenly(points: np.ndarray, count: int) -> np.ndarray:
    """``count`` rows of ``points`` evenly spread over them (repeated when there are fewer)."""
    return points[np.linspace(0, len(points) - 1, count).round().astype(np.int64)]


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

    def near(self, points: np.ndarray, reach: float | None = None) -> np.ndarray:
        """Whether target-frame ``points`` (N, 3) may lie within ``reach`` metres of the
        surface (within the truncation when None). A cell holds its centre's distance, which
        differs from its points' by at most 0.87 cell: none within ``reach`` is left out."""
        limit = self.truncation if reach is None else min(reach + self.cell, self.truncation)
        return self.at_cells((points - self.origin) / self.cell) < limit

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
        visible = [thinned[_zbuffer(thinned, sight_basis(w), L / 64)] for w in self.views]
        self.visible_centroids = np.array([v.mean(axis=0) for v in visible])
        # (views, VISIBLE_SAMPLES, 3): an even share of each view's visible points, to find
        # the part a camera frames (``sdcnet.registration.search``)
        self.visible_samples = np.stack([_evenly(v, VISIBLE_SAMPLES) for v in visible]).astype(
            np.float32
        )
        render = small_gicp.voxelgrid_sampling(
            small_gicp.PointCloud(self.surface), L * config.grid_cell_of_longest / 2.5
        )
        self.render_points = np.asarray(render.points())[:, :3]
        self_fit = _SelfFit(self)
        self.symmetries = self._symmetries(self_fit, _dominant_normals(mesh))
        self.near_twins = self._near_twins(self_fit)

    def _symmetries(self, self_fit: _SelfFit, normals: np.ndarray) -> list[np.ndarray]:
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
        tolerance = self_fit.floor + self.config.symmetry_tolerance_of_longest * self.longest_m
        found: list[np.ndarray] = []

        def add(S: np.ndarray) -> None:
            if self._new_turn(S, found) and self_fit.spread(S) <= tolerance:
                found.append(S)

        for axis in [*self_fit.principal, *normals]:
            for n in (2, 3, 4, 6):
                T = self_fit.turn(axis, 2 * np.pi / n)
                if self_fit.coarse_spread(T) > 4 * self_fit.coarse_floor:
                    continue
                T = self_fit.refined(T)
                for S in (T, np.linalg.inv(T)):
                    add(S)
        for A, B in [(A, B) for A in found for B in found]:  # compositions: a box's third turn
            add(A @ B)
        return found

    def _near_twins(self, self_fit: _SelfFit) -> list[np.ndarray]:
        """Turns by 180 degrees about the principal axes that map the target almost onto
        itself, within ``near_twin_tolerance_of_longest`` x L but not a symmetry: poses P S
        the completed cloud hardly tells from P, which only the returns (centimetres, on the
        parts that differ) can. The search offers the best pose turned by each
        (``sdcnet.registration.search``); Juno's and a comsat's panels turned the answer 180
        degrees without them (docs/pose/README.md)."""
        L = self.longest_m
        tolerance = self_fit.floor + self.config.near_twin_tolerance_of_longest * L
        twins: list[np.ndarray] = []
        for axis in self_fit.principal:
            T = self_fit.refined(self_fit.turn(axis, np.pi))
            if self._new_turn(T, [*self.symmetries, *twins]) and self_fit.spread(T) <= tolerance:
                twins.append(T)
        return twins

    def _new_turn(self, T: np.ndarray, known: list[np.ndarray]) -> bool:
        """Whether the turn of ``T`` is at least ``alternative_deg`` from no turn and from
        each of ``known``."""
        angles = [rotation_angle_deg(T[:3, :3], K[:3, :3]) for K in [np.eye(4), *known]]
        return min(angles) >= self.config.alternative_deg


class _SelfFit:
    """How well the target, moved by a rigid motion T (4 x 4, target frame), lies on itself:
    its surface thinned to L / 48 (the probe), moved, measured against the distance field
    (coarse) or the dense samples, beside the floor the sampling sets (T = identity)."""

    def __init__(self, model: TargetModel):
        self.model = model
        L = model.longest_m
        self.probe, _ = small_gicp.preprocess_points(
            model.surface, downsampling_resolution=L / 48, num_neighbors=10
        )
        self.points = np.asarray(self.probe.points())[:, :3]
        self.centre = model.surface.mean(axis=0)
        _, _, self.principal = np.linalg.svd(model.surface - self.centre, full_matrices=False)
        self.coarse_floor = self.coarse_spread(np.eye(4))
        self.floor = self.spread(np.eye(4))

    def moved(self, T: np.ndarray) -> np.ndarray:
        """The probe's points moved by ``T``, (N, 3) metres."""
        return self.points @ T[:3, :3].T + T[:3, 3]

    def coarse_spread(self, T: np.ndarray) -> float:
        """The moved probe's mean distance to the surface read from the distance field."""
        field = self.model.field
        return float(np.mean(field.at_cells((self.moved(T) - field.origin) / field.cell)))

    def spread(self, T: np.ndarray) -> float:
        """The moved probe's mean distance to the dense samples, each at most L / 50."""
        _, squared = self.model.tree.batch_nearest_neighbor_search(self.moved(T))
        return float(np.mean(np.minimum(np.sqrt(squared), self.model.longest_m / 50)))

    def turn(self, axis: np.ndarray, angle: float) -> np.ndarray:
        """The turn by ``angle`` (radians) about ``axis`` through the centroid, 4 x 4."""
        R = axis_angle(axis, angle)
        return Pose(R, self.centre - R @ self.centre).matrix()

    def refined(self, T: np.ndarray) -> np.ndarray:
        """``T`` refined by GICP of the probe onto the target's sparse samples."""
        model = self.model
        return small_gicp.align(
            model.sparse_cloud,
            self.probe,
            model.sparse_tree,
            T,
            max_correspondence_distance=model.longest_m / 20,
        ).T_target_source


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


def surface_fit(model: TargetModel, points: np.ndarray, pose: Pose, gate: float):
    """(share of points within ``gate`` of the surface, RMS distance of those)."""
    d = surface_distances(model, points, pose)
    inliers = d < gate
    rmse = float(np.sqrt(np.mean(d[inliers] ** 2))) if inliers.any() else float("inf")
    return float(inliers.mean()), rmse
