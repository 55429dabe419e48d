"""Real parts for the service and client tests: an exported model, generated frames, and the
real service (``python -m sdcnet.service``, i.e. ``sdc-serve``) in a subprocess on 127.0.0.1,
with its memory and open files read from /proc.

Plain helpers rather than fixtures, so that each test module builds its own module-scoped
fixtures (one service process per module) on top of them. The benchmarks that start the
service (``benchmarks.service_latency``, ``benchmarks.load``, ``benchmarks.fuzz``) use them too.
"""

from __future__ import annotations

import functools
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import httpx
import numpy as np
import torch

from sdcnet.dataset_format import Sample
from sdcnet.export.onnx_export import export_onnx, model_metadata
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense
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


@functools.cache
def samples(size: int = 1024, count: int = 4, seed: int = 5) -> tuple[Sample, ...]:
    """``count`` generated frames at ``size`` x ``size``, one per procedural spacecraft of
    ``seed``: different shapes, attitudes and distances (50-250 m), the same for a seed."""
    config = GenerateConfig(models=count, views=1, seed=seed, split=(count, 0, 0), size=size)
    return tuple(make_sample(config, build_model(config, m), m, 0, "test") for m in range(count))


def sample_files(s: Sample) -> dict[str, tuple[str, bytes]]:
    """The multipart files of one frame as a client sends them: gray PNG, sparse ``.npy``."""
    return {"gray": ("gray.png", png_bytes(s.gray)), "sparse": ("sparse.npy", npy_bytes(s.sparse))}


def multipart_body(files: dict, data: dict | None = None) -> tuple[bytes, str]:
    """(body bytes, Content-Type) of a multipart form, encoded once by httpx: load generators
    send the same bytes many times without re-encoding them."""
    request = httpx.Request("POST", "http://127.0.0.1/", files=files, data=data)
    return request.read(), request.headers["content-type"]


def png_bytes(image: np.ndarray, ext: str = ".png", params: list[int] | None = None) -> bytes:
    """``image`` encoded by OpenCV as ``ext`` (PNG by default) with its encoder ``params``."""
    ok, data = cv2.imencode(ext, image, params or [])
    assert ok
    return data.tobytes()


@dataclass(frozen=True)
class Service:
    """A running ``sdc-serve``: its base URL and the process id /proc knows it by."""

    url: str
    pid: int


@contextmanager
def service_process(model: Path, log: Path, *flags: str) -> Iterator[Service]:
    """Start ``sdc-serve`` on a free port of 127.0.0.1 with ``flags`` (after ``--threads 1``,
    which a ``--threads`` flag overrides); yield it once ``/ready`` answers 200; stop it
    afterwards."""
    command = [sys.executable, "-m", "sdcnet.service", "--model", str(model)]
    command += ["--host", "127.0.0.1", "--port", "0", "--threads", "1", *flags]
    with log.open("w") as out:
        process = subprocess.Popen(command, stdout=out, stderr=subprocess.STDOUT)
    try:
        yield Service(_wait_ready(process, log), process.pid)
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@contextmanager
def running_service(model: Path, log: Path, *flags: str) -> Iterator[str]:
    """``service_process``, yielding only the URL."""
    with service_process(model, log, *flags) as service:
        yield service.url


#: The model the service ships with, when it has been trained and exported.
SHIPPED_MODEL = Path(__file__).resolve().parent.parent / "models" / "sdcnet.onnx"


def benchmark_model(path: Path | None, workdir: Path) -> tuple[Path, str]:
    """The model a benchmark serves, and how to name it in its report: ``path`` when given,
    else the shipped ``models/sdcnet.onnx`` when it exists, else the real architecture with
    random weights (``random_model``), exported into ``workdir``."""
    if path is not None:
        return path, f"`{path}`"
    if SHIPPED_MODEL.exists():
        return SHIPPED_MODEL, "the shipped `models/sdcnet.onnx`"
    return random_model(workdir), (
        "SDCNet with random weights (`models/sdcnet.onnx` does not exist yet; the "
        "segmentation bias is raised so that the whole crop is foreground)"
    )


