"""The inference service over real HTTP: the real app under uvicorn in a subprocess, on a model
exported from the real architecture, fed generated frames."""

from __future__ import annotations

import base64
import io
import json
import re
import subprocess
import sys
import threading
import zipfile

import cv2
import httpx
import numpy as np
import pytest
from fixtures_runtime import MODEL_VERSION, npy_bytes, png_bytes, random_model, running_service
from fixtures_runtime import sample as generated

from sdcnet.camera import Intrinsics
from sdcnet.pipeline import complete
from sdcnet.pointcloud import back_project, read_ply, statistical_outliers
from sdcnet.runtime import OnnxModel

MAX_PIXELS = 1024 * 1024
MAX_UPLOAD_BYTES = 8 * 2**20
MAX_IN_FLIGHT = 2


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    return random_model(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="module")
def url(model_path, tmp_path_factory):
    log = tmp_path_factory.mktemp("service") / "serve.log"
    flags = [f"--max-in-flight={MAX_IN_FLIGHT}", f"--max-pixels={MAX_PIXELS}"]
    flags += [f"--max-upload-bytes={MAX_UPLOAD_BYTES}", "--retry-after=2"]
    with running_service(model_path, log, *flags) as address:
        yield address


def frame_files(gray=None, sparse=None) -> dict:
    """Multipart files of the 256 x 256 test frame, with either part replaced."""
    s = generated(256)
    return {
        "gray": ("gray.png", png_bytes(s.gray) if gray is None else gray),
        "sparse": ("sparse.npy", npy_bytes(s.sparse) if sparse is None else sparse),
    }


def post(url: str, files: dict, data: dict | None = None, **params) -> httpx.Response:
    return httpx.post(f"{url}/complete", files=files, data=data, params=params, timeout=60)


def decoded(array: dict) -> np.ndarray:
    return np.load(io.BytesIO(base64.b64decode(array["npy_base64"])), allow_pickle=False)


def metric(url: str, name: str, **labels: str) -> float:
    """Value of one Prometheus sample (0 when absent)."""
    text = httpx.get(f"{url}/metrics").text
    wanted = ",".join(f'{k}="{v}"' for k, v in labels.items())
    pattern = "^" + re.escape(name + (f"{{{wanted}}}" if wanted else "")) + r" (\S+)$"
    found = re.search(pattern, text, re.MULTILINE)
    return float(found.group(1)) if found else 0.0


def test_probes_answer_under_short_and_kserve_names(url):
    for path in ("/health", "/v2/health/live"):
        response = httpx.get(url + path)
        assert response.status_code == 200 and response.json() == {"live": True}
    for path in ("/ready", "/v2/health/ready", "/v2/models/sdcnet/ready"):
        response = httpx.get(url + path)
        assert response.status_code == 200 and response.json() == {"ready": True}
    assert httpx.get(f"{url}/docs").status_code == 200
    assert "/complete" in httpx.get(f"{url}/openapi.json").json()["paths"]


def test_model_metadata(url):
    meta = httpx.get(f"{url}/model").json()
    assert meta == httpx.get(f"{url}/v2/models/sdcnet").json()
    assert meta["name"] == "sdcnet" and meta["versions"] == [MODEL_VERSION]
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
    }
    assert meta["intrinsics"]["fx"] == pytest.approx(7939.2, abs=0.1)
    assert meta["limits"] == {
        "max_pixels": MAX_PIXELS,
        "max_upload_bytes": MAX_UPLOAD_BYTES,
        "max_in_flight": MAX_IN_FLIGHT,
    }


