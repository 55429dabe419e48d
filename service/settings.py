"""Service settings: environment variables ``SDCNET_*``, overridden by ``sdc-serve`` flags."""

from __future__ import annotations

import math
import os
from importlib import resources
from pathlib import Path
from typing import Literal

from fastapi import Request
from pydantic import Field, ValidationInfo, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from sdcnet.frame_budget import WINDOW_FRAMES
from sdcnet.pointcloud import MAX_POINTS
from sdcnet.runtime.registry import DEFAULT_RUNTIME, RUNTIMES

#: Largest image accepted by default (width x height, pixels).
MAX_PIXELS = 2048 * 2048


def shipped_model_path() -> Path:
    """The model installed with the package: ``sdcnet/models/sdcnet.onnx``."""
    return Path(str(resources.files("sdcnet.models") / "sdcnet.onnx"))


def available_cpus() -> int:
    """CPUs this process may use: its affinity, capped by a cgroup CPU quota (containers)."""
    cpus = len(os.sched_getaffinity(0))
    try:  # cgroup v2: "<quota> <period>" or "max <period>"
        quota, period = Path("/sys/fs/cgroup/cpu.max").read_text().split()
        if quota != "max":
            cpus = min(cpus, math.ceil(int(quota) / int(period)))
    except (OSError, ValueError):
        pass
    return max(cpus, 1)


