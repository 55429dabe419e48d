"""The wire: the Open Inference Protocol route (tritonclient.http against the real service),
LIDAR returns as a list on both protocols, the compact answer layouts the Python client asks
for, and a 4xx in the protocol's shape for every malformed v2 request."""

from __future__ import annotations

import base64
import gzip
import io
import json

import httpx
import numpy as np
import pytest
import tritonclient.http as triton
from tritonclient.utils import InferenceServerException

from sdcnet.camera import Intrinsics
from sdcnet.caveats import UNCERTAIN_MASK_IOU
from sdcnet.client.api import Client
from sdcnet.client.protocol import summary
from sdcnet.compact import depth_from_fp16, paste, unpack_mask
from sdcnet.formats.v2 import HEADER_LENGTH
from sdcnet.normals import normals_at
from sdcnet.npyio import npy_bytes
from sdcnet.pipeline import complete
from sdcnet.pointcloud import back_project, mask_pixels
from sdcnet.returns import returns_from_dense, write_returns_csv
from sdcnet.runtime.onnx import SPIN_WAIT, OnnxModel
from sdcnet.service.app import load_model
from sdcnet.service.settings import Settings
from tests.support.frames import png_bytes, synthetic_frame
from tests.support.fuzzing import fuzz_inputs
from tests.support.serving import running_service

MAX_PIXELS = 1024 * 1024
MAX_UPLOAD_BYTES = 4 * 2**20
INFER = "/v2/models/sdcnet/infer"


@pytest.fixture(scope="module")
def model_path(tiny_model_path):
    return tiny_model_path


def generated(size: int):
    """The test frame: a synthetic spacecraft at 100 m."""
    return synthetic_frame(size, seed=1)


@pytest.fixture(scope="module")
def url(model_path, tmp_path_factory):
    log = tmp_path_factory.mktemp("wire") / "serve.log"
    flags = [f"--max-pixels={MAX_PIXELS}", f"--max-upload-bytes={MAX_UPLOAD_BYTES}"]
    with running_service(model_path, log, *flags) as address:
        yield address


@pytest.fixture(scope="module")
def expected(model_path) -> dict[str, np.ndarray]:
    """The 256 x 256 test frame completed in process, as the service must answer it: the
    pipeline on onnxruntime (same model, same single thread), the paper's camera scaled."""
    s = generated(256)
    model = OnnxModel(model_path, provider="cpu", threads=1)
    K = model.info.intrinsics.scaled(256, 256)
    info = model.info
    result = complete(model.run, s.gray, s.sparse, K.fx, info.stride, info.work_pixels)
    points = back_project(result.depth, result.mask, K)
    normals = normals_at(result, *mask_pixels(result.mask), K)
    assert result.mask.any() and np.isfinite(result.sigma).all() and result.sigma.any()
    mask = result.mask.astype(np.uint8)
    return {
        "depth": result.depth,
        "mask": mask,
        "points": points,
        "normals": normals,
        "sigma": result.sigma,
    }


PROTOCOL_OUTPUT_NAMES = ("depth", "mask", "points", "normals", "sigma")


def triton_infer(url: str, inputs: dict[str, np.ndarray], binary: bool, **parameters):
    """``tritonclient.http``, unmodified, on the service: every output, binary or JSON."""
    datatypes = {np.dtype(np.uint8): "UINT8", np.dtype(np.float32): "FP32"}
    client = triton.InferenceServerClient(url.removeprefix("http://"))
    try:
        tensors = []
        for name, array in inputs.items():
            tensor = triton.InferInput(name, list(array.shape), datatypes[array.dtype])
            tensor.set_data_from_numpy(array, binary_data=binary)
            tensors.append(tensor)
        outputs = [
            triton.InferRequestedOutput(name, binary_data=binary) for name in PROTOCOL_OUTPUT_NAMES
        ]
        result = client.infer("sdcnet", tensors, outputs=outputs, parameters=parameters or None)
        return {name: result.as_numpy(name) for name in PROTOCOL_OUTPUT_NAMES}, result
    finally:
        client.close()


