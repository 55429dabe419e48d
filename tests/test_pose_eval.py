"""The pose evaluation: a rendered frame's pose from the shipped model's cloud, and the
bookkeeping (success, frames without a pose, the tables)."""

import math

import numpy as np
import pytest
import trimesh

from sdcnet.camera import Intrinsics
from sdcnet.evaluation.pose_eval import (
    RAW,
    FrameResult,
    evaluate_frames,
    perturbed,
    single_frames,
    suite_frames,
    symmetric_errors,
    truth_of,
)
from sdcnet.evaluation.pose_report import report, sigma_coverage, summary
from sdcnet.evaluation.robustness import render_condition
from sdcnet.evaluation.scoring import network
from sdcnet.meshes import read_mesh_folder
from sdcnet.pointcloud import back_project
from sdcnet.registration.target import surface_distances
from sdcnet.rigid import Pose, axis_angle, pose_errors
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.service.settings import shipped_model_path
from sdcnet.targets import load_target, prepare_target
from sdcnet.training.data.generate import GenerateConfig, build_spacecraft
from tests.support.targets import probe_mesh, write_targets


def _frame(rotation_deg: float, translation_m: float, cloud: str = "completed", **kw):
    fields = dict(
        spacecraft="a",
        cloud=cloud,
        mode="scratch",
        frame="m0000_v000",
        trajectory="",
        range_m=100.0,
        returns=50,
        rotation_deg=rotation_deg,
        translation_m=translation_m,
        ambiguous=False,
        among_answers=rotation_deg <= 2,
        registration_ms=10.0,
        cloud_ms=5.0,
    )
    return FrameResult(**{**fields, **kw})


def test_success_needs_both_errors_within_bounds_and_a_missing_pose_fails():
    frames = [_frame(1.0, 0.1), _frame(3.0, 0.1), _frame(1.0, 0.3), _frame(math.nan, math.nan)]
    s = summary(frames)
    assert s["frames"] == 4 and s["no_pose"] == 1
    assert s["success_pct"] == 25.0
    assert s["rotation_mean_deg"] == (1.0 + 3.0 + 1.0) / 3
    assert s["translation_mean_pct_range"] == pytest.approx(100 * (0.1 + 0.1 + 0.3) / 3 / 100.0)


def test_answers_marked_reliable_but_wrong_are_counted_beside_the_verdict_mix():
    frames = [
        _frame(0.5, 0.01, verdict="reliable"),
        _frame(3.0, 0.01, verdict="reliable"),  # wrong in rotation
        _frame(0.5, 0.5, verdict="reliable"),  # wrong in translation
        _frame(170.0, 0.1, verdict="ambiguous", reasons=("symmetric_twins",)),
        _frame(math.nan, math.nan),  # no pose: no verdict
    ]
    s = summary(frames)
    assert s["reliable_but_wrong"] == 2
    assert (s["verdict_reliable_pct"], s["verdict_ambiguous_pct"]) == (60.0, 20.0)
    assert s["verdict_unreliable_pct"] == 0.0
    assert (
        "Over all 5 answers: 3 marked reliable, of which 2 wrong"
        in report({"run": frames}, ["completed"])[0]
    )


def test_sigma_coverage_counts_errors_within_1_2_3_sigma():
    frames = [
        _frame(0.5, 0.01, rotation_sigma_deg=1.0, translation_sigma_m=0.02),  # within 1
        _frame(1.5, 0.05, rotation_sigma_deg=1.0, translation_sigma_m=0.02),  # 2, 3
        _frame(0.5, 0.01),  # no sigma: not covered
        _frame(5.0, 0.01, rotation_sigma_deg=1.0, translation_sigma_m=0.02),  # beyond 3, 1
    ]
    rotation, translation = sigma_coverage(frames)
    assert rotation == [25.0, 50.0, 50.0] and translation == [50.0, 50.0, 75.0]


