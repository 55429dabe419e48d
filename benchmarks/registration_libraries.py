"""small_gicp against Open3D on our clouds: local refinement and global registration.

    python -m benchmarks.registration_libraries [--views 6] [--model models/sdcnet.onnx]

Frames of the real spacecraft meshes (``--meshes``, the generator's camera, LIDAR and scene
ranges, seed 0) are completed by the ONNX model; each completed cloud is registered to its
target (``sdcnet.targets``: surface samples of the mesh in its own frame):

- local: from the true pose turned by 3 degrees about a random axis and moved 0.3 m (what a
  tracker at 10 Hz starts from), by small_gicp's GICP and Open3D's generalized ICP and
  point-to-plane ICP, on the same downsampled clouds with the same gates;
- global: from nothing, by Open3D's FPFH features + RANSAC then its generalized ICP, and by
  ``sdcnet.registration.estimate_pose`` (small_gicp inside) on the cloud alone.

Open3D is optional (``pip install open3d-cpu``): without it only small_gicp's rows print.
Errors: rotation in degrees, translation in metres; times per frame on one thread.
"""

from __future__ import annotations

import argparse
import time
from functools import partial
from pathlib import Path

import numpy as np
import small_gicp

from sdcnet.camera import Intrinsics
from sdcnet.evaluation.cli import REAL_MESHES  # from the repository root, as sdc-eval real
from sdcnet.meshes import read_mesh_folder
from sdcnet.pipeline import complete
from sdcnet.pointcloud import back_project
from sdcnet.registration import TargetModel, estimate_pose
from sdcnet.rigid import Pose, axis_angle, pose_errors
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.targets import load_target
from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample

SHIPPED = Path(__file__).resolve().parents[1] / "models" / "sdcnet.onnx"

try:
    import open3d as o3d
except ImportError:  # optional: the comparison's other half
    o3d = None


def frames(meshes: Path, views: int, model_path: Path):
    """(target, completed cloud, true pose) for ``views`` frames of each mesh."""
    entries = read_mesh_folder(meshes)
    config = GenerateConfig(models=0, views=views, seed=0, meshes=entries)
    onnx = OnnxModel(model_path, threads=1)
    for m, entry in enumerate(entries):
        target = load_target(entry)
        spacecraft = build_spacecraft(config, m)
        for v in range(views):
            sample = make_sample(config, spacecraft, m, v, "real")
            K = Intrinsics(**sample.meta["intrinsics"])
            result = complete(
                onnx.run, sample.gray, sample.sparse, K.fx, onnx.stride, onnx.info.work_pixels
            )
            truth = Pose(
                *spacecraft.file_frame_pose(
                    np.array(sample.meta["rotation"]), np.array(sample.meta["translation_m"])
                )
            )
            yield target, back_project(result.depth, result.mask, K).astype(np.float64), truth


def perturbed(truth: Pose, rng: np.random.Generator) -> Pose:
    axis = rng.normal(size=3)
    step = rng.normal(size=3)
    return Pose(
        axis_angle(axis, np.radians(3)) @ truth.R, truth.t + 0.3 * step / np.linalg.norm(step)
    )


def local_small_gicp(model: TargetModel, cloud: np.ndarray, start: Pose, voxel: float) -> Pose:
    source, _ = small_gicp.preprocess_points(cloud, downsampling_resolution=voxel)
    T = start.inverse().matrix()
    for gate in (0.1 * model.longest_m, 3 * voxel):
        T = small_gicp.align(
            model.cloud, source, model.tree, T, max_correspondence_distance=gate, max_iterations=30
        ).T_target_source
    return Pose.from_matrix(np.linalg.inv(T))


def _o3d_cloud(points: np.ndarray, voxel: float):
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
    cloud.estimate_covariances(o3d.geometry.KDTreeSearchParamKNN(10))
    return cloud


