"""The client (Python API and ``sdc-client``) against the real service in a subprocess, on the
tiny sdcnet-shaped ONNX model (no torch), fed synthetic frames."""

from __future__ import annotations

import base64
import io
import json
import socket
import subprocess
import sys
import threading
import time

import cv2
import httpx
import numpy as np
import pytest

from sdcnet.camera import GivenIntrinsics
from sdcnet.caveats import CAVEATS, FEW_RETURNS
from sdcnet.client.api import DEFAULT_URL, Client, Completion, ServiceError
from sdcnet.client.batch import find_pairs
from sdcnet.client.cli import frame_kwargs, main, parser
from sdcnet.client.outputs import OUTPUT_FILES, normal_image
from sdcnet.dataset_format import SampleStore
from sdcnet.npyio import npy_bytes
from sdcnet.pipeline import complete
from sdcnet.pointcloud import read_ply
from sdcnet.returns import returns_from_dense, write_returns_csv
from sdcnet.runtime.onnx import OnnxModel
from tests.support.attacks import connect, request_head
from tests.support.frames import multipart_body, png_bytes, synthetic_frame, write_dataset
from tests.support.models import TINY_VERSION
from tests.support.serving import running_service


def frame(size: int):
    """The test frame: a synthetic spacecraft at 100 m."""
    return synthetic_frame(size, seed=1)


@pytest.fixture(scope="module")
def url(tmp_path_factory, tiny_model_path):
    model = tiny_model_path
    log = tmp_path_factory.mktemp("client-service") / "serve.log"
    # one request at a time, none held waiting: concurrent clients meet 503s and must retry
    flags = ("--max-in-flight=1", "--max-requests=1", "--retry-after=1")
    with running_service(model, log, *flags) as address:
        yield address


@pytest.fixture(scope="module")
def frame_files(tmp_path_factory):
    """The 256 x 256 test frame as files: gray.png and sparse.npy."""
    folder = tmp_path_factory.mktemp("frame")
    s = frame(256)
    cv2.imwrite(str(folder / "gray.png"), s.gray)
    np.save(folder / "sparse.npy", s.sparse)
    return folder / "gray.png", folder / "sparse.npy"


def service_answer(url: str, gray: bytes, sparse: bytes, **fields) -> dict[str, np.ndarray]:
    """The service's own JSON answer, decoded: what the client's files must hold."""
    files = {"gray": ("g.png", gray), "sparse": ("s.npy", sparse)}
    body = httpx.post(f"{url}/complete", files=files, data=fields, timeout=60).json()
    return {
        k: np.load(io.BytesIO(base64.b64decode(body[k]["npy_base64"])), allow_pickle=False)
        for k in ("depth", "mask", "points", "normals", "sigma")
    }


def service_summary(url: str, gray: bytes, sparse: bytes) -> dict:
    """The summary of the service's own JSON answer."""
    files = {"gray": ("g.png", gray), "sparse": ("s.npy", sparse)}
    body = httpx.post(f"{url}/complete", files=files, timeout=60).json()
    return {k: v for k, v in body.items() if not isinstance(v, dict) or "npy_base64" not in v}


def service_ply(url: str, gray: bytes, sparse: bytes, **fields) -> bytes:
    """The service's own PLY answer."""
    files = {"gray": ("g.png", gray), "sparse": ("s.npy", sparse)}
    params = {"format": "ply"}
    return httpx.post(
        f"{url}/complete", files=files, data=fields, params=params, timeout=60
    ).content


