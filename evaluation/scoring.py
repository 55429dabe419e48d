"""The yardstick: a method's answers scored with the paper's metrics, through PyTorch or the
exported ONNX model. Training's validation scores with it too, so it imports nothing from
``sdcnet.training`` (``tests/test_imports.py`` checks).

Every method runs through ``sdcnet.pipeline.complete`` on whole frames, exactly as the service
does: crop to the LIDAR-bounded region, resample to the working grid, infer, paste back; the
classical fill (``classical_fill``) of each frame is the reference of the depth figures.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from tqdm import tqdm

from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import Sample, SampleStore
from sdcnet.evaluation.classical_fill import classical_fill
from sdcnet.metrics import MASK_NAMES, MetricTable, false_specks, frame_metrics, frame_report
from sdcnet.normals import normal_map
from sdcnet.pipeline import WORK_PIXELS, Completion, ModelFn, complete


def torch_model_fn(model: torch.nn.Module, device: torch.device | str = "cpu") -> ModelFn:
    """Wrap a (gray, sparse, focal_px) -> (depth, probability, sigma) module as a numpy
    callable."""
    model = model.eval().to(device)

    @torch.no_grad()
    def run(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
        inputs = (torch.from_numpy(a).to(device) for a in (gray, sparse, focal_px))
        return tuple(t.cpu().numpy() for t in model(*inputs))

    return run


def torch_segmentation_fn(model: torch.nn.Module, device: torch.device | str = "cpu") -> ModelFn:
    """Only the foreground path of ``model``, an ``SDCNet`` (depth left at 0): for segmentation-only
    checkpoints (stage 1 alone, e.g. the FSNet input ablation) and at a fraction of the cost."""
    model = model.eval().to(device)

    @torch.no_grad()
    def run(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
        inputs = (torch.from_numpy(a).to(device) for a in (gray, sparse, focal_px))
        return np.zeros_like(gray), model.segment(*inputs).cpu().numpy()

    return run


def mask_metrics_only(means: dict[str, float]) -> dict[str, float]:
    """``means`` of a ``torch_segmentation_fn`` run with its depth metrics set to NaN: it
    regressed no depth, so only the mask's (IOU, IOI, specks) mean anything."""
    return {k: v if k in (*MASK_NAMES, "specks") else float("nan") for k, v in means.items()}


class FrameAnswer(NamedTuple):
    """A method's answer on one frame: depth (H, W) float32 metres (0 off the mask), mask
    (H, W) bool, the depth's uncertainty sigma (H, W) float32 metres (None for a method without
    one) and, from the pipeline, its whole ``Completion``: the normals of its point cloud are
    scored from it (``sdcnet.normals``), those of other methods from their depth maps."""

    depth: np.ndarray
    mask: np.ndarray
    sigma: np.ndarray | None = None
    completion: Completion | None = None


#: One way to answer a frame: a network through the pipeline (``network``), the classical
#: fill or answers stored elsewhere.
Method = Callable[[Sample], FrameAnswer]


def network(model_fn: ModelFn, stride: int, work_pixels: int = WORK_PIXELS) -> Method:
    """A network as the service runs it: ``sdcnet.pipeline.complete`` on the whole frame."""

    def answer(sample: Sample) -> FrameAnswer:
        fx = float(sample.meta["intrinsics"]["fx"])
        result = complete(model_fn, sample.gray, sample.sparse, fx, stride, work_pixels)
        return FrameAnswer(result.depth, result.mask, result.sigma, result)

    return answer


#: The classical fill's name in every table and report.
FILL = "classical fill"


def classical(sample: Sample) -> FrameAnswer:
    """The classical morphological fill of the frame's returns (``classical_fill``)."""
    return FrameAnswer(*classical_fill(sample.sparse))


class StoredAnswers:
    """Answers made elsewhere (another version of sdcnet, another system): one
    ``<frame id>.npz`` per frame in ``folder`` with ``depth`` (metres), ``mask`` and the
    ``milliseconds`` it took (``benchmarks/previous_model.py`` writes them); scored like any
    method."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"no answers folder {self.folder}")

    def _load(self, sample: Sample) -> dict[str, np.ndarray]:
        path = self.folder / f"{sample.meta['id']}.npz"
        if not path.is_file():
            raise FileNotFoundError(f"{self.folder} holds no answer for frame {sample.meta['id']}")
        with np.load(path, allow_pickle=False) as answer:
            return {k: answer[k] for k in answer.files}

    def __call__(self, sample: Sample) -> FrameAnswer:
        answer = self._load(sample)
        sigma = answer["sigma"].astype(np.float32) if "sigma" in answer else None
        return FrameAnswer(answer["depth"].astype(np.float32), answer["mask"].astype(bool), sigma)

    def milliseconds(self, sample: Sample) -> float:
        """What the frame took where it was answered."""
        return float(self._load(sample)["milliseconds"])


def score_frame(method: Method, sample: Sample) -> dict[str, float]:
    """Every metric of ``sdcnet.metrics.frame_report`` for one frame, the classical fill of
    the same frame as the reference."""
    answer = method(sample)
    fill = classical(sample)
    K = Intrinsics(**sample.meta["intrinsics"])
    normals = None if answer.completion is None else normal_map(answer.completion, K)
    return frame_report(
        answer.depth,
        answer.mask,
        fill.depth,
        fill.mask,
        sample.depth,
        sample.sparse,
        K,
        answer.sigma,
        normals,
    )


def score_mask(method: Method, sample: Sample) -> dict[str, float]:
    """The paper's six metrics and the false specks of one frame, without the reports that
    need the classical fill, the normals or sigma: what a mask alone is judged by."""
    depth, mask = method(sample)[:2]
    report = frame_metrics(depth, mask, sample.depth)
    report["specks"] = float(false_specks(mask, sample.sparse, sample.depth))
    return report


def evaluate_records(
    method: Method,
    store: SampleStore,
    records: list[dict],
    progress: bool = True,
    desc: str = "evaluate",
    mask_only: bool = False,
) -> MetricTable:
    """Per-image metrics of ``method`` over ``records`` of ``store`` (``score_frame``, or
    ``score_mask`` when only the mask matters)."""
    score = score_mask if mask_only else score_frame
    table = MetricTable()
    for record in tqdm(records, desc=desc, unit="img", disable=not progress, leave=False):
        table.add(score(method, store.load(record)))
    return table
