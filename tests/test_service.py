"""The inference service, fed synthetic frames, on the tiny sdcnet-shaped ONNX model (real
onnxruntime sessions; no torch). Most tests run twice, through the ``client`` fixture:

- ``uvicorn``: over real HTTP, the real app under uvicorn in a subprocess (``sdc-serve``);
- ``in-process``: FastAPI's ``TestClient`` on ``create_app`` with the same model, loaded once
  for the module (its lifespan runs; no socket).

Those that need real sockets or concurrency talk to the subprocess only; those that reach
inside the app run in process only, through dependency overrides (``get_engine``,
``get_settings``): not ready, a model that fails, other limits.
"""

from __future__ import annotations

import base64
import io
import json
import math
import re
import subprocess
import sys
import threading
import time
import zipfile

import cv2
import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from sdcnet.calibration import CameraCalibration, Undistorter
from sdcnet.camera import Intrinsics
from sdcnet.caveats import FEW_RETURNS, UNCERTAIN_MASK_IOU
from sdcnet.client.api import Client
from sdcnet.npyio import npy_bytes
from sdcnet.pipeline import WORK_PIXELS, complete
from sdcnet.pointcloud import back_project, cloud_stride, read_ply, statistical_outliers
from sdcnet.returns import returns_from_dense, scatter_nearest
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.service import inference
from sdcnet.service.admission import slot_routes
from sdcnet.service.app import create_app
from sdcnet.service.camera import ANSWER_FRAME
from sdcnet.service.deps import get_engine
from sdcnet.service.inference import Engine, warm_up, warm_up_frame
from sdcnet.service.routes import ROUTERS
from sdcnet.service.settings import Settings, get_settings
from tests.support.frames import png_bytes, synthetic_frame
from tests.support.models import TINY_VERSION
from tests.support.serving import running_service

MAX_PIXELS = 1024 * 1024
MAX_UPLOAD_BYTES = 8 * 2**20
MAX_IN_FLIGHT = 2
MAX_REQUESTS = 4


def settings(model_path) -> Settings:
    return Settings(
        model_path=model_path,
        threads=1,
        max_in_flight=MAX_IN_FLIGHT,
        max_requests=MAX_REQUESTS,
        max_pixels=MAX_PIXELS,
        max_upload_bytes=MAX_UPLOAD_BYTES,
        retry_after_s=2,
    )


@pytest.fixture(scope="module")
def model_path(tiny_model_path):
    return tiny_model_path


@pytest.fixture(scope="module")
def url(model_path, tmp_path_factory):
    log = tmp_path_factory.mktemp("service") / "serve.log"
    flags = [f"--max-in-flight={MAX_IN_FLIGHT}", f"--max-pixels={MAX_PIXELS}"]
    flags += [f"--max-upload-bytes={MAX_UPLOAD_BYTES}", "--retry-after=2"]
    flags += [f"--max-requests={MAX_REQUESTS}"]
    with running_service(model_path, log, *flags) as address:
        yield address


@pytest.fixture(scope="module")
def engine(model_path) -> Engine:
    return Engine(OnnxModel(model_path, provider="cpu", threads=1))


@pytest.fixture(scope="module", params=["uvicorn", "in-process"])
def client(request, model_path, engine):
    """An HTTP client of the service: the subprocess's URL, or the app in this process."""
    if request.param == "uvicorn":
        with httpx.Client(base_url=request.getfixturevalue("url"), timeout=60) as http:
            yield http
        return
    with TestClient(create_app(settings(model_path), engine.model)) as http:
        yield http


def test_the_warm_up_runs_the_network_on_its_budget_and_completes_a_whole_frame(engine):
    """What the start-up warms: a frame of the largest accepted side whose crop is the whole
    frame (the full-resolution maps), and the network on a working grid at the model's budget
    (the first request's worst cases)."""
    shapes, focals = [], []

    class Recording:
        stride, info = engine.model.stride, engine.model.info

        def run(self, gray, sparse, focal_px):
            shapes.append(gray.shape)
            focals.append(float(focal_px.ravel()[0]))
            return engine.model.run(gray, sparse, focal_px)

    warm_up(Recording(), 2048)
    (_, _, _, width), (_, _, budget_height, budget_width) = shapes
    assert focals[0] == pytest.approx(1000.0 * width / 2048)  # the crop is the whole frame
    assert 0.8 * WORK_PIXELS <= budget_height * budget_width <= WORK_PIXELS


def test_the_warm_up_answers_its_frames_whole_with_the_services_cloud_size(engine, monkeypatch):
    """Both warm-up frames go through the whole answer (pipeline, cloud, normals), the cloud
    as large as the service's requests may make it (``--max-points``)."""
    answered = []

    def record(model_fn, gray, sparse, K, stride, work_pixels, frame_share=1.0, max_points=0):
        answered.append((gray.shape, work_pixels, max_points))

    monkeypatch.setattr(inference, "answer_in_process", record)
    warm_up(engine.model, 300, max_points=1234)
    own = engine.model.info.work_pixels
    side = math.isqrt(own)
    assert answered == [((300, 300), own, 1234), ((side, side), own, 1234)]


def test_the_warm_up_frame_asks_the_most_a_frame_of_its_side_can():
    """Every pixel lit (a 16-bit image) and a return on every one of them, at the depth of a
    plane: the frame whose answer writes every full-resolution map the pipeline has, so that
    the first real frames find that memory already written."""
    gray, sparse, K = warm_up_frame(300)
    assert gray.shape == sparse.shape == (300, 300)
    assert gray.dtype == np.uint16 and gray.min() > 0 and gray.max() > gray.min()
    assert sparse.dtype == np.float32 and np.all((sparse > 9) & (sparse < 11))
    assert (K.width, K.height, K.cx, K.cy) == (300, 300, 150.0, 150.0)


