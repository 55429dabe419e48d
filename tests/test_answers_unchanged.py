"""The service's answers on stored frames, bit for bit: a refactor must not change them.

``tests/data/answers.json`` holds, per stored frame, the SHA-256 of the depth, mask, sigma and
point cloud that ``POST /complete`` gave for it with the shipped model, and a few sums that
say how large a change is when one happens. A change of the model or of what the pipeline
computes is a new model version: rewrite the file with

    python -m tests.test_answers_unchanged --write

(``make reports`` does, after exporting) and say in the commit why the answers changed. A
fresh export of ``models/sdcnet.pt`` must answer as the shipped model, to the exporting CPU's
rounding: the training-side code (model, exporter) is held to the stored answers too (that
test needs torch, and is skipped without it).
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA
from sdcnet.client.api import Client
from sdcnet.pipeline import complete
from sdcnet.pointcloud import back_project
from sdcnet.returns import read_returns_csv
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.service.settings import shipped_model_path
from tests.support.serving import running_service

ROOT = Path(__file__).resolve().parent.parent
STORED = Path(__file__).resolve().parent / "data" / "answers.json"
#: Stored frames: (gray PNG, returns CSV) of the paper's camera, by name.
FRAMES = {"tdrs": (ROOT / "examples" / "tdrs.png", ROOT / "examples" / "tdrs.returns.csv")}


def fingerprint(depth: np.ndarray, mask: np.ndarray, sigma: np.ndarray, points: np.ndarray):
    """SHA-256 of each answer array's bytes (its dtype and shape included) and the sums that
    say how far a changed answer moved: foreground pixels, depth and sigma (metres) summed."""

    def sha(array: np.ndarray) -> str:
        array = np.ascontiguousarray(array)
        header = f"{array.dtype.str}{array.shape}".encode()
        return hashlib.sha256(header + array.tobytes()).hexdigest()

    return {
        "depth": sha(depth),
        "mask": sha(mask.astype(bool)),
        "sigma": sha(sigma),
        "points": sha(points),
        "foreground_px": int(np.count_nonzero(mask)),
        "depth_sum_m": float(depth.sum(dtype=np.float64)),
        "sigma_sum_m": float(sigma.sum(dtype=np.float64)),
    }


def frame_inputs(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The stored frame's gray image (uint8) and sparse depth map (float32, metres)."""
    gray_path, returns_path = FRAMES[name]
    gray = cv2.imread(str(gray_path), cv2.IMREAD_UNCHANGED)
    returns = read_returns_csv(returns_path)
    sparse = np.zeros(gray.shape, np.float32)
    sparse[returns[:, 0].astype(int), returns[:, 1].astype(int)] = returns[:, 2]
    return gray, sparse


def in_process_answer(onnx: Path, name: str) -> tuple[np.ndarray, ...]:
    """``onnx``'s depth, mask, sigma and points for a stored frame, through
    ``sdcnet.pipeline`` as the service runs it (the paper's camera: the frames' own)."""
    model = OnnxModel(onnx, provider="cpu", threads=1)
    gray, sparse = frame_inputs(name)
    K = PAPER_CAMERA.intrinsics()
    result = complete(model.run, gray, sparse, K.fx, model.info.stride, model.info.work_pixels)
    points = back_project(result.depth, result.mask, K)
    return result.depth, result.mask, result.sigma, points


def in_process_fingerprint(onnx: Path, name: str) -> dict:
    """The fingerprint of ``onnx``'s answer to a stored frame (``in_process_answer``)."""
    return fingerprint(*in_process_answer(onnx, name))


def stored() -> dict:
    return json.loads(STORED.read_text())


@pytest.fixture(scope="module")
def url(tmp_path_factory):
    log = tmp_path_factory.mktemp("answers-service") / "serve.log"
    with running_service(shipped_model_path(), log) as address:
        yield address


@pytest.mark.parametrize("name", sorted(FRAMES))
def test_the_service_answers_a_stored_frame_as_stored(url, name):
    gray_path, returns_path = FRAMES[name]
    with Client(url) as client:
        answer = client.complete(gray_path, returns_path)
    got = fingerprint(answer.depth, answer.mask, answer.sigma, answer.points)
    assert got == stored()[name]


@pytest.mark.parametrize("name", sorted(FRAMES))
def test_the_in_process_pipeline_answers_as_the_service(name):
    assert in_process_fingerprint(shipped_model_path(), name) == stored()[name]


def test_a_fresh_export_of_the_shipped_checkpoint_answers_as_the_shipped_model(tmp_path):
    """The shipped model is held to the stored answers bit for bit (above); a fresh export
    to its answers, to the rounding of the CPU that exports: torch folds the exported
    constants with its own kernels, and on an Intel Xeon the shipped model's export (made on
    an AMD EPYC) gave the same mask and depth and a sigma off in the seventh digit."""
    pytest.importorskip("torch", reason="exporting needs torch (make test-runtime has none)")
    from sdcnet.export.cli import main as export_main

    out = tmp_path / "sdcnet.onnx"
    checkpoint = shipped_model_path().with_suffix(".pt")
    assert export_main(["--checkpoint", str(checkpoint), "--out", str(out)]) == 0
    for name in sorted(FRAMES):
        depth, mask, sigma, points = in_process_answer(out, name)
        shipped = in_process_answer(shipped_model_path(), name)
        np.testing.assert_array_equal(mask, shipped[1])
        np.testing.assert_allclose(depth, shipped[0], rtol=0, atol=1e-6)  # metres
        np.testing.assert_allclose(sigma, shipped[2], rtol=1e-5, atol=1e-9)
        np.testing.assert_allclose(points, shipped[3], rtol=0, atol=1e-6)


def test_a_changed_answer_changes_its_fingerprint():
    _, sparse = frame_inputs("tdrs")
    depth = sparse.copy()
    mask = depth > 0
    before = fingerprint(depth, mask, depth, np.zeros((3, 3), np.float32))
    depth[mask.nonzero()[0][0], mask.nonzero()[1][0]] += 1e-3  # one pixel, one millimetre
    after = fingerprint(depth, mask, depth, np.zeros((3, 3), np.float32))
    assert after["depth"] != before["depth"] and after["mask"] == before["mask"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"rewrite {STORED.name}")
    parser.add_argument("--onnx", type=Path, default=shipped_model_path())
    args = parser.parse_args()
    answers = {name: in_process_fingerprint(args.onnx, name) for name in sorted(FRAMES)}
    if args.write:
        STORED.parent.mkdir(exist_ok=True)
        STORED.write_text(json.dumps(answers, indent=2) + "\n")
        print(f"wrote {STORED}")
    else:
        print(json.dumps(answers, indent=2))


if __name__ == "__main__":
    main()