def assert_same(answer: dict[str, np.ndarray], expected: dict[str, np.ndarray]) -> None:
    for name in answer:
        assert answer[name].dtype == expected[name].dtype, name
        np.testing.assert_array_equal(answer[name], expected[name], err_msg=name)


# -- tritonclient and the in-process pipeline ------------------------------------------


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "json"])
@pytest.mark.parametrize("lidar", ["returns", "sparse"])
def test_tritonclient_gets_the_in_process_answer_bit_for_bit(url, expected, binary, lidar):
    s = generated(256)
    lidar_tensor = returns_from_dense(s.sparse) if lidar == "returns" else s.sparse
    answer, result = triton_infer(url, {"gray": s.gray, lidar: lidar_tensor}, binary)
    assert_same(answer, expected)
    document = result.get_response()
    assert document["model_name"] == "sdcnet"
    assert document["parameters"]["returns"] == np.count_nonzero(s.sparse)
    assert document["parameters"]["point_count"] == len(expected["points"])


def test_tritonclient_reads_the_metadata_and_probes(url):
    client = triton.InferenceServerClient(url.removeprefix("http://"))
    try:
        assert client.is_server_live() and client.is_server_ready()
        assert client.is_model_ready("sdcnet")
        assert "binary_tensor_data" in client.get_server_metadata()["extensions"]
        metadata = client.get_model_metadata("sdcnet")
        assert {t["name"] for t in metadata["inputs"]} == {"gray", "sparse", "returns"}
        assert [t["name"] for t in metadata["outputs"]] == list(PROTOCOL_OUTPUT_NAMES)
    finally:
        client.close()


def test_request_parameters_reach_the_pipeline(url):
    s = generated(256)
    inputs = {"gray": s.gray, "returns": returns_from_dense(s.sparse)}
    plain, _ = triton_infer(url, inputs, True)
    given, result = triton_infer(
        url, inputs, True, fx=2000.0, fy=2020.0, cx=100.5, cy=130.0, outlier_removal=True
    )
    parameters = result.get_response()["parameters"]
    assert (parameters["fx"], parameters["fy"], parameters["cx"]) == (2000.0, 2020.0, 100.5)
    valid = np.count_nonzero(given["mask"].astype(bool) & (given["depth"] > 0))
    assert parameters["outliers_removed"] == valid - len(given["points"]) > 0
    assert not np.array_equal(given["points"][:10], plain["points"][:10])


def test_max_sigma_as_a_request_parameter_leaves_exactly_the_uncertain_points_out(url):
    s = generated(256)
    inputs = {"gray": s.gray, "returns": returns_from_dense(s.sparse)}
    whole, _ = triton_infer(url, inputs, True)
    on_mask = whole["sigma"][whole["mask"].astype(bool) & (whole["depth"] > 0)]
    max_sigma = float(np.median(on_mask))  # metres: about half the points above it
    answer, result = triton_infer(url, inputs, True, max_sigma=max_sigma)
    parameters = result.get_response()["parameters"]
    depth, sigma = answer["depth"], answer["sigma"]
    valid = answer["mask"].astype(bool) & (depth > 0)
    K = Intrinsics(*(parameters[k] for k in ("fx", "fy", "cx", "cy")), 256, 256)
    trusted = valid & (sigma <= max_sigma)
    np.testing.assert_array_equal(answer["points"], back_project(depth, trusted, K))
    assert parameters["uncertain_removed"] == np.count_nonzero(valid & (sigma > max_sigma)) > 100
    assert np.count_nonzero(trusted) > 100