def frame():
    """The 256 x 256 test frame: a synthetic spacecraft at 100 m."""
    return synthetic_frame(256, seed=1)


def frame_files(gray=None, sparse=None) -> dict:
    """Multipart files of the 256 x 256 test frame, with either part replaced."""
    s = frame()
    return {
        "gray": ("gray.png", png_bytes(s.gray) if gray is None else gray),
        "sparse": ("sparse.npy", npy_bytes(s.sparse) if sparse is None else sparse),
    }


def post(client: httpx.Client, files: dict, data: dict | None = None, **params) -> httpx.Response:
    return client.post("/complete", files=files, data=data, params=params)


def decoded(array: dict) -> np.ndarray:
    return np.load(io.BytesIO(base64.b64decode(array["npy_base64"])), allow_pickle=False)


def metric(client: httpx.Client, name: str, **labels: str) -> float:
    """Value of one Prometheus sample (0 when absent), read once no request is pending: the
    counters of a request move after its answer is sent, so a client can read them before."""
    wanted = ",".join(f'{k}="{v}"' for k, v in labels.items())
    pattern = "^" + re.escape(name + (f"{{{wanted}}}" if wanted else "")) + r" (\S+)$"
    for _ in range(100):
        text = client.get("/metrics").text
        if re.search(r"^sdcnet_inference_pending_requests 0\.0$", text, re.MULTILINE):
            break
        time.sleep(0.01)
    found = re.search(pattern, text, re.MULTILINE)
    return float(found.group(1)) if found else 0.0


def test_probes_answer_under_short_and_kserve_names(client):
    for path in ("/health", "/v2/health/live"):
        response = client.get(path)
        assert response.status_code == 200 and response.json() == {"live": True}
        assert "server" not in response.headers  # uvicorn's "Server: uvicorn" is off
    for path in ("/ready", "/v2/health/ready", "/v2/models/sdcnet/ready"):
        response = client.get(path)
        assert response.status_code == 200 and response.json() == {"ready": True}
    assert client.get("/docs").status_code == 200
    assert "/complete" in client.get("/openapi.json").json()["paths"]


def test_model_metadata(client):
    meta = client.get("/model").json()
    assert meta == client.get("/v2/models/sdcnet").json()
    assert meta["name"] == "sdcnet" and meta["versions"] == [TINY_VERSION]
    assert meta["provider"] == "CPUExecutionProvider" and meta["threads"] == 1
    # the tensors of POST /v2/models/sdcnet/infer, not the ONNX graph's
    tensors = {t["name"]: (t["datatype"], t["shape"]) for t in meta["inputs"] + meta["outputs"]}
    assert tensors == {
        "gray": ("UINT8", [-1, -1]),
        "sparse": ("FP32", [-1, -1]),
        "returns": ("FP32", [-1, 3]),
        "depth": ("FP32", [-1, -1]),
        "mask": ("UINT8", [-1, -1]),
        "points": ("FP32", [-1, 3]),
        "normals": ("FP32", [-1, 3]),
        "sigma": ("FP32", [-1, -1]),
    }
    assert "metres" in meta["inputs"][1]["description"]
    assert meta["intrinsics"]["fx"] == pytest.approx(7939.2, abs=0.1)
    assert meta["default_intrinsics"]["fx"] == meta["intrinsics"]["fx"]  # no --camera
    assert meta["camera"] is None
    assert meta["limits"] == {
        "max_pixels": MAX_PIXELS,
        "max_returns": Settings.model_fields["max_returns"].default,
        "max_upload_bytes": MAX_UPLOAD_BYTES,
        "max_points": Settings.model_fields["max_points"].default,
        "max_in_flight": MAX_IN_FLIGHT,
        "max_requests": MAX_REQUESTS,
    }


def test_a_frame_round_trips_and_matches_onnxruntime(client, model_path):
    s = frame()
    response = post(client, frame_files())
    assert response.status_code == 200, response.text
    body = response.json()
    depth, mask, points, sigma = (decoded(body[k]) for k in ("depth", "mask", "points", "sigma"))

    direct_model = OnnxModel(model_path, provider="cpu", threads=1)
    K = direct_model.info.intrinsics.scaled(256, 256)  # the paper's camera at 256 px
    info = direct_model.info
    direct = complete(direct_model.run, s.gray, s.sparse, K.fx, info.stride, info.work_pixels)
    assert depth.dtype == np.float32 and mask.dtype == np.uint8 and points.dtype == np.float32
    np.testing.assert_array_equal(depth, direct.depth)
    np.testing.assert_array_equal(mask, direct.mask.astype(np.uint8))
    valid = direct.mask & (direct.depth > 0)
    np.testing.assert_array_equal(points, back_project(direct.depth, valid, K))
    # the tiny model's sigma is a tenth of the gray image (metres), 0 off the mask
    assert sigma.dtype == np.float32 and np.isfinite(sigma).all()
    np.testing.assert_array_equal(sigma, direct.sigma)
    assert not sigma[~direct.mask].any() and sigma[direct.mask].min() > 0
    assert body["uncertain_removed"] == 0
    # the tiny model calls bright pixels spacecraft: the drawn craft, not the dim stars (its
    # outline within resampling to the working grid and back)
    differ = mask.astype(bool) != (s.gray > 127)
    assert differ.sum() <= 0.01 * (s.gray > 127).sum()
    assert len(points) == body["point_count"] == np.count_nonzero(depth) > 3000
    assert np.abs(depth - s.depth)[depth > 0].max() < 0.5  # a fill of returns on a plane
    assert body["model_version"] == TINY_VERSION
    assert body["provider"] == "CPUExecutionProvider"
    assert body["intrinsics"] == pytest.approx({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy})
    assert body["returns"] == np.count_nonzero(s.sparse)
    assert body["mask_iou_estimate"] == direct.mask_iou_estimate  # the caveat decides on it
    assert 0.0 < direct.mask_iou_estimate < 1.0  # the tiny model's probability is the gray
    assert set(body["timings"]) == {"decode_ms", "queue_ms", "inference_ms", "encode_ms"}
    assert "inference;dur=" in response.headers["server-timing"]


