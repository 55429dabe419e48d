"""Real parts for the service and client tests: an exported model, generated frames, and the
real service (``python -m sdcnet.service``, i.e. ``sdc-serve``) in a subprocess on 127.0.0.1.

Plain helpers rather than fixtures, so that each test module builds its own module-scoped
fixtures (one service process per module) on top of them.
"""

from __future__ import annotations

import functools
import io
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import httpx
import numpy as np
import torch

from sdcnet.export.onnx_export import export_onnx, model_metadata
from sdcnet.training.data.format import Sample
from sdcnet.training.data.generate import GenerateConfig, build_model, make_sample
from sdcnet.training.model.sdcnet import SDCNet

MODEL_VERSION = "test-random"
_STARTED = re.compile(r"Uvicorn running on (http://\S+)")


def random_model(base: Path) -> Path:
    """The real SDCNet graph with random weights, exported once per test session into
    ``base``. Random weights predict no foreground, so the segmentation head's bias is raised
    (as test_export does) to make the whole crop foreground: a non-empty mask and cloud."""
    path = base / "sdcnet-random.onnx"
    if not path.exists():
        torch.manual_seed(0)
        model = SDCNet().eval()
        with torch.no_grad():
            model.fsnet.head.bias += 3.0
        export_onnx(model, path, model_metadata(model, MODEL_VERSION))
    return path


@functools.cache
def sample(size: int = 256) -> Sample:
    """One generated frame at ``size`` x ``size`` (same optics as the paper's camera)."""
    config = GenerateConfig(models=1, views=1, seed=3, split=(1, 0, 0), size=size)
    return make_sample(config, build_model(config, 0), 0, 0, "test")


def png_bytes(image: np.ndarray, ext: str = ".png") -> bytes:
    ok, data = cv2.imencode(ext, image)
    assert ok
    return data.tobytes()


def npy_bytes(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=allow_pickle)
    return buffer.getvalue()


@contextmanager
def running_service(model: Path, log: Path, *flags: str) -> Iterator[str]:
    """Start ``sdc-serve`` on a free port of 127.0.0.1 with ``flags``; yield its URL once
    ``/ready`` answers 200; stop it afterwards."""
    command = [sys.executable, "-m", "sdcnet.service", "--model", str(model)]
    command += ["--host", "127.0.0.1", "--port", "0", "--threads", "1", *flags]
    with log.open("w") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    try:
        url = _wait_ready(process, log)
        yield url
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def _wait_ready(process: subprocess.Popen, log: Path, timeout_s: float = 90.0) -> str:
    deadline = time.monotonic() + timeout_s
    url = None
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the service exited with {process.returncode}:\n{log.read_text()}")
        if url is None and (found := _STARTED.search(log.read_text())):
            url = found.group(1)
        if url is not None:
            try:
                if httpx.get(f"{url}/ready", timeout=2).status_code == 200:
                    return url
            except httpx.TransportError:
                pass
        time.sleep(0.1)
    raise RuntimeError(f"the service was not ready within {timeout_s} s:\n{log.read_text()}")
