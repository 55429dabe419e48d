"""Frames to send: a synthetic spacecraft drawn with numpy (no generator needed), frames
rendered by the project's generator (the ``data`` extra), their files as a client uploads them,
and a small dataset on disk in the ``sdc-data`` format."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import cv2
import httpx
import numpy as np

from sdcnet.camera import PAPER_CAMERA, PAPER_LIDAR, Intrinsics
from sdcnet.dataset_format import Sample, sample_id, write_manifest, write_sample
from sdcnet.formats.v2 import HEADER_LENGTH
from sdcnet.npyio import npy_bytes


def png_bytes(image: np.ndarray, ext: str = ".png", params: list[int] | None = None) -> bytes:
    """``image`` encoded by OpenCV as ``ext`` (PNG by default) with its encoder ``params``."""
    ok, data = cv2.imencode(ext, image, params or [])
    if not ok:
        raise ValueError(f"OpenCV cannot encode a {image.dtype} {image.shape} image as {ext}")
    return data.tobytes()


def beam_grid(K: Intrinsics, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The pixels the paper's LIDAR samples in a frame of intrinsics ``K``: its beam rows and
    columns (an ``np.ix_`` index), the grid's phase drawn from ``rng``."""
    steps = np.radians([PAPER_LIDAR.vertical_step_deg, PAPER_LIDAR.horizontal_step_deg])
    spacing = np.array([K.fy, K.fx]) * np.tan(steps)  # pixels between beams: rows, columns
    phase = rng.uniform(0, 1, 2) * spacing
    rows = np.round(np.arange(phase[0], K.height, spacing[0])).astype(int)
    cols = np.round(np.arange(phase[1], K.width, spacing[1])).astype(int)
    return np.ix_(rows[rows < K.height], cols[cols < K.width])


def synthetic_frame(size: int = 256, seed: int = 0, distance_m: float = 100.0) -> Sample:
    """A drawn spacecraft at ``size`` x ``size`` with the paper camera's optics: a bus and two
    solar wings, bright (gray 150-230) on a black sky with a few stars, its surface a plane
    tilted in depth around ``distance_m``, and LIDAR returns on the beam grid (with a random
    phase) where it is, Z within 3 cm of the truth. The same for the same arguments."""
    rng = np.random.default_rng(seed)
    K = PAPER_CAMERA.intrinsics().scaled(size, size)
    scale = size / PAPER_CAMERA.width
    rows, cols = np.mgrid[0:size, 0:size].astype(np.float32)
    centre = size / 2 + rng.uniform(-0.05, 0.05, 2) * size
    bus = (np.abs(rows - centre[0]) < 0.08 * size) & (np.abs(cols - centre[1]) < 0.08 * size)
    wings = (np.abs(rows - centre[0]) < 0.03 * size) & (np.abs(cols - centre[1]) < 0.3 * size)
    mask = bus | wings
    tilt = rng.uniform(-0.02, 0.02, 2) / scale  # metres per pixel of this frame
    plane = distance_m + tilt[0] * (rows - centre[0]) + tilt[1] * (cols - centre[1])
    depth = np.where(mask, plane, 0).astype(np.float32)

    gray = np.zeros((size, size), np.uint8)
    gray[mask] = rng.integers(150, 231, int(mask.sum()))
    stars = rng.integers(0, size, (8, 2))
    gray[stars[:, 0], stars[:, 1]] = np.maximum(gray[stars[:, 0], stars[:, 1]], 90)

    sparse = np.zeros_like(depth)
    grid = beam_grid(K, rng)
    hit = mask[grid]
    noise = rng.uniform(-0.03, 0.03, hit.shape).astype(np.float32)
    sparse[grid] = np.where(hit, depth[grid] + noise, 0)
    meta = {
        "id": sample_id(seed, 0),
        "file": f"samples/{sample_id(seed, 0)}.npz",
        "model": seed,
        "model_name": "synthetic",
        "view": 0,
        "distance_m": distance_m,
        "returns": int(np.count_nonzero(sparse)),
        "foreground_px": int(mask.sum()),
    }
    return Sample(gray, sparse, depth, meta)


