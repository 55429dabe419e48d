"""The synthetic dataset: geometry, LIDAR pattern and noise, splits, user meshes, format."""

import hashlib
import json

import numpy as np
import pytest
import trimesh

from sdcnet.camera import PAPER_CAMERA, PAPER_LIDAR
from sdcnet.dataset_format import SampleStore
from sdcnet.meshes import read_mesh_folder
from sdcnet.training.data.cli import main as data_main
from sdcnet.training.data.generate import GenerateConfig, close, generate, model_splits
from sdcnet.training.data.lidar import scan
from sdcnet.training.data.materials import Material, jittered_shading
from sdcnet.training.data.render import PosedModel, render_camera
from sdcnet.training.data.scene import Scene
from sdcnet.training.data.spacecraft import (
    SpacecraftModel,
    _crinkle_waves,
    load_mesh_file,
    procedural_spacecraft,
)

K = PAPER_CAMERA.intrinsics()


def plate_model(size_m: float = 20.0) -> SpacecraftModel:
    mesh = trimesh.creation.box((size_m, size_m, 0.01))
    rng = np.random.default_rng(0)
    materials = np.full(len(mesh.faces), Material.WHITE_PAINT, np.int16)
    return SpacecraftModel(
        "plate",
        mesh,
        materials,
        np.zeros((len(mesh.faces), 9)),
        jittered_shading(rng),
        _crinkle_waves(rng),
    )


def facing_scene(distance: float) -> Scene:
    # plate centre on the optical axis; its front face (z = -0.005 in the object frame) faces us
    return Scene(np.eye(3), np.array([0.0, 0.0, distance + 0.005]), np.array([0.0, 0.0, -1.0]), 0.0)


def test_flat_plate_renders_to_its_exact_distance():
    posed = PosedModel.place(plate_model(), facing_scene(100.0))
    frame = render_camera(posed, K, np.random.default_rng(0))
    assert np.all(frame.depth > 0), "a 20 m plate at 100 m fills the 12.9 m field of view"
    np.testing.assert_allclose(frame.depth, 100.0, atol=1e-3)
    assert frame.gray.mean() > 100, "a sunlit white plate is bright"


def test_lidar_returns_follow_the_angular_grid_and_noise_bound():
    posed = PosedModel.place(plate_model(), facing_scene(200.0))
    sparse = scan(posed.caster, PAPER_LIDAR, K, np.random.default_rng(1))
    v, u = np.nonzero(sparse)
    assert len(u) > 2500  # a 20 m plate at 200 m spans ~794 px: ~64 x 44 beams
    # spacing in pixels implied by the beam steps: fx * tan(step)
    expected_du = K.fx * np.tan(np.radians(PAPER_LIDAR.horizontal_step_deg))
    expected_dv = K.fy * np.tan(np.radians(PAPER_LIDAR.vertical_step_deg))
    centre_row = sparse[np.abs(np.arange(1024) - 511.5).argmin() + np.arange(-9, 10)]
    row = centre_row[np.argmax(np.count_nonzero(centre_row, axis=1))]
    du = np.diff(np.flatnonzero(row))
    assert np.median(du) == pytest.approx(expected_du, abs=1.0)
    assert expected_du == pytest.approx(12.47, abs=0.02)
    rows = np.unique(v)
    dv = np.diff(rows)
    assert np.median(dv) == pytest.approx(expected_dv, abs=1.0)
    assert expected_dv == pytest.approx(18.01, abs=0.02)
    # range noise within 3 cm: Z of a facing plate is its distance (up to beam obliquity)
    directions = K.pixel_rays(u, v)
    cos = 1 / np.linalg.norm(directions, axis=1)
    range_error = (sparse[v, u] - 200.0) / cos
    assert np.abs(range_error).max() < PAPER_LIDAR.range_error_m + 0.01
    assert range_error.std() > 0.003, "the noise is there"


def test_model_splits_are_disjoint_and_in_paper_ratio():
    config = GenerateConfig()
    splits = model_splits(config)
    by_split = {
        name: {m for m, s in splits.items() if s == name} for name in ("train", "val", "test")
    }
    assert [len(by_split[s]) for s in ("train", "val", "test")] == [99, 9, 18]
    assert not (by_split["train"] & by_split["test"]) and not (by_split["val"] & by_split["test"])
    assert not (by_split["train"] & by_split["val"])


def test_procedural_models_are_distinct_and_paper_sized():
    models = [procedural_spacecraft(0, m) for m in range(12)]
    signatures = {(len(m.mesh.faces), tuple(np.round(m.mesh.extents, 2))) for m in models}
    assert len(signatures) == 12
    assert len({m.name.split("-")[-1] for m in models}) >= 3, "several archetypes"
    assert all(1.0 < m.longest_m < 30.0 for m in models)
    again = procedural_spacecraft(0, 5)
    np.testing.assert_array_equal(again.mesh.vertices, models[5].mesh.vertices)


def test_user_mesh_loads_scaled_with_inferred_materials(tmp_path):
    wing = trimesh.creation.box((6.0, 2.0, 0.03))
    wing.apply_translation((4.0, 0, 0))
    bus = trimesh.creation.box((1.5, 1.5, 1.5))
    path = tmp_path / "sat.stl"
    trimesh.util.concatenate([bus, wing]).export(path)
    model = load_mesh_file(path, longest_m=14.0)
    assert model.longest_m == pytest.approx(14.0)
    assert np.allclose(model.mesh.bounds.mean(axis=0), 0)
    assert Material.SOLAR_CELL in model.materials and Material.MLI_GOLD in model.materials