def test_the_caveats_travel_as_one_parameter_and_come_back_as_a_list(url):
    """The Open Inference Protocol's parameters are scalars: the codes joined by commas,
    which the client's summary splits back into ``POST /complete``'s list."""
    s = generated(256)
    returns = returns_from_dense(s.sparse)
    _, result = triton_infer(url, {"gray": s.gray, "returns": returns}, True)
    parameters = result.get_response()["parameters"]
    assert parameters["caveats"] == "mask_uncertain"  # the tiny model: probability = gray
    assert parameters["mask_iou_estimate"] < UNCERTAIN_MASK_IOU
    sure = np.where(s.gray >= 150, 255, s.gray).astype(np.uint8)  # probability 1 on the craft
    _, result = triton_infer(url, {"gray": sure, "returns": returns}, True)
    assert result.get_response()["parameters"]["caveats"] == ""
    # five returns along the craft's top (the rest of it, past the crop around them, is
    # answered by a second look)
    _, result = triton_infer(url, {"gray": sure, "returns": returns[:5]}, True)
    document = result.get_response()
    assert document["parameters"]["caveats"] == "few_returns"
    assert summary(document)["caveats"] == ["few_returns"]
    _, result = triton_infer(url, {"gray": s.gray, "returns": returns[:5]}, True)
    document = result.get_response()
    assert document["parameters"]["caveats"] == "few_returns,mask_uncertain"
    assert summary(document)["caveats"] == ["few_returns", "mask_uncertain"]


def test_the_service_lets_idle_onnxruntime_threads_sleep(model_path):
    """Spinning threads took the CPUs the request's own work needed (benchmarks/wire)."""
    settings = Settings(model_path=model_path, threads=1)
    assert settings.spin_wait is False
    options = load_model(settings).session.get_session_options()
    assert options.get_session_config_entry(SPIN_WAIT) == "0"
    spinning = load_model(Settings(model_path=model_path, threads=1, spin_wait=True))
    assert spinning.session.get_session_options().get_session_config_entry(SPIN_WAIT) == "1"


# -- compact inputs and answers ----------------------------------------------------------


def test_returns_and_the_dense_map_give_identical_answers_on_complete(url, expected, tmp_path):
    s = generated(256)
    returns = returns_from_dense(s.sparse)
    write_returns_csv(tmp_path / "r.csv", returns)
    gray = ("gray.png", png_bytes(s.gray))
    forms = {
        "sparse .npy": {"gray": gray, "sparse": ("s.npy", npy_bytes(s.sparse))},
        "returns .npy": {"gray": gray, "returns": ("r.npy", npy_bytes(returns))},
        "returns .csv": {"gray": gray, "returns": ("r.csv", (tmp_path / "r.csv").read_bytes())},
        "returns float64": {"gray": gray, "returns": ("r.npy", npy_bytes(returns.astype(float)))},
    }
    for name, files in forms.items():
        response = httpx.post(f"{url}/complete", files=files, timeout=60)
        assert response.status_code == 200, (name, response.text)
        body = response.json()
        arrays = {
            k: np.load(io.BytesIO(base64.b64decode(body[k]["npy_base64"])), allow_pickle=False)
            for k in PROTOCOL_OUTPUT_NAMES
        }
        assert_same(arrays, expected)
        assert body["returns"] == len(returns)


def test_the_python_client_rebuilds_the_compact_answer_exactly(url, expected, tmp_path):
    s = generated(256)
    write_returns_csv(tmp_path / "returns.csv", returns_from_dense(s.sparse))
    with Client(url) as client:
        results = [
            client.complete(s.gray, s.sparse),  # a dense map, sent as a list
            client.complete(s.gray, returns=returns_from_dense(s.sparse)),
            client.complete(png_bytes(s.gray), tmp_path / "returns.csv"),
        ]
        half = client.complete(s.gray, s.sparse, float16_depth=True)
    for result in [*results, half]:
        assert_same({"points": result.points, "sigma": result.sigma}, expected)
    for result in results:
        mask = result.mask.astype(np.uint8)
        assert_same({"depth": result.depth, "mask": mask}, expected)
        assert result.mask.dtype == bool and result.points.flags.writeable
        assert result.meta["returns"] == np.count_nonzero(s.sparse)
        assert set(result.timings_ms) == {"decode_ms", "queue_ms", "inference_ms", "encode_ms"}
        assert set(result.meta["intrinsics"]) == {"fx", "fy", "cx", "cy"}
    np.testing.assert_array_equal(half.depth == 0, expected["depth"] == 0)
    assert np.abs(half.depth - expected["depth"]).max() <= 0.008  # a spacecraft < 32 m deep


