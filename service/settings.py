"""Service settings: environment variables ``SDCNET_*``, overridden by ``sdc-serve`` flags."""

from __future__ import annotations

import math
import os
from importlib import resources
from pathlib import Path
from typing import Literal

from fastapi import Request
from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict


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
    provider: str | None = Field(
        default=None,
        description="onnxruntime execution provider: 'cpu', 'cuda' or a full provider name; "
        "default: CUDA when onnxruntime-gpu and a GPU are present, else CPU",
    )
    threads: int = Field(
        default_factory=available_cpus,
        ge=1,
        description="onnxruntime intra-op threads (default: the CPUs this process may use)",
    )
    spin_wait: bool = Field(
        default=False,
        description="let onnxruntime's idle threads spin-wait for work; off: they sleep and "
        "leave the CPUs to the request's own decoding, encoding and HTTP, and to the other "
        "processes of a shared machine or a CPU quota",
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
        default=4,
        ge=1,
        description="POST /complete requests admitted at once; more get 503 with Retry-After",
    )
    retry_after_s: int = Field(
        default=1, ge=0, description="Retry-After seconds advertised on 503 answers"
    )
    max_pixels: int = Field(
        default=4096 * 4096, ge=1, description="largest image (width x height) accepted"
    )
    max_upload_bytes: int = Field(
        default=256 * 2**20, ge=1, description="largest request body (bytes) accepted"
    )
    body_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="seconds a request body may stall between two chunks before 408 (a "
        "stalled upload would otherwise hold one of the max_in_flight places for ever)",
    )
    log_level: Literal["critical", "error", "warning", "info", "debug"] = Field(
        default="info", description="critical, error, warning, info or debug"
    )


async def get_settings(request: Request) -> Settings:
    """FastAPI dependency: the settings the application was created with."""
    return request.app.state.settings