def test_stray_returns_are_left_out_and_counted(client):
    s = frame()
    clean = post(client, frame_files()).json()
    noisy_sparse = s.sparse.copy()
    noisy_sparse[5, 250] = noisy_sparse[250, 5] = 100.0  # alone in the sky, far from the craft
    noisy = post(client, frame_files(sparse=npy_bytes(noisy_sparse))).json()
    assert clean["stray_returns"] == 0 and noisy["stray_returns"] == 2
    assert noisy["returns"] == clean["returns"] + 2
    for key in ("mask", "depth"):
        np.testing.assert_array_equal(decoded(noisy[key]), decoded(clean[key]))


def test_intrinsics_are_those_of_a_pinhole_of_the_frame_or_422(client):
    """Focal lengths from a 150 degree field of view (34.3 px across 256) to 1e9 px are
    served at the fixed cost of a frame; shorter ones, and a principal point far outside, get
    422 on every route (the Open Inference Protocol's: tests/test_wire.py)."""
    for fx in ("34.5", "1e9"):
        response = post(client, frame_files(), {"fx": fx}, format="npz")
        assert response.status_code == 200, response.text
    for fields in ({"fx": "1e-300"}, {"fx": "1"}, {"fy": "34"}, {"cx": "1e308"}, {"cy": "-129"}):
        error = assert_error_shape(post(client, frame_files(), fields), 422, "invalid_intrinsics")
        assert "px" in error["message"] or "principal point" in error["message"]


def test_a_focal_length_sent_alone_brings_the_other_at_the_default_cameras_aspect(client):
    """A careless client's "fx 1400" on its own: the answer's fy is 1400 (the model's camera
    has square pixels), not the default lens's, whose ratio would stretch the cloud."""
    for fields, fy in (({"fx": "1400"}, 1400.0), ({"fy": "900", "fx": "950"}, 900.0)):
        meta = post(client, frame_files(), fields).json()["intrinsics"]
        assert meta["fy"] == pytest.approx(fy) and meta["fx"] == float(fields["fx"])


def test_npz_and_ply_formats_with_given_intrinsics_and_outlier_removal(client):
    fields = {"fx": "2000", "fy": "2020", "cx": "100.5", "cy": "130", "outlier_removal": "true"}
    as_json = post(client, frame_files(), fields).json()
    npz = post(client, frame_files(), fields, format="npz")
    ply = post(client, frame_files(), fields, format="ply")
    assert npz.status_code == ply.status_code == 200
    assert 'filename="sdcnet.npz"' in npz.headers["content-disposition"]
    names = zipfile.ZipFile(io.BytesIO(npz.content)).namelist()  # any zip reader opens it
    assert names == [
        "depth.npy",
        "mask.npy",
        "points.npy",
        "normals.npy",
        "sigma.npy",
        "meta.json",
    ]

    with np.load(io.BytesIO(npz.content), allow_pickle=False) as archive:
        assert sorted(archive.files) == ["depth", "mask", "meta.json", "normals", "points", "sigma"]
        depth, mask, points = archive["depth"], archive["mask"], archive["points"]
        normals = archive["normals"]
        sigma, meta = archive["sigma"], json.loads(archive["meta.json"])
    np.testing.assert_array_equal(depth, decoded(as_json["depth"]))
    np.testing.assert_array_equal(points, decoded(as_json["points"]))
    np.testing.assert_array_equal(normals, decoded(as_json["normals"]))
    # one unit normal a point, facing the camera (towards -P)
    assert normals.shape == points.shape and normals.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-5)
    assert (np.sum(normals * points, axis=1) < 0).all()
    np.testing.assert_array_equal(sigma, decoded(as_json["sigma"]))
    assert sigma.dtype == np.float32 and np.isfinite(sigma).all() and sigma.max() > 0
    assert meta["intrinsics"] == {"fx": 2000.0, "fy": 2020.0, "cx": 100.5, "cy": 130.0}

    # the points are the kept pixels, back-projected with the intrinsics given
    K = Intrinsics(2000.0, 2020.0, 100.5, 130.0, 256, 256)
    valid = mask.astype(bool) & (depth > 0)
    kept = statistical_outliers(depth, valid, K)
    np.testing.assert_array_equal(points, back_project(depth, kept, K))
    assert meta["outliers_removed"] == valid.sum() - len(points)

    cloud = read_ply(ply.content)
    np.testing.assert_array_equal(cloud.points, points)
    np.testing.assert_array_equal(cloud.properties["sigma"], sigma[kept])  # each point's own
    assert list(cloud.properties) == ["nx", "ny", "nz", "sigma"]  # the names readers know
    ply_normals = np.stack([cloud.properties[k] for k in ("nx", "ny", "nz")], axis=1)
    np.testing.assert_array_equal(ply_normals, normals)
    assert f"model_version {TINY_VERSION}" in cloud.comments