@contextmanager
def temporary_service(model: Path | None, *flags: str) -> Iterator[tuple[Service, str]]:
    """``service_process`` on ``benchmark_model(model)``, its log in a temporary folder; yields
    the service and the model's description."""
    with tempfile.TemporaryDirectory() as work:
        path, description = benchmark_model(model, Path(work))
        with service_process(path, Path(work) / "serve.log", *flags) as service:
            yield service, description


def memory_kib(pid: int) -> dict[str, int]:
    """Resident memory of a process from /proc/PID/status, KiB: ``rss`` (VmRSS, now) and
    ``peak`` (VmHWM, the most it ever held)."""
    fields = dict(
        line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines()
    )
    return {"rss": int(fields["VmRSS"].split()[0]), "peak": int(fields["VmHWM"].split()[0])}


def open_fds(pid: int) -> int:
    """File descriptors the process holds open (entries of /proc/PID/fd)."""
    return len(os.listdir(f"/proc/{pid}/fd"))


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


# -- fuzzing the API from its OpenAPI schema (tests/test_fuzz.py, benchmarks/fuzz.py) ------

COMPLETE = "POST /complete"
V2_INFER = "POST /v2/models/sdcnet/infer"


@dataclass
class FuzzReport:
    """What a schemathesis run did: statuses per operation, failures (check, message, curl)."""

    statuses: dict[str, dict[int | None, int]]
    failures: list[str]
    seconds: float

    @property
    def requests(self) -> int:
        return sum(sum(counts.values()) for counts in self.statuses.values())

    def summary(self) -> str:
        """A markdown table of statuses per operation, then the failures."""
        codes = sorted({c for counts in self.statuses.values() for c in counts}, key=str)
        lines = [
            "| operation | requests | " + " | ".join(str(c) for c in codes) + " |",
            "|---|---|" + "---|" * len(codes),
        ]
        for operation, counts in sorted(self.statuses.items()):
            cells = " | ".join(str(counts.get(c, 0)) for c in codes)
            lines.append(f"| {operation} | {sum(counts.values())} | {cells} |")
        lines.append(
            f"\n{self.requests} requests in {self.seconds:.1f} s, {len(self.failures)} failures"
        )
        return "\n".join(lines + self.failures)


def fuzz_arrays() -> tuple[np.ndarray, np.ndarray]:
    """A valid 64 x 64 frame: a gray gradient (uint8) and 256 returns at 100-115 m (dense)."""
    gray = np.add.outer(np.arange(64), np.arange(64)).astype(np.uint8)
    sparse = np.zeros((64, 64), np.float32)
    sparse[::4, ::4] = 100 + np.arange(256, dtype=np.float32).reshape(16, 16) / 16
    return gray, sparse


def fuzz_frame(depth_scale: float | None, as_returns: bool = False) -> dict[str, bytes]:
    """``fuzz_arrays`` as the files of POST /complete: gray PNG and the returns as a ``.npy``
    map or, when ``depth_scale`` (metres per unit) is given, a 16-bit PNG; or, ``as_returns``,
    a ``.npy`` list (field ``returns``)."""
    gray, sparse = fuzz_arrays()
    if as_returns:
        return {"gray": png_bytes(gray), "returns": npy_bytes(returns_from_dense(sparse))}
    if depth_scale is None:
        return {"gray": png_bytes(gray), "sparse": npy_bytes(sparse)}
    units = np.clip(np.round(sparse / depth_scale), 0, 65535).astype(np.uint16)
    units[::4, ::4] = np.maximum(units[::4, ::4], 1)  # a return stays a return at any scale
    return {"gray": png_bytes(gray), "sparse": png_bytes(units)}


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
    return header + binary, {"Inference-Header-Content-Length": str(len(header))}


def fuzz_inputs(binary: bool) -> tuple[list[dict], bytes]:
    """``fuzz_arrays`` as the inputs of POST /v2/models/sdcnet/infer (``v2_inputs``)."""
    gray, sparse = fuzz_arrays()
    return v2_inputs(gray, returns_from_dense(sparse), binary)