def local_open3d(model: TargetModel, target, points, start: Pose, voxel: float, kind: str) -> Pose:
    reg = o3d.pipelines.registration
    cloud = _o3d_cloud(points, voxel)
    method = (
        reg.TransformationEstimationForGeneralizedICP()
        if kind == "gicp"
        else reg.TransformationEstimationPointToPlane()
    )
    run = reg.registration_generalized_icp if kind == "gicp" else reg.registration_icp
    T = start.inverse().matrix()
    for gate in (0.1 * model.longest_m, 3 * voxel):
        criteria = reg.ICPConvergenceCriteria(max_iteration=30)
        T = run(cloud, target, gate, T, method, criteria).transformation
    return Pose.from_matrix(np.linalg.inv(T))


def global_sdcnet(model: TargetModel, points: np.ndarray) -> Pose:
    return estimate_pose(model, points).pose


def global_open3d(target, points: np.ndarray, voxel: float) -> Pose:
    reg = o3d.pipelines.registration
    cloud = _o3d_cloud(points, voxel)
    feature = o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    source_fpfh = reg.compute_fpfh_feature(cloud, feature)
    target_fpfh = reg.compute_fpfh_feature(target, feature)
    found = reg.registration_ransac_based_on_feature_matching(
        cloud,
        target,
        source_fpfh,
        target_fpfh,
        True,
        1.5 * voxel,
        reg.TransformationEstimationPointToPoint(False),
        3,
        [
            reg.CorrespondenceCheckerBasedOnEdgeLength(0.9),
            reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel),
        ],
        reg.RANSACConvergenceCriteria(100_000, 0.999),
    )
    T = reg.registration_generalized_icp(
        cloud,
        target,
        3 * voxel,
        found.transformation,
        reg.TransformationEstimationForGeneralizedICP(),
    ).transformation
    return Pose.from_matrix(np.linalg.inv(T))


def summary(name: str, errors: list[tuple[float, float, float]], rot: float, trans: float) -> str:
    e = np.array(errors)
    ok = (e[:, 0] <= rot) & (e[:, 1] <= trans)
    return (
        f"| {name} | {len(e)} | {np.mean(e[:, 0]):.2f} | {np.median(e[:, 0]):.2f} | "
        f"{np.mean(e[:, 1]):.3f} | {100 * ok.mean():.0f} % | {np.median(e[:, 2]):.1f} |"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--meshes", type=Path, default=REAL_MESHES)
    p.add_argument("--views", type=int, default=6, help="frames per mesh")
    p.add_argument("--model", type=Path, default=SHIPPED, help="ONNX model that completes")
    args = p.parse_args(argv)
    if o3d is not None:
        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    rng = np.random.default_rng(0)
    results: dict[str, list] = {}

    def record(name: str, fn, truth: Pose) -> None:
        start = time.perf_counter()
        pose = fn()
        elapsed = (time.perf_counter() - start) * 1e3
        results.setdefault(name, []).append((*pose_errors(pose, truth), elapsed))

    for target, cloud, truth in frames(args.meshes, args.views, args.model):
        model = target.model
        voxel = model.longest_m / 32
        start = perturbed(truth, rng)
        record(
            "local: small_gicp GICP", partial(local_small_gicp, model, cloud, start, voxel), truth
        )
        record(
            "global: sdcnet.registration (small_gicp)", partial(global_sdcnet, model, cloud), truth
        )
        if o3d is None:
            continue
        surface = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(model.surface))
        fine_target = surface.voxel_down_sample(model.longest_m / 250)
        fine_target.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(10))
        fine_target.estimate_covariances(o3d.geometry.KDTreeSearchParamKNN(10))
        coarse_target = _o3d_cloud(model.surface, voxel)
        for kind, name in (("gicp", "generalized ICP"), ("plane", "point-to-plane ICP")):
            record(
                f"local: Open3D {name}",
                partial(local_open3d, model, fine_target, cloud, start, voxel, kind),
                truth,
            )
        record(
            "global: Open3D FPFH + RANSAC + GICP",
            partial(global_open3d, coarse_target, cloud, voxel),
            truth,
        )
    print(
        "| method | frames | mean rot. error deg | median | mean transl. error m | "
        "within 2 deg, 0.2 m (local) / 5 deg, 0.5 m (global) | median ms |"
    )
    print("|---|---|---|---|---|---|---|")
    for name, errors in results.items():
        local = name.startswith("local")
        print(summary(name, errors, 2.0 if local else 5.0, 0.2 if local else 0.5))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
