"""Known targets from a mesh folder: names, frames (glTF scene graph), scale, clear errors."""

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sdcnet.targets import TargetError, load_targets

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real-meshes"


def _manifest(folder: Path, *entries: dict) -> None:
    (folder / "manifest.json").write_text(json.dumps(list(entries)))


def test_a_gltf_scene_graph_is_applied_and_the_target_scaled_in_its_own_frame(tmp_path):
    box = trimesh.creation.box((2.0, 1.0, 0.5))  # longest extent 2 (file units)
    moved = trimesh.transformations.rotation_matrix(np.pi / 2, [0, 0, 1])
    moved[:3, 3] = [10.0, 0.0, 0.0]
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="bus", transform=moved)
    scene.export(tmp_path / "sat.glb")
    box.export(tmp_path / "plain.stl")
    _manifest(tmp_path, {"file": "sat.glb", "longest_m": 8.0}, {"file": "plain.stl"})
    targets = load_targets(tmp_path)
    assert sorted(targets) == ["plain", "sat"]
    sat = targets["sat"]
    assert sat.longest_m == pytest.approx(8.0)
    # The node turned the box 90 degrees about z and moved it 10 units along x; then x4.
    lo, hi = sat.vertices.min(axis=0), sat.vertices.max(axis=0)
    np.testing.assert_allclose(lo, [4 * 9.5, -4 * 1.0, -4 * 0.25], atol=1e-4)
    np.testing.assert_allclose(hi, [4 * 10.5, 4 * 1.0, 4 * 0.25], atol=1e-4)
    plain = targets["plain"]  # no longest_m: the file's units are metres
    assert plain.longest_m == pytest.approx(2.0)
    described = sat.describe()
    assert described["name"] == "sat" and described["file"] == "sat.glb"
    assert described["symmetries"] == len(sat.model.symmetries) > 0  # a box turns onto itself
    assert described["near_twins"] == 0  # its turns are exact: symmetries, not near twins


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        (lambda d: (d / "manifest.json").write_text("{oops"), "not valid JSON"),
        (lambda d: _manifest(d, {"longest_m": 3}), "has no 'file'"),
        (lambda d: _manifest(d, {"file": "a.stl", "longest_m": -2}), "positive number"),
        (lambda d: _manifest(d, {"file": "ghost.stl"}), "mesh file not found"),
        (lambda d: (d / "a.stl").write_bytes(b"solid x\nnot an stl"), r"target a\.stl"),
        (
            lambda d: (d / "a.obj").write_text((d / "b.obj").read_text()),
            "share the name a",
        ),
    ],
    ids=["json", "no-file", "negative", "missing", "broken", "same-stem"],
)
def test_a_bad_targets_folder_is_explained(tmp_path, setup, message):
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    box.export(tmp_path / "a.stl")
    box.export(tmp_path / "b.obj")
    setup(tmp_path)
    with pytest.raises(TargetError, match=message):
        load_targets(tmp_path)


def test_a_missing_folder_is_explained(tmp_path):
    with pytest.raises(TargetError, match="not found"):
        load_targets(tmp_path / "nowhere")


@pytest.mark.skipif(not (REAL / "manifest.json").exists(), reason=f"no real meshes at {REAL}")
def test_the_real_meshes_load_as_targets_at_their_size():
    targets = load_targets(REAL)
    manifest = {
        Path(e["file"]).stem: e["longest_m"]
        for e in json.loads((REAL / "manifest.json").read_text())
    }
    assert sorted(targets) == sorted(manifest)
    for name, target in targets.items():
        assert target.longest_m == pytest.approx(manifest[name])