def test_max_sigma_leaves_exactly_the_points_above_it_out_of_every_answer(client):
    """The points are those of the pixels whose sigma is at most max_sigma (then the outlier
    removal, on those); depth, mask and sigma stay whole; the summary counts the rest."""
    whole = post(client, frame_files()).json()
    depth, mask, sigma = (decoded(whole[k]) for k in ("depth", "mask", "sigma"))
    valid = mask.astype(bool) & (depth > 0)
    max_sigma = float(np.median(sigma[valid]))  # half the points above it
    trusted = valid & (sigma <= max_sigma)
    K = Intrinsics(**whole["intrinsics"], width=256, height=256)
    fields = {"max_sigma": repr(max_sigma)}
    as_json = post(client, frame_files(), fields).json()
    for name, array in (("depth", depth), ("mask", mask), ("sigma", sigma)):
        np.testing.assert_array_equal(decoded(as_json[name]), array, err_msg=name)
    np.testing.assert_array_equal(decoded(as_json["points"]), back_project(depth, trusted, K))
    assert as_json["uncertain_removed"] == np.count_nonzero(valid & (sigma > max_sigma)) > 100
    assert as_json["point_count"] == np.count_nonzero(trusted)

    npz = post(client, frame_files(), {**fields, "outlier_removal": "true"}, format="npz")
    with np.load(io.BytesIO(npz.content), allow_pickle=False) as archive:
        kept = statistical_outliers(depth, trusted, K)
        np.testing.assert_array_equal(archive["points"], back_project(depth, kept, K))
        np.testing.assert_array_equal(archive["sigma"], sigma)
        meta = json.loads(archive["meta.json"])
    assert meta["uncertain_removed"] == as_json["uncertain_removed"]
    assert meta["outliers_removed"] == np.count_nonzero(trusted) - np.count_nonzero(kept) > 0

    cloud = read_ply(post(client, frame_files(), fields, format="ply").content)
    np.testing.assert_array_equal(cloud.points, decoded(as_json["points"]))
    np.testing.assert_array_equal(cloud.properties["sigma"], sigma[trusted])
    assert cloud.properties["sigma"].max() <= max_sigma
    assert f"uncertain_removed {as_json['uncertain_removed']}" in cloud.comments


def test_a_cloud_holds_at_most_max_points_on_every_kth_pixel_and_says_so(url, model_path, tmp_path):
    """``sdc-serve --max-points``: a mask of more pixels gives the points of every k-th row
    and column, k the smallest that fits, in every format, each point with its own normal and
    sigma; depth, mask and sigma stay whole, and the answer says k."""
    with httpx.Client(base_url=url, timeout=60) as http:
        whole = post(http, frame_files()).json()
    depth, mask, sigma = (decoded(whole[k]) for k in ("depth", "mask", "sigma"))
    valid = mask.astype(bool) & (depth > 0)
    K = Intrinsics(**whole["intrinsics"], width=256, height=256)
    assert whole["cloud_stride"] == 1 and whole["point_count"] == np.count_nonzero(valid) > 3000
    max_points = 1000
    with (
        running_service(model_path, tmp_path / "serve.log", f"--max-points={max_points}") as url,
        httpx.Client(base_url=url, timeout=60) as http,
    ):
        assert http.get("/model").json()["limits"]["max_points"] == max_points
        thin = post(http, frame_files()).json()
        npz = post(http, frame_files(), format="npz")
        cloud = read_ply(post(http, frame_files(), format="ply").content)
    for name, array in (("depth", depth), ("mask", mask), ("sigma", sigma)):
        np.testing.assert_array_equal(decoded(thin[name]), array, err_msg=name)
    stride = thin["cloud_stride"]
    on_lattice = np.zeros_like(valid)
    on_lattice[::stride, ::stride] = valid[::stride, ::stride]
    assert stride == cloud_stride(valid, max_points) > 1
    assert np.count_nonzero(valid[:: stride - 1, :: stride - 1]) > max_points  # the smallest
    points = decoded(thin["points"])
    np.testing.assert_array_equal(points, back_project(depth, on_lattice, K))
    assert len(points) == thin["point_count"] <= max_points
    # each point keeps the normal and the sigma of its pixel in the whole cloud
    in_whole = on_lattice[valid]
    np.testing.assert_array_equal(decoded(thin["normals"]), decoded(whole["normals"])[in_whole])
    np.testing.assert_array_equal(cloud.properties["sigma"], sigma[on_lattice])
    np.testing.assert_array_equal(cloud.points, points)
    assert f"cloud_stride {stride}" in cloud.comments
    with np.load(io.BytesIO(npz.content), allow_pickle=False) as archive:
        np.testing.assert_array_equal(archive["points"], points)
        assert json.loads(archive["meta.json"])["cloud_stride"] == stride


