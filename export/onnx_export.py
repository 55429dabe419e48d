"""Trace SDCNet (pre-fill + FSNet + FDCNet) to one self-contained ONNX graph, and check it.

The parity check runs onnxruntime (CPU) against PyTorch on real generated frames at two sizes
and batch 1 and 2, and fails the export when depth differs by more than 1 mm anywhere on the
foreground, sigma by more than 0.1 %, or the foreground decisions agree on fewer than 99.99 %
of pixels. Sigma's depth-edge term reads the foreground decisions around each pixel, so where
the two runtimes round a probability of 0.5 to opposite sides (a float's last bits) the sigma
of the pixels within that term's window differs by design; sigma is compared on the pixels
both call foreground with no disagreement within the window.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import onnx
import torch

from sdcnet import __version__
from sdcnet.pipeline import WORK_PIXELS
from sdcnet.runtime.interface import INPUTS, OUTPUTS, metadata_props
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.training.model.sdcnet import SPREAD_WINDOW, SDCNet

OPSET = 17
MAX_DEPTH_ERROR_M = 1e-3
MIN_MASK_AGREEMENT = 0.9999
MAX_SIGMA_ERROR = 1e-3  # relative


def network_metadata_props(
    model: SDCNet, version: str, metrics: dict | None = None, extra: dict | None = None
) -> dict:
    """The metadata_props of network ``model``'s ONNX file: ``metadata_props`` (all the
    service needs besides the graph) and the architecture (``model_config``) it was exported
    from."""
    return metadata_props(
        version,
        model.config.stride,
        model.config.factor,
        WORK_PIXELS,
        metrics,
        {"model_config": json.dumps(model.config.to_dict()), **(extra or {})},
    )


def export_onnx(model: SDCNet, path: str | Path, metadata: dict[str, str]) -> Path:
    """Write ``model`` as ONNX with dynamic batch, height and width; checked by onnx.checker."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model = model.eval().cpu()
    example = (torch.rand(1, 1, 256, 256), torch.zeros(1, 1, 256, 256), torch.ones(1, 1, 1, 1))
    dynamic = {name: {0: "batch", 2: "height", 3: "width"} for name in (*INPUTS, *OUTPUTS)}
    dynamic["focal_px"] = {0: "batch"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notices
        torch.onnx.export(
            model,
            example,
            str(path),
            input_names=list(INPUTS),
            output_names=list(OUTPUTS),
            dynamic_axes=dynamic,
            opset_version=OPSET,
            dynamo=False,
            do_constant_folding=True,
        )
    graph = onnx.load(str(path))
    graph.producer_name = "sdcnet"
    graph.producer_version = __version__
    del graph.metadata_props[:]
    for key, value in sorted(metadata.items()):
        graph.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(graph, full_check=True)
    onnx.save(graph, str(path))
    return path


@dataclass
class ParityCase:
    """One comparison: ``size`` x ``size`` crops, ``batch`` of them; depth (metres) compared on
    the ``compared_px`` pixels that either runtime calls foreground, sigma (relative) on those
    both call foreground away from any pixel they disagree on (``compare_outputs``)."""

    size: int
    batch: int
    max_depth_error_m: float
    mask_agreement: float
    compared_px: int
    max_sigma_error: float = 0.0  # relative

    @property
    def passed(self) -> bool:
        return (
            self.max_depth_error_m <= MAX_DEPTH_ERROR_M
            and self.mask_agreement >= MIN_MASK_AGREEMENT
            and self.max_sigma_error <= MAX_SIGMA_ERROR
        )


#: One parity or calibration frame: gray uint8 (H, W), sparse float32 (H, W) metres, fx pixels.
Frame = tuple[np.ndarray, np.ndarray, float]


def parity_check(
    model: SDCNet,
    onnx_path: str | Path,
    frames: list[Frame],
    sizes: tuple[int, ...] = (512, 1024),
    batches: tuple[int, ...] = (1, 2),
) -> list[ParityCase]:
    """Compare onnxruntime (CPU) with PyTorch on frames centre-cropped to each size. Needs at
    least max(batches) frames."""
    session = OnnxModel(onnx_path, provider="CPUExecutionProvider")
    model = model.eval().cpu()
    cases = []
    for size in sizes:
        for batch in batches:
            chosen = frames[:batch]
            gray = np.stack([_centre(g, size) for g, _, _ in chosen])[:, None] / np.float32(255)
            sparse = np.stack([_centre(s, size) for _, s, _ in chosen])[:, None]
            focal = np.array([f for _, _, f in chosen], np.float32).reshape(-1, 1, 1, 1)
            inputs = (gray.astype(np.float32), sparse.astype(np.float32), focal)
            with torch.no_grad():
                reference = [t.numpy() for t in model(*map(torch.from_numpy, inputs))]
            cases.append(compare_outputs(size, batch, reference, session.run(*inputs)))
    return cases


Outputs = tuple[np.ndarray, np.ndarray, np.ndarray]  # depth (m), probability, sigma (m)


def compare_outputs(size: int, batch: int, reference: Outputs, candidate: Outputs) -> ParityCase:
    """One parity case from the two runtimes' outputs, each (B, 1, H, W). Depth does not read
    the mask: compared wherever either calls foreground. Sigma's depth-edge term reads the
    foreground decisions within ``SPREAD_WINDOW``: compared where both call foreground and agree
    on every pixel of the window around it."""
    ref_depth, ref_prob, ref_sigma = reference
    depth, prob, sigma = candidate
    ref_foreground, foreground = ref_prob > 0.5, prob > 0.5
    depth_error = np.abs(depth - ref_depth)[ref_foreground | foreground]
    disagree = (ref_foreground != foreground)[:, 0].astype(np.uint8)
    window = np.ones((SPREAD_WINDOW, SPREAD_WINDOW), np.uint8)
    near_disagreement = np.stack([cv2.dilate(d, window) for d in disagree])[:, None] > 0
    steady = ref_foreground & foreground & ~near_disagreement
    sigma_error = np.abs(sigma - ref_sigma)[steady] / np.maximum(ref_sigma[steady], 1e-6)
    return ParityCase(
        size,
        batch,
        float(depth_error.max()) if depth_error.size else 0.0,
        float(np.mean(foreground == ref_foreground)),
        int(depth_error.size),
        float(sigma_error.max()) if sigma_error.size else 0.0,
    )


def export_checked(
    model: SDCNet,
    out: Path,
    metadata: dict[str, str],
    frames: list[Frame],
) -> list[ParityCase]:
    """Export ``model`` to a temporary file beside ``out``, check its parity on ``frames``, and
    only when every case passes move it to ``out`` (one rename): ``out`` never holds a graph
    that failed, and a failed or interrupted export leaves it as it was."""
    staged = out.with_name(f".{out.name}.unchecked")
    try:
        export_onnx(model, staged, metadata)
        cases = parity_check(model, staged, frames)
        if all(c.passed for c in cases):
            os.replace(staged, out)
        return cases
    finally:
        staged.unlink(missing_ok=True)


def _centre(image: np.ndarray, size: int) -> np.ndarray:
    H, W = image.shape
    if size > min(H, W):
        raise ValueError(f"parity size {size} exceeds the {H} x {W} frames")
    y, x = (H - size) // 2, (W - size) // 2
    return image[y : y + size, x : x + size]