def test_missing_or_broken_mesh_gives_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="mesh file not found"):
        load_mesh_file(tmp_path / "nope.stl")
    broken = tmp_path / "broken.stl"
    broken.write_bytes(b"solid x\nfacet normal 0 0 1\nthis is not an stl\n")
    with pytest.raises(ValueError, match=r"broken\.stl"):
        load_mesh_file(broken)
    (tmp_path / "manifest.json").write_text(json.dumps([{"file": "ghost.stl", "longest_m": 3}]))
    with pytest.raises(FileNotFoundError, match=r"ghost\.stl"):
        read_mesh_folder(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps([{"file": "broken.stl", "longest_m": -1}]))
    with pytest.raises(ValueError, match="longest_m"):
        read_mesh_folder(tmp_path)


def _digest(root):
    return {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file()
    }


def test_generation_is_deterministic_and_round_trips(tiny_dataset, tmp_path):
    store = SampleStore(tiny_dataset)
    assert len(store) == 6
    assert {r["split"] for r in store.records} == {"train", "val", "test"}
    record = store.records[0]
    sample = store.load(record)
    assert sample.gray.dtype == np.uint8 and sample.gray.shape == (256, 256)
    assert sample.depth.dtype == np.float32 and sample.sparse.dtype == np.float32
    assert sample.meta == record
    assert 50 <= record["distance_m"] <= 250
    # returns sit on the object at its depth (within range noise and edge effects)
    v, u = np.nonzero(sample.sparse)
    assert len(u) == record["returns"] > 0
    on_object = sample.depth[v, u] > 0
    assert on_object.mean() > 0.8
    assert np.median(np.abs(sample.sparse[v, u][on_object] - sample.depth[v, u][on_object])) < 0.5
    again = tmp_path / "again"
    generate(GenerateConfig(models=3, views=2, size=256, seed=0), again, workers=2, progress=False)
    assert _digest(again) == _digest(tiny_dataset)


def test_generation_resumes_and_refuses_mixed_settings(tiny_dataset, tmp_path):
    out = tmp_path / "d"
    config = GenerateConfig(models=3, views=2, size=128, seed=1)
    assert generate(config, out, shard=(0, 2), progress=False) is None  # half the work: no manifest
    assert not (out / "manifest.jsonl").exists()
    store = generate(config, out, shard=(1, 2), progress=False)
    assert store is not None and len(store) == 6
    with pytest.raises(ValueError, match="other settings"):
        generate(GenerateConfig(models=3, views=2, size=128, seed=2), out, progress=False)


def test_a_stopped_generation_is_closed_over_its_complete_samples(tmp_path):
    out = tmp_path / "d"
    config = GenerateConfig(models=3, views=2, size=128, seed=1)
    assert generate(config, out, shard=(0, 2), progress=False) is None
    with pytest.raises(FileNotFoundError, match="sdc-data close"):
        SampleStore(out)
    done = sorted(p.name for p in (out / "samples").glob("*.npz"))
    (out / "samples" / "m0002_v001.npz").write_bytes(b"PK cut off mid-write")
    store = close(out)
    assert sorted(r["file"].split("/")[-1] for r in store.records) == done
    assert len(store) == 3 and store.load(store.records[0]).gray.shape == (128, 128)
    assert len(generate(config, out, progress=False)) == 6  # resumed: the cut sample redone
    with pytest.raises(FileNotFoundError, match="not a dataset"):
        close(tmp_path)


def test_merged_datasets_hold_every_frame_of_each_under_its_own_id(tiny_dataset, tmp_path):
    other = tmp_path / "other"
    generate(GenerateConfig(models=3, views=1, size=128, seed=1), other, progress=False)
    out = tmp_path / "runs" / "both"  # not beside the sources: paths relative to it
    assert data_main(["merge", "--out", str(out), str(tiny_dataset), str(other)]) == 0
    merged, first, second = SampleStore(out), SampleStore(tiny_dataset), SampleStore(other)
    assert len(merged) == len(first) + len(second) == 9
    assert len({r["id"] for r in merged.records}) == 9
    for store in (first, second):
        for record in store.records:
            mine = next(r for r in merged.records if r["id"] == f"{store.root.name}/{record['id']}")
            assert mine["split"] == record["split"]
            a, b = merged.load(mine), store.load(record)
            assert np.array_equal(a.gray, b.gray) and np.array_equal(a.sparse, b.sparse)
    info = json.loads((out / "dataset.json").read_text())
    assert info["command"].startswith("sdc-data merge --out")
    assert [m["seed"] for m in info["merged_from"]] == [0, 1]
    assert [m["frames"] for m in info["merged_from"]] == [6, 3]


@pytest.mark.parametrize(
    "case, message",
    [
        ("one", "at least two"),
        ("same names", "folder names must differ"),
        ("not empty", "not empty"),
        ("no dataset", "no dataset.json"),
    ],
)
def test_a_merge_that_cannot_be_made_is_refused_with_its_reason(
    tiny_dataset, tmp_path, capsys, case, message
):
    out = tmp_path / "both"
    twin = tmp_path / "elsewhere" / tiny_dataset.name
    twin.parent.mkdir()
    twin.symlink_to(tiny_dataset)
    sources = {
        "one": [tiny_dataset],
        "same names": [tiny_dataset, twin],
        "not empty": [tiny_dataset, tiny_dataset.parent],
        "no dataset": [tiny_dataset, tmp_path],
    }[case]
    if case == "not empty":
        out.mkdir()
        (out / "notes.txt").write_text("mine")
    assert data_main(["merge", "--out", str(out), *map(str, sources)]) != 0
    assert message in capsys.readouterr().err
    if case == "not empty":
        assert [p.name for p in out.iterdir()] == ["notes.txt"]
    else:
        assert not out.exists()