def test_every_answer_says_when_its_mask_rests_on_few_returns_or_is_in_doubt(client):
    """The caveats (``sdcnet.caveats``) and the mask's estimated IOU in the JSON answer, the
    npz's meta.json and the PLY's header: ``few_returns`` when most of the test frame's
    returns are left out (the ten left lie along the craft's top, whose rest, in sight, runs
    past the crop around them: a second look beyond it answers it, and no ``crop_cut`` is
    left to say); ``mask_uncertain`` with the estimate
    below its floor (the tiny model's probability is the gray image: its outline is in doubt
    where the image is dim)."""
    whole = post(client, frame_files()).json()
    assert whole["caveats"] == uncertain(whole["mask_iou_estimate"])
    sparse = frame().sparse.copy()
    rows, cols = np.nonzero(sparse)
    sparse[rows[FEW_RETURNS // 2 :], cols[FEW_RETURNS // 2 :]] = 0
    few = post(client, frame_files(sparse=npy_bytes(sparse))).json()
    expected = ["few_returns", *uncertain(few["mask_iou_estimate"])]
    assert few["caveats"] == expected
    npz = post(client, frame_files(sparse=npy_bytes(sparse)), format="npz")
    with np.load(io.BytesIO(npz.content), allow_pickle=False) as archive:
        meta = json.loads(archive["meta.json"])
    assert meta["caveats"] == expected and meta["mask_iou_estimate"] == few["mask_iou_estimate"]
    cloud = read_ply(post(client, frame_files(sparse=npy_bytes(sparse)), format="ply").content)
    assert f"caveats {','.join(expected)}" in cloud.comments
    assert f"mask_iou_estimate {few['mask_iou_estimate']:.4f}" in cloud.comments

    assert whole["caveats"] == ["mask_uncertain"]  # gray 150-230: probability 0.59-0.90
    gray = frame().gray
    sure = np.where(gray >= 150, 255, gray).astype(np.uint8)  # the craft white: probability 1
    answer = post(client, frame_files(gray=png_bytes(sure))).json()
    assert answer["mask_iou_estimate"] > 0.9 and answer["caveats"] == []  # doubt: the outline


def uncertain(estimate: float) -> list[str]:
    """The ``mask_uncertain`` caveat an answer whose mask is estimated at ``estimate`` carries."""
    return ["mask_uncertain"] if estimate < UNCERTAIN_MASK_IOU else []


@pytest.mark.parametrize(
    "variant", ["gray16", "colour_jpeg", "colour_bmp", "tiff", "float64", "sparse_png16"]
)
def test_accepted_input_variants(client, variant):
    s = frame()
    gray16 = s.gray.astype(np.uint16) * 257
    colour = cv2.cvtColor(s.gray, cv2.COLOR_GRAY2BGR)
    millimetres = np.round(s.sparse * 1000).astype(np.uint16)
    gray, sparse, fields = {
        "gray16": (png_bytes(gray16), None, None),
        "colour_jpeg": (png_bytes(colour, ".jpg"), None, None),
        "colour_bmp": (png_bytes(colour, ".bmp"), None, None),
        "tiff": (png_bytes(s.gray, ".tiff"), None, None),
        "float64": (None, npy_bytes(s.sparse.astype(np.float64)), None),
        "sparse_png16": (None, png_bytes(millimetres), {"depth_scale": "0.001"}),
    }[variant]
    response = post(client, frame_files(gray, sparse), fields)
    assert response.status_code == 200, response.text
    assert response.json()["returns"] == np.count_nonzero(s.sparse)


def _huge_npy_header() -> bytes:
    """A .npy that declares 2048 x 2048 float32 and holds no data: refused from the header."""
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buffer, {"descr": "<f4", "fortran_order": False, "shape": (2048, 2048)}
    )
    return b"\x93NUMPY\x01\x00" + buffer.getvalue()[8:]


def bad_request(case: str) -> tuple[dict, dict | None, dict]:
    """(files, form fields, query) of one bad request of issue 5's list."""
    s = frame()
    good_png = png_bytes(s.gray)
    with_nan, with_inf, negative, far = (s.sparse.copy() for _ in range(4))
    with_nan[5, 5], with_inf[5, 5], negative[5, 5], far[5, 5] = np.nan, np.inf, -1.0, 1e30
    files = {
        "missing_gray": {"sparse": frame_files()["sparse"]},
        "missing_sparse": {"gray": frame_files()["gray"]},
        "not_an_image": frame_files(gray=b"hello, world"),
        "empty_image": frame_files(gray=b""),
        "truncated_png": frame_files(gray=good_png[: len(good_png) // 2]),
        "truncated_jpeg": frame_files(gray=png_bytes(s.gray, ".jpg")[:3000]),
        "broken_png_header": frame_files(gray=good_png[:8] + b"\x00" * 30),
        "float_tiff": frame_files(gray=png_bytes(s.gray.astype(np.float32), ".tiff")),
        "pickled_npy": frame_files(sparse=npy_bytes(np.array([{"a": 1}]), allow_pickle=True)),
        "truncated_npy": frame_files(sparse=npy_bytes(s.sparse)[:-100]),
        "int_npy": frame_files(sparse=npy_bytes(s.sparse.astype(np.int32))),
        "3d_npy": frame_files(sparse=npy_bytes(s.sparse[None])),
        "sparse_not_npy_or_png": frame_files(sparse=b"1,2,3\n"),
        "size_mismatch": frame_files(sparse=npy_bytes(np.pad(s.sparse, ((0, 8), (0, 0))))),
        "nan_depth": frame_files(sparse=npy_bytes(with_nan)),
        "inf_depth": frame_files(sparse=npy_bytes(with_inf)),
        "negative_depth": frame_files(sparse=npy_bytes(negative)),
        "far_depth": frame_files(sparse=npy_bytes(far)),
        "no_returns": frame_files(sparse=npy_bytes(np.zeros_like(s.sparse))),
        "too_many_pixels": frame_files(gray=png_bytes(np.zeros((1024, 1025), np.uint8))),
        "npy_too_many_pixels": frame_files(sparse=_huge_npy_header()),
        "too_many_bytes": frame_files(gray=b"\x89PNG" + bytes(MAX_UPLOAD_BYTES)),
        "png_sparse_without_scale": frame_files(sparse=png_bytes(s.sparse.astype(np.uint16))),
        "png8_sparse": frame_files(sparse=png_bytes(s.sparse.astype(np.uint8))),
    }.get(case, frame_files())
    fields = {
        "png8_sparse": {"depth_scale": "0.01"},
        "scale_with_npy": {"depth_scale": "0.01"},
        "negative_fx": {"fx": "-5"},
        "nan_cx": {"cx": "nan"},
        "zero_max_sigma": {"max_sigma": "0"},
        "negative_max_sigma": {"max_sigma": "-0.05"},
        "infinite_max_sigma": {"max_sigma": "inf"},
        "text_max_sigma": {"max_sigma": "5 cm"},
    }.get(case)
    query = {"unknown_format": {"format": "xml"}}.get(case, {})
    return files, fields, query


BAD_INPUTS = {
    "missing_gray": (422, "invalid_request"),
    "missing_sparse": (422, "invalid_request"),
    "not_an_image": (415, "unsupported_media_type"),
    "empty_image": (400, "unreadable_file"),
    "truncated_png": (400, "unreadable_file"),
    "truncated_jpeg": (400, "unreadable_file"),
    "broken_png_header": (400, "unreadable_file"),
    "float_tiff": (422, "wrong_dtype"),
    "pickled_npy": (400, "pickle_not_allowed"),
    "truncated_npy": (400, "unreadable_file"),
    "int_npy": (422, "wrong_dtype"),
    "3d_npy": (422, "wrong_shape"),
    "sparse_not_npy_or_png": (415, "unsupported_media_type"),
    "size_mismatch": (422, "wrong_shape"),
    "nan_depth": (422, "invalid_depth"),
    "inf_depth": (422, "invalid_depth"),
    "negative_depth": (422, "invalid_depth"),
    "far_depth": (422, "invalid_depth"),
    "no_returns": (422, "no_returns"),
    "too_many_pixels": (413, "too_large"),
    "npy_too_many_pixels": (413, "too_large"),
    "too_many_bytes": (413, "too_large"),
    "unknown_format": (422, "invalid_request"),
    "png_sparse_without_scale": (422, "invalid_request"),
    "png8_sparse": (422, "wrong_dtype"),
    "scale_with_npy": (422, "invalid_request"),
    "negative_fx": (422, "invalid_intrinsics"),
    "nan_cx": (422, "invalid_request"),
    "zero_max_sigma": (422, "invalid_max_sigma"),
    "negative_max_sigma": (422, "invalid_max_sigma"),
    "infinite_max_sigma": (422, "invalid_request"),
    "text_max_sigma": (422, "invalid_request"),
}


def assert_error_shape(response: httpx.Response, status: int, code: str) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert set(body) == {"error"}
    assert set(body["error"]) <= {"code", "message", "details"}
    assert body["error"]["code"] == code
    assert len(body["error"]["message"]) > 10
    return body["error"]


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_gets_a_4xx_json_error(client, case):
    files, fields, query = bad_request(case)
    status, code = BAD_INPUTS[case]
    assert_error_shape(post(client, files, fields, **query), status, code)


def test_a_streamed_body_past_the_byte_limit_gets_413(url):
    request = httpx.Request("POST", f"{url}/complete", files=frame_files())
    boundary = request.headers["content-type"].split("boundary=")[1]
    head = request.read()[: -(len(boundary) + 6)]  # drop the closing boundary

    def chunks():  # no Content-Length: the limit is enforced while the bytes stream in
        yield head
        for _ in range(MAX_UPLOAD_BYTES // 2**20 + 1):
            yield bytes(2**20)

    response = httpx.post(
        f"{url}/complete",
        content=chunks(),
        headers={"content-type": request.headers["content-type"]},
        timeout=60,
    )
    assert_error_shape(response, 413, "too_large")


def test_unknown_paths_and_methods_get_the_same_error_shape(client):
    assert_error_shape(client.get("/nowhere"), 404, "not_found")
    assert_error_shape(client.get("/complete"), 405, "method_not_allowed")
    error = assert_error_shape(
        post(client, {"gray": frame_files()["gray"]}), 422, "invalid_request"
    )
    assert "the form field sparse (dense map) or returns (list), not neither" in error["message"]
    error = assert_error_shape(
        post(client, {"sparse": frame_files()["sparse"]}), 422, "invalid_request"
    )
    assert error["details"] == [{"location": "form", "field": "gray", "message": "Field required"}]


def test_mangled_files_never_get_a_500(client):
    """Random bit flips, header damage and truncation in every accepted format: always 4xx
    (or 200 when the damage is harmless), never 500."""
    s = frame()
    originals = [png_bytes(s.gray, ext) for ext in (".png", ".tiff", ".jpg", ".bmp")]
    originals += [npy_bytes(s.sparse)]
    rng = np.random.default_rng(7)
    for i in range(60):
        data = bytearray(originals[i % len(originals)])
        where = rng.integers(0, min(len(data), 96) if i % 2 else len(data), size=8)
        data[where[0] :] = data[where[0] :] if i % 3 else b""  # every third one truncated
        for at in where[1:]:
            if at < len(data):
                data[at] = rng.integers(0, 256)
        files = frame_files(sparse=bytes(data)) if i % 5 == 4 else frame_files(gray=bytes(data))
        response = post(client, files)
        assert response.status_code < 500, (i, response.text)


def test_the_service_still_serves_after_bad_input_and_never_answered_500(client):
    failed = metric(client, "sdcnet_inference_request_failure_total", reason="invalid_depth")
    for case in ("nan_depth", "inf_depth", "negative_depth"):
        assert post(client, *bad_request(case)[:2]).status_code == 422
    assert post(client, frame_files()).status_code == 200
    assert metric(client, "sdcnet_inference_request_failure_total", reason="internal_error") == 0
    invalid = metric(client, "sdcnet_inference_request_failure_total", reason="invalid_depth")
    assert invalid == failed + 3


def test_concurrent_requests_get_200_or_503_with_retry_after(url):
    s = synthetic_frame(1024, seed=2)
    files = {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}
    http = httpx.Client(base_url=url, timeout=60)
    before = metric(http, "sdcnet_inference_request_success_total")
    start = threading.Barrier(13)
    responses: list[httpx.Response] = []
    probes: list[int] = []

    def send() -> None:
        start.wait()
        responses.append(httpx.post(f"{url}/complete", files=files, params={"format": "ply"}))

    def probe() -> None:  # probes are never limited, even with the service full
        start.wait()
        probes.extend(httpx.get(f"{url}{path}").status_code for path in ("/ready", "/metrics"))

    threads = [threading.Thread(target=send) for _ in range(12)]
    threads.append(threading.Thread(target=probe))
    for t in threads:
        t.start()
    for t in threads:
        t.join()

    statuses = sorted(r.status_code for r in responses)
    assert set(statuses) <= {200, 503} and len(statuses) == 12
    assert 200 in statuses and 503 in statuses, statuses
    for r in responses:
        if r.status_code == 503:
            assert_error_shape(r, 503, "overloaded")
            assert r.headers["retry-after"] == "2"
    assert metric(http, "sdcnet_inference_request_success_total") == before + statuses.count(200)
    assert metric(http, "sdcnet_inference_request_failure_total", reason="overloaded") >= 1
    assert metric(http, "sdcnet_inference_pending_requests") == 0
    assert probes == [200, 200]
    http.close()


def test_metrics_move_with_requests(client):
    ok = metric(client, "sdcnet_inference_request_success_total")
    failed = metric(client, "sdcnet_inference_request_failure_total", reason="no_returns")
    timed = metric(client, "sdcnet_inference_phase_duration_seconds_count", phase="inference")
    assert post(client, frame_files()).status_code == 200
    assert post(client, *bad_request("no_returns")[:2]).status_code == 422
    assert metric(client, "sdcnet_inference_request_success_total") == ok + 1
    after = metric(client, "sdcnet_inference_request_failure_total", reason="no_returns")
    assert after == failed + 1
    timed_after = metric(client, "sdcnet_inference_phase_duration_seconds_count", phase="inference")
    assert timed_after == timed + 1
    own = client.get("/model").json()["frame_budget"]["model_work_pixels"]
    info = {  # Prometheus orders the labels by name
        "provider": "CPUExecutionProvider",
        "threads": "1",
        "version": TINY_VERSION,
        "work_pixels": str(own),
    }
    assert metric(client, "sdcnet_model_info", **info) == 1
    assert metric(client, "sdcnet_frame_share") == 1.0, "the tests' --frame-ms 0: all of it"
    assert metric(client, "sdcnet_inference_request_duration_seconds_count") >= 1


# -- in process only: what dependency overrides reach --------------------------------------


def test_the_routes_that_run_the_model_and_only_they_take_an_inference_slot():
    """``Admission`` bounds the routes that declare ``TAKES_SLOT``; probes, metadata and
    metrics stay unbounded."""
    routes = slot_routes(ROUTERS)
    declared = sorted((method, route.path) for route in routes for method in route.methods)
    assert declared == [
        ("POST", "/complete"),
        ("POST", "/pose"),
        ("POST", "/v2/models/sdcnet/infer"),
    ]


def test_without_a_model_the_probes_and_requests_say_not_ready(model_path):
    """No lifespan has run (no ``with``): no model yet, as while starting or stopping."""
    http = TestClient(create_app(settings(model_path)))
    assert http.get("/health").json() == {"live": True}
    for response in (http.get("/ready"), post(http, frame_files())):
        assert_error_shape(response, 503, "not_ready")
        assert response.headers["retry-after"] == "2"


def test_the_lifespan_loads_the_model_and_drops_it_on_shutdown(model_path):
    app = create_app(settings(model_path))
    with TestClient(app) as http:
        assert http.get("/ready").status_code == 200
        assert app.state.engine.model.info.version == TINY_VERSION
    assert app.state.engine is None


class FailingModel:
    """A loaded model whose inference raises, as a bug in a graph or a runtime would."""

    def __init__(self, model: OnnxModel):
        self.info, self.provider, self.stride = model.info, model.provider, model.stride

    def run(self, gray: np.ndarray, sparse: np.ndarray):
        raise RuntimeError("the model broke")


def test_a_failing_model_is_a_500_of_the_error_shape_and_the_service_goes_on(model_path, engine):
    app = create_app(settings(model_path), engine.model)
    app.dependency_overrides[get_engine] = lambda: Engine(FailingModel(engine.model))
    with TestClient(app, raise_server_exceptions=False) as http:
        error = assert_error_shape(post(http, frame_files()), 500, "internal_error")
        assert "the model broke" not in error["message"]  # details stay in the server log
        assert metric(http, "sdcnet_inference_request_failure_total", reason="internal_error") == 1
        del app.dependency_overrides[get_engine]
        assert post(http, frame_files()).status_code == 200


def test_the_routes_take_their_limits_from_the_settings_dependency(model_path, engine):
    app = create_app(settings(model_path), engine.model)
    small = settings(model_path).model_copy(update={"max_pixels": 128 * 128})
    app.dependency_overrides[get_settings] = lambda: small
    with TestClient(app) as http:
        assert http.get("/model").json()["limits"]["max_pixels"] == 128 * 128
        assert_error_shape(post(http, frame_files()), 413, "too_large")


# -- the camera: sdc-serve --camera ---------------------------------------------------------

#: A 256 x 256 camera with a strong barrel lens, and its file as OpenCV's calibration writes it.
CAMERA = CameraCalibration(
    Intrinsics(600.0, 620.0, 130.0, 124.5, 256, 256), (-2.0, 0.0, 0.001, -0.002), "plumb_bob"
)
CAMERA_YAML = """%YAML:1.0
---
image_width: 256
image_height: 256
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 600., 0., 130., 0., 620., 124.5, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 4
   cols: 1
   dt: d
   data: [ -2., 0., 1.0000000000000000e-03, -2.0000000000000000e-03 ]
"""


@pytest.fixture(scope="module")
def camera_url(model_path, tmp_path_factory):
    """The service started with ``--camera``: CAMERA's file."""
    folder = tmp_path_factory.mktemp("camera")
    (folder / "camera.yaml").write_text(CAMERA_YAML)
    flags = [f"--max-pixels={MAX_PIXELS}", f"--camera={folder / 'camera.yaml'}"]
    with running_service(model_path, folder / "serve.log", *flags) as address:
        yield address


def test_a_frame_without_intrinsics_is_undistorted_into_the_camera_of_the_file(url, camera_url):
    """Served with --camera, a frame without intrinsics gets the very answer of the same frame
    undistorted (``sdcnet.calibration``) and sent with the camera's intrinsics to a service
    without: over both protocols."""
    s = frame()
    undistorter = Undistorter(CAMERA)
    rows, cols = np.nonzero(s.sparse)
    new_rows, new_cols, kept = undistorter.returns(rows, cols)
    sparse = scatter_nearest(new_rows, new_cols, s.sparse[rows, cols][kept], s.sparse.shape)
    gray = undistorter.image(s.gray)
    assert (new_cols != cols[kept]).any() and not np.array_equal(gray, s.gray)  # the lens's work
    K = CAMERA.intrinsics
    intrinsics = {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy}
    undistorted = frame_files(png_bytes(gray), npy_bytes(sparse))
    expected = httpx.post(f"{url}/complete", files=undistorted, data=intrinsics, timeout=60)

    answer = httpx.post(f"{camera_url}/complete", files=frame_files(), timeout=60).json()
    assert answer["intrinsics"] == expected.json()["intrinsics"] == pytest.approx(intrinsics)
    assert answer["returns"] == np.count_nonzero(sparse)
    for name in ("depth", "mask", "points"):
        np.testing.assert_array_equal(decoded(answer[name]), decoded(expected.json()[name]))
    with Client(camera_url) as client:  # the Open Inference Protocol
        over_v2 = client.complete(s.gray, returns=returns_from_dense(s.sparse))
    assert over_v2.meta["intrinsics"] == pytest.approx(intrinsics)
    np.testing.assert_array_equal(over_v2.depth, decoded(answer["depth"]))
    np.testing.assert_array_equal(over_v2.points, decoded(answer["points"]))


def test_the_camera_is_listed_and_fits_frames_of_its_aspect_ratio_only(camera_url):
    with httpx.Client(base_url=camera_url, timeout=60) as http:
        meta = http.get("/model").json()
        assert meta["camera"] == {
            "source": "camera.yaml (OpenCV YAML)",
            "model": "plumb_bob",
            "intrinsics": CAMERA.intrinsics.as_dict(),
            "distortion": [-2.0, 0.0, 0.001, -0.002],
            "frame": ANSWER_FRAME,
        }
        assert meta["default_intrinsics"] == CAMERA.intrinsics.as_dict()

        small = synthetic_frame(128, seed=1)  # the camera binned 2 x 2: its intrinsics scaled
        files = {
            "gray": ("g.png", png_bytes(small.gray)),
            "sparse": ("s.npy", npy_bytes(small.sparse)),
        }
        K = CAMERA.at_size(128, 128).intrinsics
        assert post(http, files).json()["intrinsics"] == pytest.approx(
            {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy}
        )
        s = frame()  # 256 x 128: another camera, which the request must describe
        wide = frame_files(png_bytes(s.gray[64:192]), npy_bytes(s.sparse[64:192]))
        error = assert_error_shape(post(http, wide), 422, "camera_mismatch")
        assert error["message"] == (
            "the frame is 256 x 128 pixels, not of the aspect ratio of the camera's 256 x 256 "
            "(camera.yaml (OpenCV YAML)): send fx, fy, cx and cy with this frame, or serve with "
            "its camera's file (sdc-serve --camera)"
        )
        given = {"fx": 900.0, "fy": 900.0, "cx": 127.5, "cy": 63.5}
        assert post(http, wide, given).json()["intrinsics"] == given


# -- the process --------------------------------------------------------------------------


def test_sdc_serve_refuses_a_missing_model_with_one_clear_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "sdcnet.service", "--model", str(tmp_path / "none.onnx")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"sdc-serve: model file not found: {tmp_path / 'none.onnx'}"


def test_sdc_serve_refuses_a_missing_camera_file_with_one_clear_line(model_path, tmp_path):
    """Loaded before the model: a camera file's problem (sdcnet.calibration's message) is
    the one line, as a model's is."""
    command = [sys.executable, "-m", "sdcnet.service", "--model", str(model_path)]
    camera = tmp_path / "none.yaml"
    result = subprocess.run(
        [*command, "--camera", str(camera)], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"sdc-serve: camera file not found: {camera}"


def test_the_service_imports_no_torch():
    """The Docker image has no torch: the service must not need it (trimesh it does need,
    for POST /pose's targets: it is in the serve extra)."""
    code = (
        "import sys, sdcnet.service.cli\n"
        "heavy = {'torch', 'onnx'} & {m.split('.')[0] for m in sys.modules}\n"
        "heavy |= {m for m in sys.modules if m.startswith(('sdcnet.training', 'sdcnet.export'))}\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
