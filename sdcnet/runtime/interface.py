"""What every inference runtime of an sdcnet model shares, importing none of them: the
tensors, the metadata the model file carries (``metadata_props``, read back as ``ModelInfo``)
and the ``Runtime`` the service runs, so that a runtime, the export and the service's code
typed against it need no onnxruntime."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

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
#: Metadata keys without which a file is not an sdcnet model.
REQUIRED_METADATA = ("sdcnet_version", "intrinsics", "stride")


class ModelLoadError(RuntimeError):
    """The model file is missing, unreadable, not a model the runtime takes, or not an sdcnet
    model."""


def metadata_props(
    version: str,
    stride: int,
    factor: int = 1,
    work_pixels: int = WORK_PIXELS,
    metrics: dict | None = None,
    extra: dict[str, str] | None = None,
) -> dict[str, str]:
    """The metadata_props an sdcnet model file carries: what ``ModelInfo`` reads (version, the
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


@dataclass(frozen=True)
class ModelInfo:
    """What the model file says about itself (its metadata_props)."""

    version: str
    intrinsics: Intrinsics
    stride: int
    factor: int
    work_pixels: int
    metrics: dict
    raw: dict[str, str]

    @classmethod
    def from_metadata(cls, meta: dict[str, str], path: Path) -> ModelInfo:
        """The info in a model file's metadata (``metadata_props``, however the runtime reads
        them), ``path`` the file's; ``ModelLoadError`` when it is not an sdcnet model's or does
        not parse, so that every runtime refuses such a file alike."""
        missing = set(REQUIRED_METADATA) - set(meta)
        if missing:
            raise ModelLoadError(f"{path} is not an sdcnet model: metadata lacks {sorted(missing)}")
        try:
            return cls(
                version=meta.get("model_version", meta["sdcnet_version"]),
                intrinsics=Intrinsics(**json.loads(meta["intrinsics"])),
                stride=int(meta["stride"]),
                factor=int(meta.get("factor", 1)),
                work_pixels=int(meta.get("work_pixels", WORK_PIXELS)),
                metrics=json.loads(meta.get("metrics", "{}")),
                raw=dict(meta),
            )
        except (ValueError, TypeError, KeyError) as exc:
            raise ModelLoadError(
                f"{path} is not a usable sdcnet model: its metadata does not parse "
                f"({type(exc).__name__}: {exc})"
            ) from exc


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


class Loader(Protocol):
    """What loads a model file under one runtime (``sdcnet.runtime.registry.RUNTIMES``): the
    service's settings ``provider`` (where it runs, in the runtime's words; ``None``: its
    default), ``threads`` (intra-op; ``None``: the CPUs this process may use) and
    ``spin_wait`` (idle threads spin rather than sleep, where the runtime can). Raises
    ``ModelLoadError`` for a file it cannot serve."""

    def __call__(
        self, path: str | Path, provider: str | None, threads: int | None, spin_wait: bool
    ) -> Runtime: ...