def test_infer_prints_the_answers_caveats_with_their_meaning(url, frame_files, tmp_path, capsys):
    gray, sparse = frame_files
    few = np.load(sparse)
    rows, cols = np.nonzero(few)
    few[rows[FEW_RETURNS // 2 :], cols[FEW_RETURNS // 2 :]] = 0  # 10 returns left
    np.save(tmp_path / "few.npy", few)
    argv = ["infer", str(gray), str(tmp_path / "few.npy"), "--url", url, "--out", str(tmp_path)]
    assert main(argv) == 0
    assert f"caveat    few_returns: {CAVEATS['few_returns']}" in capsys.readouterr().out


def test_infer_writes_five_files_that_match_the_service(url, frame_files, tmp_path, capsys):
    gray, sparse = frame_files
    out = tmp_path / "out"
    assert main(["infer", str(gray), str(sparse), "--url", url, "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES)

    expected = service_answer(url, gray.read_bytes(), sparse.read_bytes())
    depth = np.load(out / "depth.npy", allow_pickle=False)
    np.testing.assert_array_equal(depth, expected["depth"])
    sigma = np.load(out / "sigma.npy", allow_pickle=False)
    assert sigma.dtype == np.float32 and np.isfinite(sigma).all()
    np.testing.assert_array_equal(sigma, expected["sigma"])
    mask = cv2.imread(str(out / "mask.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(mask, expected["mask"] * 255)

    header = (out / "points.ply").read_bytes().split(b"end_header\n")[0].decode()
    assert f"element vertex {len(expected['points'])}" in header
    cloud = read_ply(out / "points.ply")
    points = cloud.points
    np.testing.assert_array_equal(points, expected["points"])
    assert len(points) == np.count_nonzero(expected["depth"]) > 3000
    assert f"model_version {TINY_VERSION}" in cloud.comments
    # each point's normal and sigma, as in the service's own PLY answer
    served = read_ply(service_ply(url, gray.read_bytes(), sparse.read_bytes()))
    for name in ("nx", "ny", "nz", "sigma"):
        np.testing.assert_array_equal(cloud.properties[name], served.properties[name])

    preview = cv2.imread(str(out / "preview.png"))
    assert preview.shape == (320, 6 * 320 + 5 * 4, 3)
    printed = capsys.readouterr().out
    assert TINY_VERSION in printed and f"points    {len(points):,}" in printed
    median = np.median(expected["sigma"][expected["mask"].astype(bool)])
    assert f"sigma     median {median:.3f} m on the mask" in printed
    assert len(printed.splitlines()) <= 24  # one screen
    # enough returns, and the field holds the spacecraft; but the tiny model's probability is
    # the gray image, 0.59-0.90 on the craft: its estimate of the mask's IOU is low
    estimate = service_summary(url, gray.read_bytes(), sparse.read_bytes())["mask_iou_estimate"]
    assert f", IOU {100 * estimate:.1f} % as the network expects it" in printed
    caveats = [line.split(":")[0].split()[-1] for line in printed.splitlines() if "caveat" in line]
    assert caveats == ["mask_uncertain"]

    # --max-sigma: the cloud without the points above it, the arrays whole
    limit = float(median)  # about half the points are above it
    argv = ["infer", str(gray), str(sparse), "--url", url, "--out", str(tmp_path / "cut")]
    assert main([*argv, "--max-sigma", repr(limit)]) == 0
    cut = read_ply(tmp_path / "cut" / "points.ply")
    served = read_ply(service_ply(url, gray.read_bytes(), sparse.read_bytes(), max_sigma=limit))
    np.testing.assert_array_equal(cut.points, served.points)
    np.testing.assert_array_equal(cut.properties["sigma"], served.properties["sigma"])
    assert 0 < len(cut.points) < len(points) and cut.properties["sigma"].max() <= limit
    np.testing.assert_array_equal(np.load(tmp_path / "cut" / "sigma.npy"), sigma)
    removed = len(points) - len(cut.points)
    assert f"{removed} above max_sigma removed" in capsys.readouterr().out


def test_the_preview_fills_each_block_of_a_strided_cloud_from_its_point():
    """A cloud of every second pixel (``cloud_stride`` 2): each point's normal shows on its
    2 x 2 block, cut at the frame's edge."""
    depth = np.ones((5, 5), np.float32)
    rows, cols = np.mgrid[0:5:2, 0:5:2].reshape(2, -1)
    normals = np.zeros((len(rows), 3), np.float32)
    normals[:, 2] = np.arange(1, len(rows) + 1)
    empty = np.zeros((0, 3), np.float32)
    result = Completion(depth, depth > 0, empty, depth, normals, meta={"cloud_stride": 2})
    image = normal_image(result, (rows, cols))
    assert image.shape == (5, 5, 3)
    blocks = [[1, 1, 2, 2, 3]] * 2 + [[4, 4, 5, 5, 6]] * 2 + [[7, 7, 8, 8, 9]]
    np.testing.assert_array_equal(image[..., 2], blocks)


def test_python_api_returns_arrays(url, frame_files):
    s = frame(256)
    expected = service_answer(url, png_bytes(s.gray), npy_bytes(s.sparse))
    with Client(url) as client:
        from_arrays = client.complete(s.gray, s.sparse)
        from_files = client.complete(*frame_files)
    for result in (from_arrays, from_files):
        np.testing.assert_array_equal(result.depth, expected["depth"])
        np.testing.assert_array_equal(result.mask, expected["mask"].astype(bool))
        np.testing.assert_array_equal(result.points, expected["points"])
        np.testing.assert_array_equal(result.normals, expected["normals"])
        assert result.sigma.dtype == np.float32 and np.isfinite(result.sigma).all()
        np.testing.assert_array_equal(result.sigma, expected["sigma"])  # pasted back whole
        assert result.model_version == TINY_VERSION
        assert result.provider == "CPUExecutionProvider"
        assert set(result.timings_ms) == {"decode_ms", "queue_ms", "inference_ms", "encode_ms"}
    limit = float(np.median(expected["sigma"][expected["mask"].astype(bool)]))
    with Client(url) as client:
        cut = client.complete(s.gray, s.sparse, max_sigma=limit)
    served = service_answer(url, png_bytes(s.gray), npy_bytes(s.sparse), max_sigma=limit)
    np.testing.assert_array_equal(cut.points, served["points"])
    np.testing.assert_array_equal(cut.sigma, expected["sigma"])
    assert 0 < len(cut.points) < len(expected["points"])
    assert cut.meta["uncertain_removed"] == len(expected["points"]) - len(cut.points)


def test_concurrent_clients_retry_503_and_all_succeed(url):
    """Three clients while the one place is held (a raw request, its body one byte short):
    each is refused with 503, waits Retry-After and tries again; the place is given back
    meanwhile and all three are answered. Holding the place makes the refusals certain
    (three clients racing for it could be served one after another on a fast machine)."""
    s = frame(1024)
    overloaded = 'sdcnet_inference_request_failure_total{reason="overloaded"}'

    def refused() -> float:
        lines = httpx.get(f"{url}/metrics").text.splitlines()
        return sum(float(line.split()[-1]) for line in lines if line.startswith(overloaded))

    before = refused()
    results, errors = [], []
    small = frame(128)
    body, content_type = multipart_body(
        {"gray": ("g.png", png_bytes(small.gray)), "sparse": ("s.npy", npy_bytes(small.sparse))}
    )
    holder = connect(url)
    holder.sendall(request_head("/complete", len(body), content_type) + body[:-1])

    def run(client: Client) -> None:
        try:
            results.append(client.complete(s.gray, s.sparse))
        except Exception as exc:
            errors.append(exc)

    with Client(url, retries=8) as client:
        threads = [threading.Thread(target=run, args=(client,)) for _ in range(3)]
        for t in threads:
            t.start()
        time.sleep(0.8)  # the three refused at once, waiting out Retry-After
        holder.sendall(body[-1:])
        holder.close()
        for t in threads:
            t.join()
    assert not errors and len(results) == 3
    assert refused() >= before + 3  # each was refused with 503 and went through on a retry
    assert max(r.latency_s for r in results) >= 1.0  # ... after Retry-After: 1


def test_a_kept_alive_connection_the_server_closed_is_replaced(url):
    """uvicorn closes a connection idle for 5 s; the next request, even one that may not be
    retried, goes out on a new connection."""
    s = frame(256)
    with Client(url, retries=0) as client:
        first = client.complete(s.gray, s.sparse)
        time.sleep(6)
        assert client.health() == {"live": True, "ready": True}
        np.testing.assert_array_equal(client.complete(s.gray, s.sparse).depth, first.depth)


def test_a_missing_or_unreadable_file_exits_2(frame_files, tmp_path, capsys):
    gray, sparse = frame_files
    assert main(["infer", str(tmp_path / "nope.png"), str(sparse)]) == 2
    assert f"gray image file not found: {tmp_path / 'nope.png'}" in capsys.readouterr().err
    assert main(["infer", str(gray), str(tmp_path)]) == 2
    assert "sparse depth is a directory" in capsys.readouterr().err


def test_a_4xx_answer_exits_3_with_the_service_message(url, tmp_path, capsys):
    s = frame(256)
    np.save(tmp_path / "sparse.npy", s.sparse)
    cv2.imwrite(str(tmp_path / "gray.png"), s.gray)
    argv = ["infer", str(tmp_path / "gray.png"), str(tmp_path / "sparse.npy"), "--url", url]
    assert main([*argv, "--fx", "-5", "--out", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err
    assert "422 invalid_intrinsics" in err
    assert "focal lengths must be positive pixels, got fx -5" in err
    assert not (tmp_path / "out").exists()
    with Client(url) as client, pytest.raises(ServiceError) as raised:
        client.complete(s.gray, np.zeros_like(s.sparse))
    assert (raised.value.status, raised.value.code) == (422, "no_returns")


def test_a_sparse_map_of_another_size_or_bad_returns_exit_2_before_sending(
    frame_files, tmp_path, capsys
):
    gray, sparse = frame_files
    np.save(tmp_path / "small.npy", np.pad(np.load(sparse), ((0, 0), (0, 8))))
    argv = ["infer", str(gray), str(tmp_path / "small.npy"), "--url", "http://127.0.0.1:9"]
    assert main([*argv, "--retries", "0"]) == 2
    assert "a (H, W) = (256, 256) map in metres or an (N, 3) list" in capsys.readouterr().err
    (tmp_path / "bad.csv").write_text("row,col,z_m\n3,300,100\n")
    argv[2] = str(tmp_path / "bad.csv")
    assert main([*argv, "--retries", "0"]) == 2
    assert f"{tmp_path / 'bad.csv'}: return 0 at row 3, col 300 is outside the 256 x 256 image" in (
        capsys.readouterr().err
    )


def test_an_unreachable_server_exits_4(frame_files, capsys):
    with socket.socket() as sock:  # a port that nothing listens on
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    gray, sparse = frame_files
    url = f"http://127.0.0.1:{port}"
    assert main(["infer", str(gray), str(sparse), "--url", url, "--retries", "1"]) == 4
    assert f"cannot reach the sdcnet service at {url}" in capsys.readouterr().err
    assert main(["health", "--url", url]) == 4


def test_health_and_model_commands(url, capsys):
    assert main(["health", "--url", url]) == 0
    assert capsys.readouterr().out.strip() == f"{url}: live yes, ready yes"
    assert main(["model", "--url", url]) == 0
    assert json.loads(capsys.readouterr().out)["version"] == TINY_VERSION


def test_batch_goes_on_past_a_failed_pair(url, tmp_path, capsys):
    s = frame(256)
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    for name in ("a", "b", "c", "d"):
        cv2.imwrite(str(pairs / f"{name}.png"), s.gray)
    np.save(pairs / "a.npy", s.sparse)
    np.save(pairs / "b.npy", np.pad(s.sparse, ((0, 4), (0, 0))))  # wrong size: this one fails
    millimetres = np.round(s.sparse * 1000).astype(np.uint16)
    cv2.imwrite(str(pairs / "c.sparse.png"), millimetres)  # 16-bit PNG, needs a scale
    write_returns_csv(pairs / "d.csv", returns_from_dense(s.sparse))  # a list of returns
    out = tmp_path / "out"
    argv = ["batch", str(pairs), "--out", str(out), "--url", url, "--depth-scale", "0.001"]
    assert main([*argv, "--concurrency", "2", "--no-progress"]) == 1
    assert sorted(p.name for p in out.iterdir()) == ["a", "c", "d"]
    assert sorted(p.name for p in (out / "c").iterdir()) == sorted(OUTPUT_FILES)
    np.testing.assert_array_equal(
        np.load(out / "d" / "depth.npy"), np.load(out / "a" / "depth.npy")
    )
    report = capsys.readouterr().out
    assert "3 of 4 pairs completed, 1 failed" in report
    assert "FAILED b: sparse must be a (H, W) = (256, 256) map" in report


def test_batch_of_a_manifest_and_of_a_dataset_split(url, frame_files, tiny_model_path, tmp_path):
    gray, sparse = frame_files
    manifest = gray.parent / "pairs.jsonl"
    line = {"id": "first", "gray": gray.name, "sparse": sparse.name, "fx": 500.0}
    manifest.write_text(json.dumps(line) + "\n")
    assert main(["batch", str(manifest), "--out", str(tmp_path / "m"), "--url", url]) == 0
    assert (tmp_path / "m" / "first" / "points.ply").is_file()

    dataset = write_dataset(tmp_path / "dataset", {"train": 2, "test": 2})
    test_ids = [record["id"] for record in SampleStore(dataset).split("test")]
    for source in (dataset, dataset / "manifest.jsonl"):  # the folder or its manifest
        out = tmp_path / "d" / source.name
        argv = ["batch", str(source), "--out", str(out), "--url", url, "--split", "test"]
        assert main([*argv, "--no-progress", "--concurrency", "1"]) == 0
        assert sorted(p.name for p in out.iterdir()) == sorted(test_ids) != []
    store = SampleStore(dataset)
    sample = store.load(store.split("test")[0])
    model = OnnxModel(tiny_model_path, threads=1)  # the service's model, in process
    height, width = sample.gray.shape  # no intrinsics sent: the model's, scaled to the frame
    fx = model.info.intrinsics.scaled(width, height).fx
    answer = complete(model.run, sample.gray, sample.sparse, fx, model.stride)
    depth = np.load(out / test_ids[0] / "depth.npy")
    assert np.count_nonzero(depth) > 0
    np.testing.assert_allclose(depth, answer.depth, atol=1e-4)


def test_a_pairs_own_values_replace_the_command_lines_one_by_one(tmp_path):
    manifest = tmp_path / "pairs.jsonl"
    lines = [
        {"gray": "a.png", "sparse": "a.npy", "fx": 500, "cy": 60.5},
        {"gray": "b.png", "sparse": "b.sparse.png", "depth_scale": 0.001},
    ]
    manifest.write_text("".join(json.dumps(line) + "\n" for line in lines))
    first, second = find_pairs(manifest)
    argv = ["infer", "g.png", "s.npy", "--fx", "900", "--fy", "910", "--depth-scale", "0.01"]
    defaults = frame_kwargs(parser().parse_args(argv))
    assert first.options(defaults) == {
        # fx alone: fy at the command line's aspect ratio, not its value
        "intrinsics": GivenIntrinsics(fx=500.0, fy=500.0 * 910 / 900, cy=60.5),
        "max_sigma": None,  # and no depth scale: a .npy map holds metres
    }
    assert second.options(defaults) == {
        "intrinsics": GivenIntrinsics(fx=900.0, fy=910.0),
        "depth_scale": 0.001,
        "max_sigma": None,
    }


def test_the_client_imports_no_torch_onnxruntime_fastapi_or_httpx():
    code = (
        "import sys, sdcnet.client.cli, sdcnet.client.api\n"
        "heavy = {'torch', 'onnxruntime', 'fastapi', 'httpx', 'sdcnet.service'}\n"
        "heavy &= set(sys.modules)\n"
        "heavy |= {m for m in sys.modules if m.startswith(('sdcnet.training', 'sdcnet.export'))}\n"
        "assert not heavy, heavy\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    result = subprocess.run(
        [sys.executable, "-m", "sdcnet.client", "--help"], capture_output=True, text=True
    )
    assert result.returncode == 0 and "infer" in result.stdout and "batch" in result.stdout


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["health"], (DEFAULT_URL, 60.0, 3, False)),
        (["--url", "http://h:1", "--retries", "0", "health"], ("http://h:1", 60.0, 0, False)),
        (["model", "--url", "http://h:1", "--debug"], ("http://h:1", 60.0, 3, True)),
        # given on both sides, the command's own wins
        (
            ["--url", "http://a:1", "--timeout", "5", "health", "--url", "http://b:2"],
            ("http://b:2", 5.0, 3, False),
        ),
        (["--debug", "infer", "g.png", "s.npy"], (DEFAULT_URL, 60.0, 3, True)),
    ],
)
def test_the_connection_options_go_before_or_after_the_command(argv, expected):
    args = parser().parse_args(argv)
    assert (args.url, args.timeout, args.retries, args.debug) == expected
