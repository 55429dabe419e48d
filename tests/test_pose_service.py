"""``POST /pose`` against a real started service: the shipped model, a targets folder."""

import json
import subprocess
import sys

import cv2
import httpx
import numpy as np
import pytest
from fixtures_runtime import SHIPPED_MODEL, png_bytes, running_service, sample_files

from sdcnet.client.api import Client, ServiceError
from sdcnet.client.cli import main as client_main
from sdcnet.meshes import read_mesh_folder
from sdcnet.npyio import npy_bytes
from sdcnet.rigid import Pose, parse_pose, pose_errors
from sdcnet.training.data.generate import GenerateConfig, build_model, make_sample
from sdcnet.training.data.spacecraft import procedural_spacecraft

pytestmark = pytest.mark.skipif(not SHIPPED_MODEL.exists(), reason="no shipped model")


@pytest.fixture(scope="module")
def targets_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("targets")
    procedural_spacecraft(11, 4).mesh.export(folder / "probe.stl")
    (folder / "manifest.json").write_text(json.dumps([{"file": "probe.stl", "longest_m": 9.0}]))
    return folder


@pytest.fixture(scope="module")
def frames(targets_dir):
    """Two 1024 x 1024 frames of the target (two views) and its true poses, file frame."""
    config = GenerateConfig(models=0, views=2, seed=4, meshes=read_mesh_folder(targets_dir))
    craft = build_model(config, 0)
    out = []
    for view in range(2):
        sample = make_sample(config, craft, 0, view, "real")
        R, t = craft.file_frame_pose(
            np.array(sample.meta["rotation"]), np.array(sample.meta["translation_m"])
        )
        out.append((sample, Pose(R, t)))
    return out


@pytest.fixture(scope="module")
def service(targets_dir, tmp_path_factory):
    log = tmp_path_factory.mktemp("logs") / "serve.log"
    with running_service(SHIPPED_MODEL, log, "--targets", str(targets_dir)) as url:
        yield url


def post(url: str, sample, **data) -> httpx.Response:
    return httpx.post(f"{url}/pose", files=sample_files(sample), data=data, timeout=120)


def test_the_pose_of_a_frame_then_tracked(service, frames):
    sample, truth = frames[0]
    response = post(service, sample, target="probe")
    assert response.status_code == 200, response.text
    assert response.headers["server-timing"].startswith("decode;dur=")
    answer = response.json()
    rotation_deg, translation_m = pose_errors(parse_pose(answer["pose"]), truth)
    assert rotation_deg < 2 and translation_m < 0.2
    assert not answer["tracked"] and answer["hypotheses"] > 1
    assert answer["completion"]["returns"] == int(np.count_nonzero(sample.sparse))
    assert answer["completion"]["point_count"] > 1000
    assert 0 < answer["fitness"] <= 1 and answer["returns_rmse_m"] < 0.1
    assert np.array(answer["covariance"]).shape == (6, 6)
    assert set(answer["timings"]) >= {"inference_ms", "registration_ms", "search_ms"}
    # The same frame from its own answer: tracked, no search.
    again = post(service, sample, target="probe", init=json.dumps(answer["pose"])).json()
    assert again["tracked"] and again["hypotheses"] == 1 and again["timings"]["search_ms"] == 0
    assert pose_errors(parse_pose(again["pose"]), truth)[0] < 2
    # A quaternion init works as well as a matrix.
    quaternion = {"quaternion_wxyz": answer["pose"]["quaternion_wxyz"], "t": answer["pose"]["t"]}
    assert post(service, sample, target="probe", init=json.dumps(quaternion)).json()["tracked"]


def test_the_model_lists_the_targets(service):
    targets = httpx.get(f"{service}/model").json()["targets"]
    assert [t["name"] for t in targets] == ["probe"]
    assert targets[0]["longest_m"] == pytest.approx(9.0)


