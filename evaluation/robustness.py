"""The robustness suite (``sdc-eval robustness``): every condition users fly, model against fill.

Each condition of ``sdcnet.training.data.conditions.ROBUSTNESS`` pushes one factor away from
the paper's world (another renderer's way of drawing the paper's frames, the Earth or the Sun
behind the target, a wide camera with a rotating multi-beam LIDAR, a flash LIDAR, docking
range, a narrow camera far away, everything at once).
Its frames are rendered from spacecraft no model was trained on: the test split's procedural
models of the reference dataset and the real meshes (``shared/real-meshes``). Per condition
and method it reports the mask (IOU, false specks), the depth on the classical fill's pixels
by distance to the nearest return, the normals, and the cost of every frame in process (p50,
p95, max); and draws a gallery of a few frames per condition.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from sdcnet.dataset_format import Sample, SampleStore
from sdcnet.evaluation.real import gallery_row
from sdcnet.evaluation.scoring import (
    FILL,
    FrameAnswer,
    Method,
    StoredAnswers,
    classical,
    score_frame,
)
from sdcnet.meshes import MeshEntry
from sdcnet.metrics import BAND_NAMES, MetricTable
from sdcnet.training.data.conditions import ROBUSTNESS
from sdcnet.training.data.generate import GenerateConfig, generate
from sdcnet.visualize import montage

#: The splits a condition's frames come from: never trained on.
UNSEEN = ("test", "real")


def render_condition(
    name: str,
    root: Path,
    meshes: tuple[MeshEntry, ...],
    views: int,
    seed: int,
    workers: int,
    models: int = 126,
) -> SampleStore:
    """The frames of one condition (rendered once into ``root/name``): ``views`` of every
    test-split model of the reference dataset (``models`` models, ``seed``: the training
    data's test split) and of every mesh."""
    config = GenerateConfig(
        models=models, views=views, seed=seed, world=name, meshes=meshes, only_splits=UNSEEN
    )
    store = generate(config, root / name, workers=workers, progress=True)
    if store is None:
        raise RuntimeError(f"{root / name}: generation did not finish")
    return store


@dataclass
class ConditionResult:
    """One method on one condition: metrics (means over frames) and per-frame milliseconds."""

    metrics: dict[str, float]
    undefined: dict[str, int]
    milliseconds: list[float]

    def latency(self) -> dict[str, float]:
        """p50, p95 and max of the per-frame time (ms); NaN for a method not timed."""
        ms = np.array(self.milliseconds)
        if ms.size == 0:
            return dict.fromkeys(("p50", "p95", "max"), float("nan"))
        return {
            "p50": float(np.percentile(ms, 50)),
            "p95": float(np.percentile(ms, 95)),
            "max": float(ms.max()),
        }


def timed(method: Method, clock: list[float]) -> Method:
    """``method`` that appends the milliseconds of each call to ``clock``."""

    def answer(sample: Sample) -> FrameAnswer:
        start = time.perf_counter()
        result = method(sample)
        clock.append((time.perf_counter() - start) * 1e3)
        return result

    return answer


def evaluate_condition(
    methods: dict[str, Method], store: SampleStore, desc: str
) -> dict[str, ConditionResult]:
    """Every method, and the classical fill, on every frame of one condition's store."""
    results = {}
    for name, method in {**methods, FILL: classical}.items():
        clock: list[float] = []
        run = method if name == FILL or isinstance(method, StoredAnswers) else timed(method, clock)
        table = MetricTable()
        for record in tqdm(store.records, desc=f"{desc}: {name}", unit="img", leave=False):
            sample = store.load(record)
            table.add(score_frame(run, sample))
            if isinstance(method, StoredAnswers):
                clock.append(method.milliseconds(sample))
        results[name] = ConditionResult(table.mean(), table.undefined(), clock)
    return results


def _pair(own: float, fill: float) -> str:
    return "n/a" if np.isnan(own) else f"{own:.3f} ({fill:.3f})"


def _num(value: float, fmt: str) -> str:
    return "n/a" if np.isnan(value) else format(value, fmt)


def for_condition(methods: dict[str, Method], condition: str) -> dict[str, Method]:
    """``methods`` for one condition: stored answers are kept per condition, in a folder of
    the condition's name (``benchmarks/previous_model.py`` on the suite's data)."""
    return {
        name: StoredAnswers(m.folder / condition) if isinstance(m, StoredAnswers) else m
        for name, m in methods.items()
    }


def _coverage(m: dict[str, float]) -> str:
    within = m.get("sigma_within_1", float("nan"))
    if np.isnan(within):
        return "n/a"
    return f"{100 * within:.0f} / {100 * m['sigma_within_2']:.0f}"


def condition_table(results: dict[str, dict[str, ConditionResult]], frames: dict[str, int]) -> str:
    """Markdown: per condition and method, IOU (the fill's beside it), depth MAE on the pixels
    the method shares with the fill (the fill's own in brackets) overall and by distance band,
    mean normal error, false specks per frame, and in-process milliseconds per frame."""
    bands = " | ".join(f"{b}" for b in BAND_NAMES)
    lines = [
        f"| condition | frames | method | IOU % (fill) | MAE m (fill) | {bands} "
        "| normals ° (fill) | specks | within sigma / 2 sigma % | ms p50 / p95 / max |",
        "|---|---|---|---|---|" + "---|" * len(BAND_NAMES) + "---|---|---|---|",
    ]
    for condition, by_method in results.items():
        fill = by_method[FILL].metrics
        for name, result in by_method.items():
            if name == FILL:
                continue
            m, lat = result.metrics, result.latency()
            cells = [
                condition,
                str(frames[condition]),
                name,
                f"{100 * m['IOU']:.2f} ({100 * fill['IOU']:.2f})",
                _pair(m["MAE"], m["fill_MAE"]),
                *(_pair(m[f"MAE_{b}"], m[f"fill_MAE_{b}"]) for b in BAND_NAMES),
                f"{_num(m['normal_mean_deg'], '.1f')} ({_num(fill['normal_mean_deg'], '.1f')})",
                _num(m["specks"], ".2f"),
                _coverage(m),
                f"{lat['p50']:.0f} / {lat['p95']:.0f} / {lat['max']:.0f}",
            ]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def table_of(report: dict) -> str:
    """``condition_table`` of a ``robustness.json`` report (``run_suite``)."""
    results = {
        condition: {
            name: ConditionResult(r["metrics"], r["undefined"], r["milliseconds"])
            for name, r in by_method.items()
        }
        for condition, by_method in report["results"].items()
    }
    return condition_table(results, report["frames"])


def condition_gallery(
    method: Method, store: SampleStore, count: int, title: str, out: Path
) -> Path:
    """``count`` frames of one condition, evenly spread: gray | returns | depth | truth |
    error | side views of the completed cloud, the fill's and the true one."""
    rows = []
    for record in store.records[:: max(1, len(store.records) // count)][:count]:
        sample = store.load(record)
        caption = f"{title}: {record['model_name']} {record['distance_m']:.0f} m"
        rows.append(gallery_row(method, sample, caption, {FILL: classical}))
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), montage(rows, tile=256))
    return out


def run_suite(
    methods: dict[str, Method],
    conditions: list[str],
    data: Path,
    meshes: tuple[MeshEntry, ...],
    out: Path,
    views: int,
    seed: int,
    workers: int,
    gallery: int,
    models: int = 126,
) -> str:
    """Render (once), evaluate and draw every condition; writes ``out/robustness.md``,
    ``robustness.json`` and ``gallery_<condition>.png``; returns the table."""
    unknown = [c for c in conditions if c not in ROBUSTNESS]
    if unknown:
        raise ValueError(f"unknown conditions {unknown}; choose from {sorted(ROBUSTNESS)}")
    out.mkdir(parents=True, exist_ok=True)
    results, frames = {}, {}
    first = next(iter(methods))
    for condition in conditions:
        store = render_condition(condition, data, meshes, views, seed, workers, models)
        results[condition] = evaluate_condition(for_condition(methods, condition), store, condition)
        frames[condition] = len(store)
        if gallery:
            condition_gallery(
                methods[first], store, gallery, condition, out / f"gallery_{condition}.png"
            )
    table = condition_table(results, frames)
    (out / "robustness.md").write_text(table + "\n")
    report = {
        "conditions": conditions,
        "frames": frames,
        "results": {
            c: {
                name: {
                    "metrics": r.metrics,
                    "undefined": r.undefined,
                    "latency_ms": r.latency(),
                    "milliseconds": r.milliseconds,
                }
                for name, r in by_method.items()
            }
            for c, by_method in results.items()
        },
    }
    (out / "robustness.json").write_text(json.dumps(report, indent=1))
    return table
