"""The exported model under onnxruntime: sessions, providers, metadata. No torch.

Used by the service, the evaluation of exported files and the benchmarks.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import onnxruntime as ort

from sdcnet import __version__
from sdcnet.camera import PAPER_CAMERA, Intrinsics
from sdcnet.pipeline import WORK_PIXELS

INPUTS = ("gray", "sparse", "focal_px")
OUTPUTS = ("depth", "foreground", "sigma")
#: What each tensor holds, in the file's metadata (``/model`` shows it).
TENSORS = {
    "gray": "float32 (B, 1, H, W) in [0, 1]: 8-bit / 255 or 16-bit / 65535",
    "sparse": "float32 (B, 1, H, W) LIDAR camera-frame Z in metres, 0 = no return",
    "focal_px": "float32 (B, 1, 1, 1) focal length in pixels of the grid gray and sparse are on",
    "depth": "float32 (B, 1, H, W) camera-frame Z, metres (valid on the foreground)",
    "foreground": "float32 (B, 1, H, W) probability that a pixel is spacecraft",
    "sigma": "float32 (B, 1, H, W) the depth's uncertainty, metres: |error| <= sigma for 68 %",
}
PREFERRED_PROVIDERS = ("CUDAExecutionProvider", "CPUExecutionProvider")
#: Session option: whether idle intra-op threads spin-wait for work ("1") or sleep ("0").
SPIN_WAIT = "session.intra_op.allow_spinning"


class ModelLoadError(RuntimeError):
    """The model file is missing, unreadable, not ONNX, or not an sdcnet model."""


def metadata_props(
    version: str,
    stride: int,
    factor: int = 1,
    work_pixels: int = WORK_PIXELS,
    metrics: dict | None = None,
    extra: dict[str, str] | None = None,
) -> dict[str, str]:
    """The metadata_props an sdcnet ONNX file carries: what ``OnnxModel`` reads (version, the
    default camera's intrinsics (the paper's), the input ``stride`` in pixels, the ``factor``
    of its internal resolution, the ``work_pixels`` per frame it was trained and timed for)
    and what ``/model`` shows (metrics, tensors)."""
    meta = {
        "sdcnet_version": __version__,
        "model_version": version,
        "intrinsics": json.dumps(PAPER_CAMERA.intrinsics().as_dict()),
        "stride": str(stride),
        "factor": str(factor),
        "work_pixels": str(work_pixels),
        "metrics": json.dumps(metrics or {}),
        "inputs": json.dumps({name: TENSORS[name] for name in INPUTS}),
        "outputs": json.dumps({name: TENSORS[name] for name in OUTPUTS}),
    }
    meta.update(extra or {})
    return meta


def provider_name(requested: str) -> str:
    """onnxruntime's name of an execution provider given in short ("cpu", "cuda",
    "tensorrt", "openvino") or in full ("TensorrtExecutionProvider"), in any case; a name
    onnxruntime does not know comes back as given."""
    key = requested.strip().lower().removesuffix("executionprovider")
    known = {
        name.lower().removesuffix("executionprovider"): name for name in ort.get_all_providers()
    }
    return known.get(key, requested)


def choose_providers(requested: str | None = None) -> list[str]:
    """Execution providers to use: ``requested`` alone (``provider_name``; it must be
    available here), else CUDA then CPU."""
    available = ort.get_available_providers()
    if requested:
        name = provider_name(requested)
        if name not in available:
            raise ModelLoadError(
                f"execution provider {requested!r} is not available here; available: {available}"
            )
        return [name]
    return [p for p in PREFERRED_PROVIDERS if p in available]


@dataclass(frozen=True)
class ModelInfo:
    """What the ONNX file says about itself (its metadata_props)."""

    version: str
    intrinsics: Intrinsics
    stride: int
    factor: int
    work_pixels: int
    metrics: dict
    raw: dict[str, str]


def _info(session: ort.InferenceSession, path: Path) -> ModelInfo:
    meta = session.get_modelmeta().custom_metadata_map
    missing = {"sdcnet_version", "intrinsics", "stride"} - set(meta)
    if missing:
        raise ModelLoadError(f"{path} is not an sdcnet model: metadata lacks {sorted(missing)}")
    names = (
        tuple(i.name for i in session.get_inputs()),
        tuple(o.name for o in session.get_outputs()),
    )
    if names != (INPUTS, OUTPUTS):
        raise ModelLoadError(f"{path} has inputs/outputs {names}, expected {(INPUTS, OUTPUTS)}")
    return ModelInfo(
        version=meta.get("model_version", meta["sdcnet_version"]),
        intrinsics=Intrinsics(**json.loads(meta["intrinsics"])),
        stride=int(meta["stride"]),
        factor=int(meta.get("factor", 1)),
        work_pixels=int(meta.get("work_pixels", WORK_PIXELS)),
        metrics=json.loads(meta.get("metrics", "{}")),
        raw=dict(meta),
    )


class Runtime(Protocol):
    """An sdcnet model loaded under an inference runtime, as the service uses it: ``run`` is
    the pipeline's model callable, ``info`` what the file says about itself, ``provider``
    where it runs, ``threads`` its intra-op threads, ``platform`` the runtime and file format
    in KServe's words (``onnxruntime_onnx``, ``tensorrt_plan``, ``openvino``...)."""

    path: Path
    info: ModelInfo
    provider: str
    threads: int
    platform: str

    @property
    def stride(self) -> int:
        """Pixels the input's height and width must be multiples of."""
        ...

    def run(
        self, gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(B, 1, h, w) float32 gray in [0, 1] and sparse metres, (B, 1, 1, 1) focal length in
        pixels -> depth (m), probability, sigma (m)."""
        ...


class OnnxModel:
    """An sdcnet ONNX model loaded once under onnxruntime (a ``Runtime``); ``run`` is the
    pipeline's model callable."""

    platform = "onnxruntime_onnx"

    def __init__(
        self,
        path: str | Path,
        provider: str | None = None,
        threads: int | None = None,
        spin_wait: bool = True,
    ):
        """``spin_wait``: onnxruntime's idle intra-op threads spin (its default) rather than
        sleep; the service turns it off (``sdcnet.service.settings.Settings.spin_wait``)."""
        path = Path(path)
        if not path.is_file():
            raise ModelLoadError(f"model file not found: {path}")
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads or len(os.sched_getaffinity(0))
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.add_session_config_entry(SPIN_WAIT, "1" if spin_wait else "0")
        # onnxruntime's CPU arena keeps what the largest inference grew; the pipeline feeds
        # every frame at a fixed budget of working pixels, so that is one frame's activations,
        # reused by the next frame. Without the arena glibc keeps the freed blocks instead, and
        # shrinking it after every run costs time: both hold more memory, not less
        # (docs/development.md, "Measurements").
        options.enable_cpu_mem_arena = True
        try:
            self.session = ort.InferenceSession(
                str(path), options, providers=choose_providers(provider)
            )
        except ModelLoadError:
            raise
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise ModelLoadError(f"cannot load {path} as an ONNX model: {exc}") from exc
        self.path = path
        self.info = _info(self.session, path)
        self.provider = self.session.get_providers()[0]
        self.threads = options.intra_op_num_threads

    @property
    def stride(self) -> int:
        """Pixels the input's height and width must be multiples of."""
        return self.info.stride

    def run(
        self, gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(B, 1, h, w) float32 gray in [0, 1] and sparse metres, (B, 1, 1, 1) focal length in
        pixels -> depth (m), probability, sigma (m): the pipeline's model callable."""
        feeds = {"gray": gray, "sparse": sparse, "focal_px": focal_px}
        depth, prob, sigma = self.session.run(list(OUTPUTS), feeds)
        return depth, prob, sigma