def test_errors_modulo_symmetry_forgive_a_twin_and_inits_are_perturbed_as_asked():
    box = trimesh.creation.box((3.0, 2.0, 1.0))
    target = prepare_target("box", box.vertices, box.faces)
    truth = Pose(axis_angle([0.2, 1.0, -0.3], 1.1), np.array([0.1, 0.2, 60.0]))
    twin = Pose.from_matrix(truth.matrix() @ target.model.symmetries[0])
    assert pose_errors(twin, truth)[0] > 90
    rotation_deg, translation_m = symmetric_errors(target, twin, truth)
    assert rotation_deg < 0.5 and translation_m < 0.01
    rng = np.random.default_rng(0)
    for _ in range(5):
        rotation_deg, translation_m = pose_errors(perturbed(truth, 10.0, 1.0, rng), truth)
        assert rotation_deg == pytest.approx(10.0) and translation_m == pytest.approx(1.0)


def test_the_report_separates_clouds_modes_and_spacecraft():
    frames = [
        _frame(0.5, 0.01),
        _frame(0.4, 0.01, cloud="raw returns"),
        _frame(0.3, 0.01, mode="tracking", trajectory="tumble", spacecraft="b"),
    ]
    text, data = report({"run": frames}, ["completed", "raw returns"])
    assert list(data["run"]["overall"]) == ["completed", "completed, tracking", "raw returns"]
    assert "tumble, completed" in data["run"]["per_trajectory"]
    assert "b, completed, tracking" in data["run"]["per_spacecraft"]
    assert "### run" in text


def test_the_shipped_models_cloud_gives_the_pose_of_a_rendered_frame():
    """End to end as ``sdc-eval pose`` runs it: a procedural spacecraft rendered at 1024 x
    1024 by the generator, completed by the shipped model, registered from scratch."""
    config = GenerateConfig(models=1, views=1, seed=3, split=(1, 0, 0))
    craft = build_spacecraft(config, 0)
    target = prepare_target(craft.name, craft.mesh.vertices, craft.mesh.faces)
    onnx = OnnxModel(shipped_model_path(), threads=2)
    frames = single_frames(config, {0: (craft, target)}, 1, "test")
    results = {
        r.cloud: r
        for r in evaluate_frames(
            frames, {"completed": network(onnx.run, onnx.stride, onnx.info.work_pixels)}
        )
    }
    assert set(results) == {"completed", RAW}
    completed = results["completed"]
    assert completed.success, completed
    assert completed.rotation_deg < 1 and completed.translation_m < 0.1


def test_a_robustness_conditions_frames_come_with_their_true_poses_and_targets(tmp_path):
    """``sdc-eval pose --suite``: each docking frame (procedural models of the test split, a
    user's mesh after them) with the target it shows, its returns on that target's surface at
    the frame's true pose; the suite rendered from other meshes is refused."""
    meshes = read_mesh_folder(write_targets(tmp_path / "meshes", {"probe": (probe_mesh(), None)}))
    render_condition("docking", tmp_path, meshes, views=1, seed=0, workers=1, models=6)
    probe = build_spacecraft(GenerateConfig(models=0, meshes=meshes), 0)
    real = {0: (probe, load_target(meshes[0]))}  # the file's frame, as the service's
    frames = list(suite_frames(tmp_path / "docking", real))
    assert "probe" in [target.name for target, _ in frames] and len(frames) >= 2
    for target, sample in frames:
        assert target.name == sample.meta["model_name"]
        K = Intrinsics(**sample.meta["intrinsics"])
        returns = back_project(sample.sparse, sample.sparse > 0, K)
        if len(returns):
            noise = sample.meta["lidar"]["range_noise_m"]
            on = surface_distances(target.model, returns, truth_of(sample))
            assert np.median(on) < 2 * noise + 0.01, sample.meta["id"]
    other = prepare_target("other", probe.mesh.vertices, probe.mesh.faces)
    with pytest.raises(ValueError, match="shows probe"):
        list(suite_frames(tmp_path / "docking", {0: (probe, other)}))