def real_files_for_valid_cases(context, case, kwargs: dict) -> None:
    """schemathesis ``before_call`` hook: a positive (schema-valid) inference case is sent
    with a real frame in place of its generated images and tensors.

    The schema can say that ``gray`` and ``sparse`` are files, not that they are a decodable
    image and a depth map of the same size (nor that a form gives one of ``sparse`` and
    ``returns``); it can say that v2 inputs are tensors, not which names, shapes and bytes make
    a frame (nor that an output is asked for once). Without this, every "valid" case would be
    refused (rightly) and the positive_data_acceptance check would test nothing. Every other
    field keeps its generated value (intrinsics, depth_scale, outlier_removal, format; the v2
    request's id, parameters and outputs). The frame goes in the transport's arguments, so the
    case itself (and its positive label) is left as generated. Negative cases are sent as
    generated.
    """
    meta = case.meta
    if meta is None or meta.generation.mode.value != "positive":
        return
    operation = f"{case.method.upper()} {case.path}"
    if operation == COMPLETE and isinstance(case.body, dict):
        fields = {k: v for k, v in case.body.items() if k not in ("gray", "sparse", "returns")}
        as_returns = "returns" in case.body and "sparse" not in case.body
        frame = fuzz_frame(fields.get("depth_scale"), as_returns and "depth_scale" not in fields)
        kwargs["files"] = {name: (f"{name}.bin", data) for name, data in frame.items()}
        kwargs["data"] = {k: v if isinstance(v, str) else json.dumps(v) for k, v in fields.items()}
    elif operation == V2_INFER and isinstance(case.body, dict):
        body = {**case.body, "inputs": fuzz_inputs(binary=False)[0]}
        if body.get("outputs") is not None:
            once = {output["name"]: output for output in reversed(body["outputs"])}
            body["outputs"] = list(reversed(once.values())) or None
        kwargs["json"] = body
    elif operation == V2_INFER:  # the binary form: a JSON header, then the tensors' bytes
        inputs, binary = fuzz_inputs(binary=True)
        header = json.dumps({"inputs": inputs}).encode()
        kwargs["data"] = header + binary
        # (the transport takes headers from the case only; an undeclared header keeps it valid)
        case.headers = {**(case.headers or {}), "Inference-Header-Content-Length": str(len(header))}


def fuzz_api(url: str, max_examples: int, seed: int = 0) -> FuzzReport:
    """Run schemathesis (examples, coverage and fuzzing phases, every check) on every
    operation of the service at ``url``, from its /openapi.json; ``max_examples`` per
    operation and phase. Leaves nothing in the working directory."""
    import hypothesis.configuration
    import schemathesis
    from schemathesis.engine import events, from_schema
    from schemathesis.hooks import GLOBAL_HOOK_DISPATCHER

    config = schemathesis.Config.from_dict(
        {
            "seed": seed,
            "cache": {"enabled": False},
            "workers": 1,
            "continue-on-failure": True,
            "generation": {"max-examples": max_examples, "database": "none"},
        }
    )
    statuses: dict[str, dict[int | None, int]] = {}
    failures: list[str] = []
    start = time.monotonic()
    hook = schemathesis.hook("before_call")(real_files_for_valid_cases)
    try:
        with tempfile.TemporaryDirectory() as home:
            hypothesis.configuration.set_hypothesis_home_dir(home)
            schema = schemathesis.openapi.from_url(f"{url}/openapi.json", config=config)
            for event in from_schema(schema).execute():
                if isinstance(event, events.ScenarioFinished):
                    _record(event.recorder, statuses, failures)
                elif isinstance(event, events.NonFatalError | events.FatalError):
                    failures.append(f"- error: {event}")
    finally:
        GLOBAL_HOOK_DISPATCHER.unregister(hook)
    return FuzzReport(statuses, failures, time.monotonic() - start)


def _record(recorder, statuses: dict, failures: list[str]) -> None:
    counts = statuses.setdefault(recorder.label, {})
    for interaction in recorder.interactions.values():
        status = interaction.response.status_code if interaction.response else None
        counts[status] = counts.get(status, 0) + 1
    for checks in recorder.checks.values():
        for check in checks:
            if check.failure_info is not None:
                failure = check.failure_info.failure
                failures.append(
                    f"- {recorder.label}: {check.name}: {failure.title}: {failure.message}\n"
                    f"  {check.failure_info.code_sample}"
                )
