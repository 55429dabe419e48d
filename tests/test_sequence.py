"""Pose-tracking sequences: trajectories at 10 Hz, every frame's true pose in the file's frame."""

import json

import numpy as np
import small_gicp
import trimesh

from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore
from sdcnet.pointcloud import back_project
from sdcnet.rigid import Pose, rotation_angle_deg
from sdcnet.training.data.cli import main as sdc_data


def test_sequences_carry_the_pose_of_every_frame_in_the_mesh_files_frame(tmp_path):
    # A mesh far from its file's origin: the pose must be of the file's frame, not the
    # generator's centred one.
    mesh = trimesh.creation.box((6.0, 2.0, 1.0))
    mesh = trimesh.util.concatenate([mesh, trimesh.creation.box((1.0, 1.0, 3.0))])
    mesh.apply_translation([5.0, -2.0, 1.0])
    folder = tmp_path / "meshes"
    folder.mkdir()
    mesh.export(folder / "craft.stl")
    (folder / "manifest.json").write_text(json.dumps([{"file": "craft.stl", "longest_m": 12.0}]))
    out = tmp_path / "seq"
    assert (
        sdc_data(
            [
                "sequence",
                "--out",
                str(out),
                "--meshes",
                str(folder),
                "--frames",
                "4",
                "--size",
                "256",
                "--quiet",
            ]
        )
        == 0
    )
    store = SampleStore(out)
    assert len(store) == 12  # 3 trajectories x 4 frames
    surface, _ = trimesh.sample.sample_surface(mesh, 100_000, seed=0)
    tree = small_gicp.KdTree(np.asarray(surface) * 2.0)  # the manifest's scale: 6 -> 12 m
    by_sequence: dict[str, list] = {}
    for record in store.records:
        sample = store.load(record)
        pose = Pose(np.array(record["pose"]["R"]), np.array(record["pose"]["t"]))
        # The true depth, taken back to the file's frame by the pose, lies on the mesh.
        K = Intrinsics(**record["intrinsics"])
        points = pose.inverse().apply(back_project(sample.depth, sample.mask, K))
        _, squared = tree.batch_nearest_neighbor_search(points.astype(np.float64))
        assert np.median(np.sqrt(squared)) < 0.05, record["id"]  # samples ~4 cm apart
        by_sequence.setdefault(record["trajectory"], []).append((record, pose))
    approach = by_sequence["approach"]
    assert approach[0][0]["distance_m"] == 250.0 and approach[-1][0]["distance_m"] == 50.0
    assert [r["frame"] for r, _ in approach] == [0, 1, 2, 3]
    assert approach[1][0]["time_s"] == 0.1
    fly = by_sequence["flyaround"]
    assert len({r["distance_m"] for r, _ in fly}) == 1
    step = rotation_angle_deg(fly[0][1].R, fly[1][1].R)
    assert abs(step - 1.5) < 0.01  # 15 deg/s at 10 Hz
    tumble = by_sequence["tumble"]
    assert 0.5 < rotation_angle_deg(tumble[0][1].R, tumble[1][1].R) < 1.5  # ~10 deg/s


def test_a_docking_sequence_closes_in_seen_by_one_docking_camera_and_lidar(tmp_path):
    mesh = trimesh.creation.box((4.0, 1.5, 1.0))
    folder = tmp_path / "meshes"
    folder.mkdir()
    mesh.export(folder / "craft.stl")
    (folder / "manifest.json").write_text(json.dumps([{"file": "craft.stl", "longest_m": 4.0}]))
    out = tmp_path / "seq"
    args = ["sequence", "--out", str(out), "--meshes", str(folder), "--frames", "3"]
    assert sdc_data([*args, "--trajectories", "docking", "--quiet"]) == 0
    store = SampleStore(out)
    records = sorted(store.records, key=lambda r: r["frame"])
    assert [r["trajectory"] for r in records] == ["docking"] * 3
    # 12 m -> 4 m (the box's bounding sphere, 2.2 m, plus the metre's clearance is nearer)
    assert [r["distance_m"] for r in records] == [12.0, 8.0, 4.0]
    cameras = {json.dumps(r["intrinsics"], sort_keys=True) for r in records}
    assert len(cameras) == 1  # one camera for the whole sequence ...
    K = Intrinsics(**records[0]["intrinsics"])
    hfov = np.degrees(2 * np.arctan(K.width / 2 / K.fx))
    assert 40.0 <= hfov <= 60.0  # ... the docking world's, not the paper's 5.7 deg
    assert records[0]["lidar"]["kind"] in ("flash", "scanning")  # an array or a grid
    assert len({r["lidar"]["kind"] for r in records}) == 1
    surface, _ = trimesh.sample.sample_surface(mesh, 50_000, seed=0)
    tree = small_gicp.KdTree(np.asarray(surface, dtype=np.float64))
    for record in records:
        sample = store.load(record)
        pose = Pose(np.array(record["pose"]["R"]), np.array(record["pose"]["t"]))
        assert record["returns"] > 100, record["id"]  # metres away: hundreds of returns
        returns = pose.inverse().apply(back_project(sample.sparse, sample.sparse > 0, K))
        _, squared = tree.batch_nearest_neighbor_search(returns.astype(np.float64))
        assert np.median(np.sqrt(squared)) < 0.05, record["id"]  # on the box, within noise