@pytest.mark.parametrize(
    ("data", "code", "message"),
    [
        ({"target": "nope"}, "unknown_target", "known targets: probe"),
        ({"target": "probe", "init": "{not json"}, "invalid_init", "not valid JSON"),
        ({"target": "probe", "init": '{"t": [0, 0]}'}, "invalid_init", "shape"),
        (
            {"target": "probe", "init": '{"R": [[2,0,0],[0,1,0],[0,0,1]], "t": [0,0,1]}'},
            "invalid_init",
            "not a rotation",
        ),
        ({}, "invalid_request", "target"),
        ({"target": "probe", "targett": "x"}, "invalid_request", "unknown form field"),
    ],
)
def test_bad_requests_get_a_clear_4xx(service, frames, data, code, message):
    response = post(service, frames[1][0], **data)
    assert response.status_code == (404 if code == "unknown_target" else 422)
    error = response.json()["error"]
    assert error["code"] == code and message in error["message"]
    assert httpx.get(f"{service}/ready").status_code == 200


def test_a_frame_with_too_few_points_is_refused(service):
    gray = np.zeros((256, 256), np.uint8)
    sparse = np.zeros((256, 256), np.float32)
    sparse[128, 128] = 100.0
    files = {"gray": ("g.png", png_bytes(gray)), "sparse": ("s.npy", npy_bytes(sparse))}
    response = httpx.post(f"{service}/pose", files=files, data={"target": "probe"}, timeout=60)
    assert response.status_code == 422
    assert response.json()["error"]["code"] == "too_few_points"


def test_a_bad_targets_folder_stops_the_start_with_one_line(tmp_path):
    (tmp_path / "manifest.json").write_text(json.dumps([{"file": "ghost.stl"}]))
    command = [sys.executable, "-m", "sdcnet.service", "--model", str(SHIPPED_MODEL)]
    done = subprocess.run(
        [*command, "--targets", str(tmp_path), "--port", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 2
    assert "sdc-serve: targets folder" in done.stderr and "ghost.stl" in done.stderr


def test_sdc_client_pose_prints_the_pose_and_draws_the_target(service, frames, tmp_path, capsys):
    sample, truth = frames[0]
    (tmp_path / "gray.png").write_bytes(png_bytes(sample.gray))
    np.save(tmp_path / "sparse.npy", sample.sparse)
    argv = ["pose", str(tmp_path / "gray.png"), str(tmp_path / "sparse.npy"), "--target", "probe"]
    argv += ["--url", service, "--out", str(tmp_path / "out")]
    assert client_main(argv) == 0
    printed = capsys.readouterr().out
    assert "pose of probe" in printed and "from scratch" in printed
    answer = json.loads((tmp_path / "out" / "pose.json").read_text())
    assert pose_errors(parse_pose(answer["pose"]), truth)[0] < 2
    preview = cv2.imread(str(tmp_path / "out" / "preview.png"))
    assert preview.shape[0] == 320 and preview.shape[1] >= 2 * 320
    # Drawn in colour over the gray tile: the target's samples at the pose.
    drawn = preview[:, 324:644]
    assert np.count_nonzero(np.ptp(drawn.astype(int), axis=2) > 30) > 200
    # Tracking from the written answer.
    argv += ["--init", str(tmp_path / "out" / "pose.json")]
    assert client_main(argv) == 0
    assert "tracked" in capsys.readouterr().out
    assert client_main([*argv[:4], "nope", *argv[5:]]) == 3
    assert "unknown_target" in capsys.readouterr().err


def test_the_python_api_tracks_and_fetches_the_targets_samples(service, frames):
    with Client(service) as client:
        first = client.pose(frames[1][0].gray, frames[1][0].sparse, "probe")
        again = client.pose(frames[1][0].gray, frames[1][0].sparse, "probe", init=first.pose)
        points = client.target_points("probe")
        with pytest.raises(ServiceError, match="unknown_target"):
            client.target_points("nope")
    assert not first.answer["tracked"] and again.answer["tracked"]
    assert pose_errors(again.pose, frames[1][1])[0] < 2
    assert points.shape[1] == 3 and 1000 < len(points) <= 5000
    assert np.ptp(points, axis=0).max() == pytest.approx(9.0, rel=0.05)
