"""Evaluation on a split with the paper's metrics, through PyTorch or the exported ONNX model.

Every method runs through ``sdcnet.pipeline.complete`` on whole 1024 x 1024 frames, exactly as
the service does: crop to the LIDAR-bounded region, infer, paste back.
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from torch.nn import functional as F
from tqdm import tqdm

from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import Sample, SampleStore
from sdcnet.metrics import MASK_NAMES, MetricTable, frame_report
from sdcnet.pipeline import ModelFn, complete
from sdcnet.training.model.prefill import MorphologicalPrefill, near_wins_downsample
from sdcnet.training.model.sdcnet import SDCNet


def torch_model_fn(model: torch.nn.Module, device: torch.device | str = "cpu") -> ModelFn:
    """Wrap a (gray, sparse) -> (depth, probability) module as a numpy callable."""
    model = model.eval().to(device)

    @torch.no_grad()
    def run(gray: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        depth, prob = model(torch.from_numpy(gray).to(device), torch.from_numpy(sparse).to(device))
        return depth.cpu().numpy(), prob.cpu().numpy()

    return run


def torch_segmentation_fn(model: SDCNet, device: torch.device | str = "cpu") -> ModelFn:
    """Only the foreground path of ``model`` (depth left at 0): for segmentation-only
    checkpoints (stage 1 alone, e.g. the FSNet input ablation) and at a fraction of the cost."""
    model = model.eval().to(device)

    @torch.no_grad()
    def run(gray: np.ndarray, sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        prob = model.segment(torch.from_numpy(gray).to(device), torch.from_numpy(sparse).to(device))
        return np.zeros_like(gray), prob.cpu().numpy()

    return run


def mask_metrics_only(means: dict[str, float]) -> dict[str, float]:
    """``means`` of a ``torch_segmentation_fn`` run with its depth metrics set to NaN: it
    regressed no depth, so only the mask's (IOU, IOI, specks) mean anything."""
    return {k: v if k in (*MASK_NAMES, "specks") else float("nan") for k, v in means.items()}


class ClassicalFill(torch.nn.Module):
    """The floor: the network's own morphological pre-fill alone, mask = filled pixels.

    Same working resolution and kernels as inside SDCNet; nearest upsampling back.
    """

    def __init__(self, factor: int = 4):
        super().__init__()
        self.factor = factor
        self.stride = factor  # crops need only be whole working pixels
        self.prefill = MorphologicalPrefill()

    def forward(
        self, gray: torch.Tensor, sparse: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        H, W = sparse.shape[-2:]
        f = self.factor
        padded = F.pad(sparse, (0, (f - W % f) % f, 0, (f - H % f) % f))
        filled = self.prefill(near_wins_downsample(padded, f))
        depth = F.interpolate(filled, scale_factor=f, mode="nearest")[..., :H, :W]
        return depth, (depth > 0).to(depth.dtype)


@functools.cache
def classical_fill() -> tuple[ModelFn, int]:
    """The classical fill as a pipeline model, and its stride: the reference every depth
    metric beyond the paper's compares against on the same frame."""
    fill = ClassicalFill()
    return torch_model_fn(fill), fill.stride


def score_frame(model_fn: ModelFn, sample: Sample, stride: int) -> dict[str, float]:
    """Every metric of ``sdcnet.metrics.frame_report`` for one frame, the classical fill of
    the same frame as the reference."""
    result = complete(model_fn, sample.gray, sample.sparse, stride=stride)
    fill_fn, fill_stride = classical_fill()
    fill = complete(fill_fn, sample.gray, sample.sparse, stride=fill_stride)
    return frame_report(
        result.depth,
        result.mask,
        fill.depth,
        fill.mask,
        sample.depth,
        sample.sparse,
        Intrinsics(**sample.meta["intrinsics"]),
    )


def evaluate_records(
    model_fn: ModelFn,
    store: SampleStore,
    records: list[dict],
    stride: int,
    progress: bool = True,
    desc: str = "evaluate",
) -> MetricTable:
    """Per-image metrics of ``model_fn`` over ``records`` of ``store`` (``score_frame``)."""
    table = MetricTable()
    for record in tqdm(records, desc=desc, unit="img", disable=not progress, leave=False):
        table.add(score_frame(model_fn, store.load(record), stride))
    return table
