"""The exported model under onnxruntime (``OnnxModel``, the runtime ``onnxruntime``):
sessions, execution providers."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import onnxruntime as ort

from sdcnet.runtime.interface import INPUTS, OUTPUTS, ModelInfo, ModelLoadError

PREFERRED_PROVIDERS = ("CUDAExecutionProvider", "CPUExecutionProvider")
#: Session option: whether idle intra-op threads spin-wait for work ("1") or sleep ("0").
SPIN_WAIT = "session.intra_op.allow_spinning"


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


class OnnxModel:
    """An sdcnet ONNX model loaded once under onnxruntime: a ``Runtime``, and its ``Loader``
    (``sdcnet.runtime.registry``); ``run`` is the pipeline's model callable."""

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
        options = self.session_options(threads or len(os.sched_getaffinity(0)), spin_wait)
        try:
            self.session = ort.InferenceSession(
                str(path), options, providers=choose_providers(provider)
            )
        except ModelLoadError:
            raise
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise ModelLoadError(f"cannot load {path} as an ONNX model: {exc}") from exc
        self.path = path
        self.info = ModelInfo.from_metadata(self.session.get_modelmeta().custom_metadata_map, path)
        names = (
            tuple(i.name for i in self.session.get_inputs()),
            tuple(o.name for o in self.session.get_outputs()),
        )
        if names != (INPUTS, OUTPUTS):
            raise ModelLoadError(f"{path} has inputs/outputs {names}, expected {(INPUTS, OUTPUTS)}")
        self.provider = self.session.get_providers()[0]
        self.threads = options.intra_op_num_threads

    def session_options(self, threads: int, spin_wait: bool) -> ort.SessionOptions:
        """The session's options: ``threads`` intra-op threads, one inter-op, every graph
        optimisation, the CPU arena on; a variant of this runtime (other optimisations, a
        profiling session) overrides this rather than ``__init__``."""
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.add_session_config_entry(SPIN_WAIT, "1" if spin_wait else "0")
        # onnxruntime's CPU arena keeps what the largest inference grew; the pipeline feeds
        # every frame at a fixed budget of working pixels, so that is one frame's activations,
        # reused by the next frame. Without the arena glibc keeps the freed blocks instead, and
        # shrinking it after every run costs time: both hold more memory, not less
        # (docs/development.md, "Measurements").
        options.enable_cpu_mem_arena = True
        return options

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
