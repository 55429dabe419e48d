"""Real spacecraft: evaluation per spacecraft and a gallery a person reads at a glance.

The meshes (e.g. NASA's CAD models in ``shared/real-meshes``) are rendered by the same
generator, camera, LIDAR and scene ranges as the synthetic data, as a split of their own
(``sdc-data generate --models 0 --meshes DIR``). They are evaluation data only.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.scoring import Method, score_frame
from sdcnet.meshes import read_mesh_folder
from sdcnet.metrics import MetricTable, depth_table, frame_metrics, markdown_table
from sdcnet.pointcloud import back_project
from sdcnet.training.data.generate import GenerateConfig, generate
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
    depth, mask = method(sample)[:2]
    K = Intrinsics(**sample.meta["intrinsics"])
    window = object_crop(sample.mask | mask)
    valid = sample.depth[sample.mask]
    near, far = (float(valid.min()), float(valid.max())) if valid.size else (None, None)
    m = frame_metrics(depth, mask, sample.depth)
    sides = [labelled(side_view(back_project(depth, mask, K)), "completed, side")]
    for name, other in (others or {}).items():
        other_depth, other_mask = other(sample)[:2]
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


def render_real(meshes: str, data: Path, views: int, seed: int, workers: int) -> SampleStore:
    """The real meshes' frames at ``data`` (``views`` per mesh), rendered on the first call."""
    if not (data / "manifest.jsonl").exists():
        config = GenerateConfig(
            models=0, views=views, seed=seed, meshes=read_mesh_folder(meshes), split=(0, 0, 0)
        )
        generate(config, data, workers=workers)
    return SampleStore(data)


def evaluate_real(methods: dict[str, Method], store: SampleStore, out: Path) -> str:
    """Every method on the real split, overall and per spacecraft: ``out/real_spacecraft.md``,
    ``.json`` and ``gallery.png`` (drawn by the first method; the others' side views, the ONNX
    model's left out as the first's twin). Returns the markdown."""
    records = store.split("real")
    out.mkdir(parents=True, exist_ok=True)
    per_method = {
        name: evaluate_per_model(method, store, records) for name, method in methods.items()
    }
    overall = {name: tables["all"].mean() for name, tables in per_method.items()}
    lines = [
        f"Real spacecraft (never trained on): {len(records)} frames of "
        f"{len({r['model_name'] for r in records})} NASA models, rendered by `sdc-data` "
        f"({store.info['command']} --meshes ...), mean over images.",
        "",
        "### All spacecraft",
        "",
        markdown_table(overall),
        "",
        depth_table(overall),
        "",
    ]
    first = next(iter(per_method))
    for name in sorted(k for k in per_method[first] if k != "all"):
        rows = {method: tables[name].mean() for method, tables in per_method.items()}
        lines += [f"### {name}", "", markdown_table(rows), "", depth_table(rows), ""]
    (out / "real_spacecraft.md").write_text("\n".join(lines))
    (out / "real_spacecraft.json").write_text(
        json.dumps(
            {
                "title": "Real spacecraft (never trained on)",
                "split": "real",
                "images": len(records),
                "results": overall,
                "undefined": {n: t["all"].undefined() for n, t in per_method.items()},
            },
            indent=1,
        )
    )
    others = {
        name: method
        for name, method in methods.items()
        if name != first and not name.startswith("onnx:")  # the same model as the first
    }
    print(gallery(methods[first], store, records, out / "gallery.png", others))
    return "\n".join(lines)