class Settings(BaseSettings):
    """Everything an operator sets. Each field is read from ``SDCNET_<NAME>``."""

    model_config = SettingsConfigDict(env_prefix="SDCNET_", protected_namespaces=())

    model_path: Path = Field(
        default_factory=shipped_model_path, description="ONNX model file (default: shipped)"
    )
    runtime: str = Field(
        default=DEFAULT_RUNTIME,
        description=f"the inference runtime that runs the model: {', '.join(sorted(RUNTIMES))}",
    )
    provider: str | None = Field(
        default=None,
        description="where the runtime runs the model; onnxruntime's execution provider, short "
        "('cpu', 'cuda', 'tensorrt', 'openvino') or in full ('TensorrtExecutionProvider'); "
        "default: CUDA when onnxruntime-gpu and a GPU are present, else CPU",
    )
    threads: int = Field(
        default_factory=available_cpus,
        ge=1,
        description="the runtime's intra-op threads (default: the CPUs this process may use)",
    )
    spin_wait: bool = Field(
        default=False,
        description="let onnxruntime's idle threads spin-wait for work; off: they sleep and "
        "leave the CPUs to the request's own decoding, encoding and HTTP, and to the other "
        "processes of a shared machine or a CPU quota",
    )
    frame_ms: float = Field(
        default=100.0,
        ge=0,
        description="milliseconds a frame's in-process answer (the pipeline, its cloud and "
        "normals) is held to at p95; at start-up the service times its CPU on a reference "
        "frame and gives frames fewer working pixels than the model's where this CPU is too "
        "slow for it (down to half: sdcnet.frame_budget, GET /model's frame_budget), and "
        "re-reads it from the frames served (budget_window); 0: the model's own budget, "
        "unmeasured. The LIDAR's period: 100 ms at 10 Hz",
    )
    budget_window: int = Field(
        default=WINDOW_FRAMES,
        ge=0,
        description="served frames the share of their budget is re-read from: every quarter "
        "of this many, the p95 of the latest frames' in-process milliseconds chooses it again, "
        "so that it follows this machine's speed and the frames it is sent "
        "(sdcnet.frame_budget.ServedBudget); 0: the start-up measurement holds",
    )
    work_pixels: int | None = Field(
        default=None,
        ge=1,
        description="working pixels a frame gets at most, fixed (at most the model's own); "
        "overrides frame_ms; default: frame_ms's measurement",
    )
    targets: Path | None = Field(
        default=None,
        description="folder of known targets' meshes (STL, OBJ, PLY, glTF/GLB) with a "
        "manifest.json of {file, longest_m} entries, for POST /pose; default: none",
    )
    camera: Path | None = Field(
        default=None,
        description="the camera's calibration file (OpenCV YAML/JSON/XML, ROS camera_info, or "
        "JSON of fx, fy, cx, cy, width, height): the intrinsics requests default to, and the "
        "lens distortion taken out of every frame; default: none, the model's camera",
    )
    host: str = Field(default="127.0.0.1", description="address to bind")
    port: int = Field(default=8000, ge=0, le=65535, description="TCP port (0: any free port)")
    max_in_flight: int = Field(
        default=2,
        ge=1,
        description="inference requests (POST /complete, v2 infer, POST /pose together) "
        "decoded, completed and encoded at once, each within the memory budget; a received "
        "request waits queue_timeout_s at most for a place, then gets 503 with Retry-After",
    )
    max_requests: int = Field(
        default=16,
        ge=1,
        description="inference requests held at once in every phase (receiving their body, "
        "waiting, in flight, sending their answer); more get 503 at once",
    )
    queue_timeout_s: float = Field(
        default=0.25,
        gt=0,
        description="seconds a received request waits for an in-flight place before 503 "
        "(shed early rather than answer late)",
    )
    retry_after_s: int = Field(
        default=1, ge=0, description="Retry-After seconds advertised on 503 answers"
    )
    max_pixels: int = Field(
        default=MAX_PIXELS,
        ge=1,
        description="largest image (width x height) accepted: with max_upload_bytes, what "
        "bounds a request's memory (docs/service.md, the memory budget)",
    )
    max_points: int = Field(
        default=MAX_POINTS,
        ge=1,
        description="points a cloud holds at most: a larger mask's cloud takes every k-th "
        "pixel of its rows and columns, k as small as fits (the answer's cloud_stride), so "
        "that its cost and size stay within a frame's budget; depth, mask and sigma stay whole",
    )
    max_returns: int = Field(
        default=2**20,
        ge=1,
        description="most LIDAR returns a list (returns field, v2 returns input) may hold, "
        "counted before it is parsed; never more than the frame's pixels",
    )
    max_upload_bytes: int = Field(
        default=64 * 2**20, ge=1, description="largest request body (bytes) accepted"
    )
    body_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="seconds a request body may stall between two chunks before 408; also "
        "the start-up allowance of min_rate, for bodies and answers",
    )
    min_rate: float = Field(
        default=1 * 2**20,
        gt=0,
        description="bytes/s an inference request's body, and its answer, must average once "
        "their first body_timeout_s are over: a slower upload gets 408, a slower reader is "
        "disconnected",
    )
    request_timeout_s: float = Field(
        default=120.0,
        gt=0,
        description="seconds an inference request may take from its head to the last byte of "
        "its answer",
    )
    head_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="seconds a connection has to send a complete request head, from its "
        "opening or its previous answer; then it is closed (slowloris)",
    )
    keep_alive_s: int = Field(
        default=5,
        ge=1,
        description="seconds an idle keep-alive connection is kept after an answer "
        "(uvicorn's timeout_keep_alive)",
    )
    log_level: Literal["critical", "error", "warning", "info", "debug"] = Field(
        default="info", description="critical, error, warning, info or debug"
    )

    @field_validator("runtime")
    @classmethod
    def _a_known_runtime(cls, value: str) -> str:
        if value not in RUNTIMES:
            raise ValueError(f"not a runtime here; the runtimes are {sorted(RUNTIMES)}")
        return value

    @field_validator("max_requests")
    @classmethod
    def _holds_those_in_flight(cls, value: int, info: ValidationInfo) -> int:
        in_flight = info.data.get("max_in_flight", 1)
        if value < in_flight:
            raise ValueError(f"must be at least max_in_flight ({in_flight}): it counts them too")
        return value


async def get_settings(request: Request) -> Settings:
    """FastAPI dependency: the settings the application was created with."""
    return request.app.state.settings