def write_dataset(root: Path, splits: dict[str, int], size: int = 64) -> Path:
    """A small dataset in the ``sdc-data`` format (``sdcnet.dataset_format``) of synthetic
    frames, ``splits[name]`` frames per split, without the generator; returns ``root``."""
    (root / "samples").mkdir(parents=True, exist_ok=True)
    metas = []
    seed = 0
    for split, count in splits.items():
        for _ in range(count):
            sample = synthetic_frame(size, seed)
            sample.meta["split"] = split
            write_sample(root / sample.meta["file"], sample)
            metas.append(sample.meta)
            seed += 1
    info = {"command": f"tests.support.frames.write_dataset(splits={splits}, size={size})"}
    (root / "dataset.json").write_text(json.dumps(info) + "\n")
    write_manifest(root, metas)
    return root


@functools.cache
def generated_sample(size: int = 256) -> Sample:
    """One frame rendered by the project's generator at ``size`` x ``size`` (the paper's
    optics): a procedural spacecraft. Needs the ``data`` extra."""
    from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample

    config = GenerateConfig(models=1, views=1, seed=3, split=(1, 0, 0), size=size)
    return make_sample(config, build_spacecraft(config, 0), 0, 0, "test")


@functools.cache
def generated_samples(size: int = 1024, count: int = 4, seed: int = 5) -> tuple[Sample, ...]:
    """``count`` rendered frames at ``size`` x ``size``, one per procedural spacecraft of
    ``seed``: different shapes, attitudes and distances (50-250 m), the same for a seed.
    Needs the ``data`` extra."""
    from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample

    config = GenerateConfig(models=count, views=1, seed=seed, split=(count, 0, 0), size=size)
    return tuple(
        make_sample(config, build_spacecraft(config, m), m, 0, "test") for m in range(count)
    )


def sample_files(s: Sample) -> dict[str, tuple[str, bytes]]:
    """The multipart files of one frame as a client sends them: gray PNG, sparse ``.npy``."""
    return {"gray": ("gray.png", png_bytes(s.gray)), "sparse": ("sparse.npy", npy_bytes(s.sparse))}


def multipart_body(files: dict, data: dict | None = None) -> tuple[bytes, str]:
    """(body bytes, Content-Type) of a multipart form, encoded once by httpx: load generators
    send the same bytes many times without re-encoding them."""
    request = httpx.Request("POST", "http://127.0.0.1/", files=files, data=data)
    return request.read(), request.headers["content-type"]


def v2_inputs(gray: np.ndarray, returns: np.ndarray, binary: bool) -> tuple[list[dict], bytes]:
    """The inputs of POST /v2/models/sdcnet/infer for gray (UINT8) and returns (FP32), as JSON
    data or, when ``binary``, as binary data: (inputs, binary bytes)."""
    inputs = [
        {"name": "gray", "datatype": "UINT8", "shape": list(gray.shape)},
        {"name": "returns", "datatype": "FP32", "shape": list(returns.shape)},
    ]
    arrays = (gray, returns.astype("<f4"))
    for entry, array in zip(inputs, arrays, strict=True):
        if binary:
            entry["parameters"] = {"binary_data_size": array.nbytes}
        else:
            entry["data"] = array.ravel().tolist()
    return inputs, b"".join(a.tobytes() for a in arrays) if binary else b""


def v2_body(gray: np.ndarray, returns: np.ndarray) -> tuple[bytes, dict[str, str]]:
    """(body, headers) of a binary request to POST /v2/models/sdcnet/infer as tritonclient
    sends one by default: gray UINT8 and returns FP32 as binary data, every output binary."""
    inputs, binary = v2_inputs(gray, returns, binary=True)
    header = json.dumps({"inputs": inputs, "parameters": {"binary_data_output": True}}).encode()
    return header + binary, {HEADER_LENGTH: str(len(header))}
