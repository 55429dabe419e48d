"""Real spacecraft: evaluation per spacecraft and a gallery a person reads at a glance.

The meshes (e.g. NASA's CAD models in ``shared/real-meshes``) are rendered by the same
generator, camera, LIDAR and scene ranges as the synthetic data, as a split of their own
(``sdc-data generate --models 0 --meshes DIR``). They are evaluation data only.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore
from sdcnet.metrics import MetricTable, frame_metrics
from sdcnet.pipeline import ModelFn, complete
from sdcnet.pointcloud import back_project
from sdcnet.training.evaluate import score_frame
from sdcnet.visualize import (
    colorize_depth,
    dilated_returns,
    gray_bgr,
    labelled,
    montage,
    object_crop,
    side_view,
)


def evaluate_per_model(
    model_fn: ModelFn, store: SampleStore, records: list[dict], stride: int
) -> dict[str, MetricTable]:
    """Metric tables per spacecraft name, plus 'all'."""
    tables: dict[str, MetricTable] = defaultdict(MetricTable)
    for record in records:
        metrics = score_frame(model_fn, store.load(record), stride)
        tables[record["model_name"]].add(metrics)
        tables["all"].add(metrics)
    return dict(tables)


def error_map(pred: np.ndarray, mask: np.ndarray, gt: np.ndarray, alpha: float = 1.0) -> np.ndarray:
    """BGR: |error| on predicted ∩ true foreground from black (0) to white (>= alpha metres);
    false foreground in red, missed foreground in blue."""
    A, P = gt > 0, mask
    out = np.zeros((*gt.shape, 3), np.uint8)
    both = A & P
    level = (np.clip(np.abs(pred - gt) / alpha, 0, 1) * 255).astype(np.uint8)
    out[both] = cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)[both]
    out[P & ~A] = (0, 0, 255)
    out[A & ~P] = (255, 80, 0)
    return out


def gallery_row(
    model_fn: ModelFn,
    sample,
    stride: int,
    caption: str,
    others: dict[str, tuple[ModelFn, int]] | None = None,
) -> list[np.ndarray]:
    """gray | LIDAR returns | predicted depth | ground truth | error map | side views of the
    completed cloud, of each of ``others``' clouds (name -> model, stride) and of the true one:
    where a flat panel comes out flat, and where it ripples between scan lines."""
    result = complete(model_fn, sample.gray, sample.sparse, stride=stride)
    K = Intrinsics(**sample.meta["intrinsics"])
    window = object_crop(sample.mask | result.mask)
    valid = sample.depth[sample.mask]
    near, far = (float(valid.min()), float(valid.max())) if valid.size else (None, None)
    m = frame_metrics(result.depth, result.mask, sample.depth)
    sides = [labelled(side_view(back_project(result.depth, result.mask, K)), "completed, side")]
    for name, (fn, other_stride) in (others or {}).items():
        other = complete(fn, sample.gray, sample.sparse, stride=other_stride)
        sides.append(labelled(side_view(back_project(other.depth, other.mask, K)), f"{name}, side"))
    sides.append(labelled(side_view(back_project(sample.depth, sample.mask, K)), "true, side"))
    return [
        labelled(gray_bgr(sample.gray)[window], caption),
        labelled(
            dilated_returns(sample.sparse, 4, near, far)[window],
            f"{sample.meta['returns']} returns",
        ),
        labelled(
            colorize_depth(result.depth, near, far)[window],
            f"predicted, IOU {100 * m['IOU']:.0f} %",
        ),
        labelled(colorize_depth(sample.depth, near, far)[window], "ground truth"),
        labelled(
            error_map(result.depth, result.mask, sample.depth)[window], f"MAEI {m['MAEI']:.2f} m"
        ),
        *sides,
    ]


def gallery(
    model_fn: ModelFn,
    store: SampleStore,
    records: list[dict],
    stride: int,
    out: Path,
    others: dict[str, tuple[ModelFn, int]] | None = None,
) -> Path:
    """One row per spacecraft (its first view in ``records``); ``others`` add side views."""
    first: dict[str, dict] = {}
    for record in records:
        first.setdefault(record["model_name"], record)
    rows = [
        gallery_row(model_fn, store.load(r), stride, f"{name} {r['distance_m']:.0f} m", others)
        for name, r in first.items()
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), montage(rows, tile=256))
    return out