REGION = ("region_y0", "region_x0", "region_height", "region_width")


def test_compact_layouts_are_what_they_say(url, expected):
    """Region, bits and fp16 asked for by hand: the answer's parameters are enough to rebuild
    the full frames (the client's own code is not used here); sigma's window is the depth's."""
    s = generated(256)
    returns = returns_from_dense(s.sparse)
    inputs = [
        {"name": "gray", "datatype": "UINT8", "shape": [256, 256]},
        {"name": "returns", "datatype": "FP32", "shape": list(returns.shape)},
    ]
    for entry, array in zip(inputs, (s.gray, returns), strict=True):
        entry["parameters"] = {"binary_data_size": array.nbytes}
    header = {
        "inputs": inputs,
        "outputs": [
            {"name": "mask", "parameters": {"binary_data": True, "region": True, "bits": True}},
            {"name": "depth", "parameters": {"binary_data": True, "region": True, "fp16": True}},
            {"name": "sigma", "parameters": {"binary_data": True, "region": True}},
        ],
    }
    response = post_v2(url, header, s.gray.tobytes() + returns.tobytes())
    assert response.status_code == 200, response.text
    length = int(response.headers[HEADER_LENGTH])
    document = json.loads(response.content[:length])
    mask_out, depth_out, sigma_out = document["outputs"]
    p = mask_out["parameters"]
    assert mask_out["datatype"] == "UINT8" and depth_out["datatype"] == "FP16"
    window = (p["region_height"], p["region_width"])
    assert p["binary_data_size"] == -(-window[0] * window[1] // 8) == mask_out["shape"][0]
    data = response.content[length:]
    bits = np.frombuffer(data[: p["binary_data_size"]], np.uint8)
    mask = paste(unpack_mask(bits, window), p["region_y0"], p["region_x0"], (256, 256))
    np.testing.assert_array_equal(mask, expected["mask"].astype(bool))
    q = depth_out["parameters"]
    assert depth_out["shape"] == list(window) and q["region_y0"] == p["region_y0"]
    at = p["binary_data_size"] + q["binary_data_size"]
    residuals = np.frombuffer(data[p["binary_data_size"] : at], "<f2").reshape(window)
    depth = paste(
        depth_from_fp16(residuals, q["depth_offset"]), q["region_y0"], q["region_x0"], (256, 256)
    )
    np.testing.assert_array_equal(depth == 0, expected["depth"] == 0)
    assert np.abs(depth - expected["depth"]).max() <= 0.008
    r = sigma_out["parameters"]
    assert sigma_out["datatype"] == "FP32" and sigma_out["shape"] == list(window)
    assert [r[k] for k in REGION] == [q[k] for k in REGION]  # the depth's window
    sigma = np.frombuffer(data[at:], "<f4").reshape(window)
    assert len(data[at:]) == r["binary_data_size"] == sigma.nbytes
    sigma = paste(sigma, r["region_y0"], r["region_x0"], (256, 256))
    np.testing.assert_array_equal(sigma, expected["sigma"])
    assert len(response.content) < 256 * 256 * 6  # less than the full frame in FP16 and FP32


# -- malformed v2 requests ----------------------------------------------------------------


def post_v2(
    url: str, header: dict | bytes, binary: bytes = b"", headers: dict | None = None
) -> httpx.Response:
    encoded = header if isinstance(header, bytes) else json.dumps(header).encode()
    sent = {HEADER_LENGTH: str(len(encoded))} if binary else {}
    return httpx.post(
        f"{url}{INFER}", content=encoded + binary, headers={**sent, **(headers or {})}, timeout=60
    )


def good_request() -> tuple[dict, bytes]:
    """A valid binary request on a 64 x 64 frame: gray UINT8 and returns FP32."""
    inputs, binary = fuzz_inputs(binary=True)
    return {"inputs": inputs}, binary


def with_input(header: dict, target: str, **changes) -> dict:
    """``header`` with the input named ``target`` changed."""
    inputs = [dict(i, **changes) if i["name"] == target else i for i in header["inputs"]]
    return {**header, "inputs": inputs}


def malformed(case: str) -> tuple[dict | bytes, bytes, dict]:
    """(JSON header or raw bytes, binary data, extra HTTP headers) of one malformed request."""
    header, binary = good_request()
    gray_size, returns_size = (i["parameters"]["binary_data_size"] for i in header["inputs"])
    returns_json = fuzz_inputs(binary=False)[0][1]
    nan_returns = np.array([[1, 1, np.nan]], np.float32)
    return {
        "gray_fp32": (with_input(header, "gray", datatype="FP32"), binary, {}),
        "returns_fp64": (with_input(header, "returns", datatype="FP64"), binary, {}),
        "gray_3d": (with_input(header, "gray", shape=[1, 64, 64]), binary, {}),
        "returns_n_by_2": (
            with_input(header, "returns", shape=[returns_size // 8, 2]),
            binary,
            {},
        ),
        "sparse_other_size": (
            {
                "inputs": [
                    header["inputs"][0],
                    {
                        "name": "sparse",
                        "datatype": "FP32",
                        "shape": [64, 32],
                        "parameters": {"binary_data_size": 64 * 32 * 4},
                    },
                ]
            },
            binary[:gray_size] + bytes(64 * 32 * 4),
            {},
        ),
        "missing_gray": ({"inputs": header["inputs"][1:]}, binary[gray_size:], {}),
        "missing_returns": ({"inputs": header["inputs"][:1]}, binary[:gray_size], {}),
        "sparse_and_returns": (
            {
                "inputs": [
                    *header["inputs"],
                    {"name": "sparse", "datatype": "FP32", "shape": [64, 64], "data": [0.0] * 4096},
                ]
            },
            binary,
            {},
        ),
        "unknown_input": (with_input(header, "returns", name="lidar"), binary, {}),
        "input_twice": (
            {"inputs": [header["inputs"][0], *header["inputs"]]},
            binary[:gray_size] + binary,
            {},
        ),
        "binary_size_wrong": (
            with_input(header, "gray", parameters={"binary_data_size": gray_size - 1}),
            binary,
            {},
        ),
        "binary_short": (header, binary[:-12], {}),
        "binary_trailing": (header, binary + b"\x00" * 8, {}),
        "header_length_not_a_number": (header, binary, {HEADER_LENGTH: "twelve"}),
        "header_length_zero": (header, binary, {HEADER_LENGTH: "0"}),
        "header_length_past_the_body": (header, binary, {HEADER_LENGTH: str(10**7)}),
        "header_length_too_short": (header, binary, {HEADER_LENGTH: "10"}),
        "not_json": (b"{'inputs': nope", binary, {}),
        "json_not_an_object": (b"[1, 2, 3]", b"", {}),
        "empty_body": (b"", b"", {}),
        "unknown_parameter": ({**header, "parameters": {"fx": 100.0, "zoom": 2}}, binary, {}),
        "string_parameter": ({**header, "parameters": {"fx": "100"}}, binary, {}),
        "negative_fx": ({**header, "parameters": {"fx": -1.0}}, binary, {}),
        "zero_max_sigma": ({**header, "parameters": {"max_sigma": 0.0}}, binary, {}),
        "nan_max_sigma": ({**header, "parameters": {"max_sigma": float("nan")}}, binary, {}),
        "string_max_sigma": ({**header, "parameters": {"max_sigma": "0.1"}}, binary, {}),
        "unknown_output": ({**header, "outputs": [{"name": "foreground"}]}, binary, {}),
        "output_twice": ({**header, "outputs": [{"name": "mask"}, {"name": "mask"}]}, binary, {}),
        "no_outputs": ({**header, "outputs": []}, binary, {}),
        "bits_on_depth": (
            {**header, "outputs": [{"name": "depth", "parameters": {"bits": True}}]},
            binary,
            {},
        ),
        "unknown_output_parameter": (
            {**header, "outputs": [{"name": "points", "parameters": {"classification": 3}}]},
            binary,
            {},
        ),
        "data_and_binary": (
            with_input(header, "returns", data=returns_json["data"]),
            binary,
            {},
        ),
        "no_data": (
            {
                "inputs": [
                    header["inputs"][0],
                    {k: v for k, v in returns_json.items() if k != "data"},
                ]
            },
            binary[:gray_size],
            {},
        ),
        "json_data_wrong_count": (
            {"inputs": [header["inputs"][0], dict(returns_json, data=returns_json["data"][:-1])]},
            binary[:gray_size],
            {},
        ),
        "json_gray_out_of_range": (
            {
                "inputs": [
                    {"name": "gray", "datatype": "UINT8", "shape": [1, 1], "data": [300]},
                    {"name": "returns", "datatype": "FP32", "shape": [1, 3], "data": [0, 0, 100]},
                ]
            },
            b"",
            {},
        ),
        "json_data_strings": (
            {
                "inputs": [
                    header["inputs"][0],
                    dict(returns_json, data=["a"] * len(returns_json["data"])),
                ]
            },
            binary[:gray_size],
            {},
        ),
        "nan_return": (
            with_input(header, "returns", shape=[1, 3], parameters={"binary_data_size": 12}),
            binary[:gray_size] + nan_returns.tobytes(),
            {},
        ),
        "return_outside_the_frame": (
            {
                "inputs": [
                    header["inputs"][0],
                    {
                        "name": "returns",
                        "datatype": "FP32",
                        "shape": [1, 3],
                        "data": [64, 0, 100.0],
                    },
                ]
            },
            binary[:gray_size],
            {},
        ),
        "no_return": (
            with_input(header, "returns", shape=[0, 3], parameters={"binary_data_size": 0}),
            binary[:gray_size],
            {},
        ),
        "too_many_pixels": (
            with_input(header, "gray", shape=[1024, 1025]),
            binary,
            {},
        ),
        "gzip_body": (
            gzip.compress(json.dumps(header).encode()),
            b"",
            {"Content-Encoding": "gzip"},
        ),
    }[case]


MALFORMED = {
    "gray_fp32": (400, "wrong_dtype", "input gray has datatype FP32; it takes UINT8 or UINT16"),
    "returns_fp64": (400, "wrong_dtype", "input returns has datatype FP64; it takes FP32"),
    "gray_3d": (400, "wrong_shape", "input gray has shape [1, 64, 64]; it must be [H, W]"),
    "returns_n_by_2": (400, "wrong_shape", "it must be [N, 3]"),
    "sparse_other_size": (422, "wrong_shape", "gray is 64 x 64 but sparse is 32 x 64"),
    "missing_gray": (400, "invalid_request", "missing input gray"),
    "missing_returns": (400, "invalid_request", "sparse (FP32 [H, W]) or returns"),
    "sparse_and_returns": (400, "invalid_request", "not both"),
    "unknown_input": (400, "invalid_request", "unknown input 'lidar'"),
    "input_twice": (400, "invalid_request", "input gray is given twice"),
    "binary_size_wrong": (400, "invalid_request", "binary_data_size is 4095 bytes"),
    "binary_short": (400, "invalid_request", "which holds"),
    "binary_trailing": (400, "invalid_request", "8 bytes of binary data follow"),
    "header_length_not_a_number": (400, "invalid_request", "must be a number of bytes"),
    "header_length_zero": (400, "invalid_request", "between 1 and the body's"),
    "header_length_past_the_body": (400, "invalid_request", "between 1 and the body's"),
    "header_length_too_short": (400, "invalid_request", "not valid JSON"),
    "not_json": (400, "invalid_request", "not valid JSON"),
    "json_not_an_object": (400, "invalid_request", "invalid inference request"),
    "empty_body": (400, "invalid_request", "not valid JSON"),
    "unknown_parameter": (400, "invalid_request", "parameters.zoom: Extra inputs"),
    "string_parameter": (400, "invalid_request", "parameters.fx: Input should be a valid number"),
    "negative_fx": (422, "invalid_intrinsics", "focal lengths must be positive pixels"),
    "zero_max_sigma": (422, "invalid_max_sigma", "a positive finite number of metres, got 0.0"),
    "nan_max_sigma": (422, "invalid_max_sigma", "a positive finite number of metres, got nan"),
    "string_max_sigma": (400, "invalid_request", "parameters.max_sigma: Input should be a valid"),
    "unknown_output": (400, "invalid_request", "'depth', 'mask', 'points'"),
    "output_twice": (400, "invalid_request", "output mask is asked for more than once"),
    "no_outputs": (400, "invalid_request", "outputs is empty"),
    "bits_on_depth": (400, "invalid_request", "outputs.0.depth.parameters.bits: Extra inputs"),
    "unknown_output_parameter": (400, "invalid_request", "classification: Extra inputs"),
    "data_and_binary": (400, "invalid_request", "both data and binary_data_size"),
    "no_data": (400, "invalid_request", "input returns has no values"),
    "json_data_wrong_count": (400, "invalid_request", "shape [256, 3] needs 768"),
    "json_gray_out_of_range": (400, "wrong_dtype", "UINT8 values lie in 0..255, got 300..300"),
    "json_data_strings": (400, "wrong_dtype", "data must hold numbers, got strings"),
    "nan_return": (422, "invalid_depth", "returns must be finite numbers; return 0"),
    "return_outside_the_frame": (422, "invalid_returns", "outside the 64 x 64 image"),
    "no_return": (422, "no_returns", "no LIDAR return"),
    "too_many_pixels": (413, "too_large", f"above this service's limit of {MAX_PIXELS}"),
    "gzip_body": (415, "unsupported_media_type", "Content-Encoding gzip is not supported"),
}


def assert_v2_error(response: httpx.Response, status: int, code: str, message: str) -> None:
    """The Open Inference Protocol's error: ``{"error": "..."}`` alone, code in a header."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/json"
    body = response.json()
    assert list(body) == ["error"] and isinstance(body["error"], str), body
    assert message in body["error"], body["error"]
    assert response.headers["sdcnet-error-code"] == code


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_a_malformed_v2_request_gets_a_4xx_in_the_protocols_shape(url, case):
    header, binary, headers = malformed(case)
    assert_v2_error(post_v2(url, header, binary, headers), *MALFORMED[case])
    good = post_v2(url, *good_request())  # and the service keeps serving
    assert good.status_code == 200, good.text


def test_tritonclient_raises_the_services_message(url):
    s = generated(256)
    with pytest.raises(InferenceServerException, match="missing input gray"):
        triton_infer(url, {"returns": returns_from_dense(s.sparse)}, True)


def test_v2_routes_answer_framework_errors_in_the_protocols_shape(url):
    header, binary = good_request()
    too_big = binary + bytes(MAX_UPLOAD_BYTES)  # refused from its Content-Length
    assert_v2_error(post_v2(url, header, too_big), 413, "too_large", "above this service's")
    assert_v2_error(httpx.get(f"{url}{INFER}"), 405, "method_not_allowed", "GET is not allowed")
    assert_v2_error(
        httpx.post(f"{url}/v2/models/other/infer", content=b"{}"), 404, "not_found", "no endpoint"
    )
    # the rest of the service keeps its own shape
    error = httpx.get(f"{url}/nowhere").json()["error"]
    assert error["code"] == "not_found"