def test_a_generated_frame_round_trips_and_matches_onnxruntime(url, model_path):
    s = generated(256)
    response = post(url, frame_files())
    assert response.status_code == 200, response.text
    body = response.json()
    depth, mask, points = (decoded(body[k]) for k in ("depth", "mask", "points"))

    direct_model = OnnxModel(model_path, provider="cpu", threads=1)
    # a 256 px frame of the paper's camera: the service resamples it x4 to the model's scale
    direct = complete(direct_model.run, s.gray, s.sparse, direct_model.stride, zoom=4.0)
    K = direct_model.info.intrinsics.scaled(256, 256)
    assert depth.dtype == np.float32 and mask.dtype == np.uint8 and points.dtype == np.float32
    np.testing.assert_array_equal(depth, direct.depth)
    np.testing.assert_array_equal(mask, direct.mask.astype(np.uint8))
    np.testing.assert_array_equal(points, back_project(direct.depth, direct.mask, K))
    assert mask.sum() > 0 and len(points) == body["point_count"] == mask.sum()
    assert body["model_version"] == MODEL_VERSION
    assert body["provider"] == "CPUExecutionProvider"
    assert body["intrinsics"] == pytest.approx({"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy})
    assert body["returns"] == np.count_nonzero(s.sparse)
    assert set(body["timings"]) == {"decode_ms", "queue_ms", "inference_ms", "encode_ms"}
    assert "inference;dur=" in response.headers["server-timing"]


def test_odd_focal_lengths_are_served_at_the_nearest_supported_scale(url):
    for fx in ("1e-9", "1.0", "1e9"):
        response = post(url, frame_files(), {"fx": fx}, format="npz")
        assert response.status_code == 200, response.text


def test_npz_and_ply_formats_with_given_intrinsics_and_outlier_removal(url):
    fields = {"fx": "2000", "fy": "2020", "cx": "100.5", "cy": "130", "outlier_removal": "true"}
    as_json = post(url, frame_files(), fields).json()
    npz = post(url, frame_files(), fields, format="npz")
    ply = post(url, frame_files(), fields, format="ply")
    assert npz.status_code == ply.status_code == 200
    assert 'filename="sdcnet.npz"' in npz.headers["content-disposition"]
    names = zipfile.ZipFile(io.BytesIO(npz.content)).namelist()  # any zip reader opens it
    assert names == ["depth.npy", "mask.npy", "points.npy", "meta.json"]

    with np.load(io.BytesIO(npz.content), allow_pickle=False) as archive:
        assert sorted(archive.files) == ["depth", "mask", "meta.json", "points"]
        depth, mask, points = archive["depth"], archive["mask"], archive["points"]
        meta = json.loads(archive["meta.json"])
    np.testing.assert_array_equal(depth, decoded(as_json["depth"]))
    np.testing.assert_array_equal(points, decoded(as_json["points"]))
    assert meta["intrinsics"] == {"fx": 2000.0, "fy": 2020.0, "cx": 100.5, "cy": 130.0}

    # the points are the kept pixels, back-projected with the intrinsics given
    K = Intrinsics(2000.0, 2020.0, 100.5, 130.0, 256, 256)
    kept = statistical_outliers(depth, mask.astype(bool), K)
    np.testing.assert_array_equal(points, back_project(depth, kept, K))
    assert meta["outliers_removed"] == mask.sum() - len(points)

    cloud, comments = read_ply(ply.content)
    np.testing.assert_array_equal(cloud, points)
    assert f"model_version {MODEL_VERSION}" in comments


@pytest.mark.parametrize(
    "variant", ["gray16", "colour_jpeg", "colour_bmp", "tiff", "float64", "sparse_png16"]
)
def test_accepted_input_variants(url, variant):
    s = generated(256)
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
    response = post(url, frame_files(gray, sparse), fields)
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
    s = generated(256)
    good_png = png_bytes(s.gray)
    with_nan, with_inf, negative = s.sparse.copy(), s.sparse.copy(), s.sparse.copy()
    with_nan[5, 5], with_inf[5, 5], negative[5, 5] = np.nan, np.inf, -1.0
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
    "no_returns": (422, "no_returns"),
    "too_many_pixels": (413, "too_large"),
    "npy_too_many_pixels": (413, "too_large"),
    "too_many_bytes": (413, "too_large"),
    "unknown_format": (422, "invalid_request"),
    "png_sparse_without_scale": (422, "invalid_request"),
    "png8_sparse": (422, "wrong_dtype"),
    "scale_with_npy": (422, "invalid_request"),
    "negative_fx": (422, "invalid_request"),
    "nan_cx": (422, "invalid_request"),
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
def test_bad_input_gets_a_4xx_json_error(url, case):
    files, fields, query = bad_request(case)
    status, code = BAD_INPUTS[case]
    assert_error_shape(post(url, files, fields, **query), status, code)


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


def test_unknown_paths_and_methods_get_the_same_error_shape(url):
    assert_error_shape(httpx.get(f"{url}/nowhere"), 404, "not_found")
    assert_error_shape(httpx.get(f"{url}/complete"), 405, "method_not_allowed")
    error = assert_error_shape(post(url, {"gray": frame_files()["gray"]}), 422, "invalid_request")
    assert "the form field sparse (dense map) or returns (list), not neither" in error["message"]
    error = assert_error_shape(
        post(url, {"sparse": frame_files()["sparse"]}), 422, "invalid_request"
    )
    assert error["details"] == [{"location": "form", "field": "gray", "message": "Field required"}]


def test_mangled_files_never_get_a_500(url):
    """Random bit flips, header damage and truncation in every accepted format: always 4xx
    (or 200 when the damage is harmless), never 500."""
    s = generated(256)
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
        response = post(url, files)
        assert response.status_code < 500, (i, response.text)


def test_the_service_still_serves_after_bad_input_and_never_answered_500(url):
    assert post(url, frame_files()).status_code == 200
    assert metric(url, "sdcnet_inference_request_failure_total", reason="internal_error") == 0
    assert metric(url, "sdcnet_inference_request_failure_total", reason="invalid_depth") >= 3


def test_concurrent_requests_get_200_or_503_with_retry_after(url):
    s = generated(1024)
    files = {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}
    before = metric(url, "sdcnet_inference_request_success_total")
    start = threading.Barrier(13)
    responses: list[httpx.Response] = []
    probes: list[int] = []

    def send() -> None:
        start.wait()
        responses.append(post(url, files, format="ply"))

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
    assert metric(url, "sdcnet_inference_request_success_total") == before + statuses.count(200)
    assert metric(url, "sdcnet_inference_request_failure_total", reason="overloaded") >= 1
    assert metric(url, "sdcnet_inference_pending_requests") == 0
    assert probes == [200, 200]


def test_metrics_move_with_requests(url):
    ok = metric(url, "sdcnet_inference_request_success_total")
    failed = metric(url, "sdcnet_inference_request_failure_total", reason="no_returns")
    timed = metric(url, "sdcnet_inference_phase_duration_seconds_count", phase="inference")
    assert post(url, frame_files()).status_code == 200
    assert post(url, *bad_request("no_returns")[:2]).status_code == 422
    assert metric(url, "sdcnet_inference_request_success_total") == ok + 1
    assert metric(url, "sdcnet_inference_request_failure_total", reason="no_returns") == failed + 1
    assert (
        metric(url, "sdcnet_inference_phase_duration_seconds_count", phase="inference") == timed + 1
    )
    info = {"provider": "CPUExecutionProvider", "threads": "1", "version": MODEL_VERSION}
    assert metric(url, "sdcnet_model_info", **info) == 1
    assert metric(url, "sdcnet_inference_request_duration_seconds_count") >= 1


def test_sdc_serve_refuses_a_missing_model_with_one_clear_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "sdcnet.service", "--model", str(tmp_path / "none.onnx")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == f"sdc-serve: model file not found: {tmp_path / 'none.onnx'}"


def test_the_service_imports_no_torch():
    """The Docker image has no torch: the service must not need it."""
    code = (
        "import sys, sdcnet.service.cli\n"
        "heavy = {'torch', 'onnx', 'trimesh'} & {m.split('.')[0] for m in sys.modules}\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
