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
from sdcnet.pointcloud import back_project
from sdcnet.training.evaluate import Method, score_frame
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
    method: Method, store: SampleStore, records: list[dict]
) -> dict[str, MetricTable]:
    """Metric tables per spacecraft name, plus 'all'."""
    tables: dict[str, MetricTable] = defaultdict(MetricTable)
    for record in records:
        metrics = score_frame(method, store.load(record))
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
    method: Method,
    sample,
    caption: str,
    others: dict[str, Method] | None = None,
) -> list[np.ndarray]:
    """gray | LIDAR returns | predicted depth | ground truth | error map | side views of the
    completed cloud, of each of ``others``' clouds (name -> method) and of the true one:
    where a flat panel comes out flat, and where it ripples between scan lines."""
    depth, mask, _ = method(sample)
    K = Intrinsics(**sample.meta["intrinsics"])
    window = object_crop(sample.mask | mask)
    valid = sample.depth[sample.mask]
    near, far = (float(valid.min()), float(valid.max())) if valid.size else (None, None)
    m = frame_metrics(depth, mask, sample.depth)
    sides = [labelled(side_view(back_project(depth, mask, K)), "completed, side")]
    for name, other in (others or {}).items():
        other_depth, other_mask, _ = other(sample)
        sides.append(labelled(side_view(back_project(other_depth, other_mask, K)), f"{name}, side"))
    sides.append(labelled(side_view(back_project(sample.depth, sample.mask, K)), "true, side"))
    return [
        labelled(gray_bgr(sample.gray)[window], caption),
        labelled(
            dilated_returns(sample.sparse, 4, near, far)[window],
            f"{sample.meta['returns']} returns",
        ),
        labelled(
            colorize_depth(depth, near, far)[window], f"predicted, IOU {100 * m['IOU']:.0f} %"
        ),
        labelled(colorize_depth(sample.depth, near, far)[window], "ground truth"),
        labelled(error_map(depth, mask, sample.depth)[window], f"MAEI {m['MAEI']:.2f} m"),
        *sides,
    ]


def gallery(
    method: Method,
    store: SampleStore,
    records: list[dict],
    out: Path,
    others: dict[str, Method] | None = None,
) -> Path:
    """One row per spacecraft (its first view in ``records``); ``others`` add side views."""
    first: dict[str, dict] = {}
    for record in records:
        first.setdefault(record["model_name"], record)
    rows = [
        gallery_row(method, store.load(r), f"{name} {r['distance_m']:.0f} m", others)
        for name, r in first.items()
    ]
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), montage(rows, tile=256))
    return out
