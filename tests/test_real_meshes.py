"""Real spacecraft meshes (../shared/real-meshes, NASA 3D Resources) through the generator."""

import json
from pathlib import Path

import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA
from sdcnet.meshes import read_mesh_folder
from sdcnet.training.data.render import PosedModel, render_camera
from sdcnet.training.data.scene import Scene
from sdcnet.training.data.spacecraft import load_mesh_file

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real-meshes"
pytestmark = pytest.mark.skipif(
    not (REAL / "manifest.json").exists(), reason=f"no real meshes at {REAL}"
)


def test_manifest_scales_every_mesh_to_its_real_size():
    entries = {e.path.name: e for e in read_mesh_folder(REAL)}
    assert len(entries) == 8
    manifest = {e["file"]: e["longest_m"] for e in json.loads((REAL / "manifest.json").read_text())}
    lro = entries["lro.stl"]
    model = load_mesh_file(lro.path, longest_m=lro.longest_m)
    assert model.longest_m == pytest.approx(manifest["lro.stl"])


def test_a_real_mesh_renders_at_its_scale_and_distance():
    model = load_mesh_file(REAL / "dawn.stl", longest_m=19.7)
    K = PAPER_CAMERA.intrinsics()
    distance = 150.0
    scene = Scene(np.eye(3), np.array([0.0, 0.0, distance]), np.array([0.0, 0.0, -1.0]), 0.0)
    frame = render_camera(PosedModel.place(model, scene), K, np.random.default_rng(0))
    z = frame.depth[frame.depth > 0]
    lo, hi = model.mesh.bounds[:, 2]
    assert distance + lo - 1e-3 <= z.min() and z.max() <= distance + hi + 1e-3
    cols = np.flatnonzero((frame.depth > 0).any(axis=0))
    width_px = cols.max() - cols.min() + 1
    expected = np.ptp(model.mesh.bounds[:, 0]) * K.fx / distance  # ~1043 px: clipped by the frame
    assert width_px == pytest.approx(min(expected, K.width), rel=0.03)
    rows = np.flatnonzero((frame.depth > 0).any(axis=1))
    assert (
        rows.max() - rows.min() + 1 <= np.ptp(model.mesh.bounds[:, 1]) * K.fy / (distance + lo) + 2
    )


def test_missing_or_malformed_manifest_entries_are_explained(tmp_path):
    (tmp_path / "a.stl").write_bytes((REAL / "lro.stl").read_bytes())
    (tmp_path / "manifest.json").write_text(json.dumps([{"name": "a", "longest_m": 4.5}]))
    with pytest.raises(ValueError, match="has no 'file'"):
        read_mesh_folder(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps([{"file": "a.stl", "longest_m": "big"}]))
    with pytest.raises(ValueError, match="longest_m must be a positive number"):
        read_mesh_folder(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        read_mesh_folder(tmp_path)


def test_sdc_data_example_makes_the_shipped_example_again(tmp_path, capsys):
    """``examples/`` is what ``sdc-data example`` renders (the README says how it was made)."""
    from sdcnet.training.data.cli import main as data_main

    argv = ["example", "--meshes", str(REAL), "--name", "tdrs", "--seed", "1"]
    assert data_main([*argv, "--distance", "140", "--out", str(tmp_path)]) == 0
    shipped = Path(__file__).resolve().parents[1] / "examples"
    for name in ("tdrs.png", "tdrs.returns.csv"):
        assert (tmp_path / name).read_bytes() == (shipped / name).read_bytes(), name
    assert data_main([*argv[:3], "--name", "hubble", "--out", str(tmp_path)]) == 2
    assert "no mesh called 'hubble'" in capsys.readouterr().err
