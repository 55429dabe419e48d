"""``sdc-eval factors``: where a model's mask loses, factor by factor, on frames whose every
factor was drawn at once (the ``any`` world, ``sdcnet.training.data.conditions``).

The robustness suite pushes one factor at a time; flight frames push all of them together.
Here each frame of a dataset is scored once per method (IOU of the mask, as the service
answers it) and grouped by each factor its metadata records (background, LIDAR, exposure, bit
depth, ...) or its truth implies (the target's size in pixels, the returns on it). A value's
share of the first method's deficit (the sum of 1 - IOU over its frames, over the sum over all
frames) says what that value costs the model in all; its mean IOU, how hard one such frame is.
Factors are drawn together, so a value's mean carries the others' mixture with it: read a
factor's table beside the suite's one-factor conditions, not as a controlled ablation.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sdcnet.dataset_format import Sample, SampleStore
from sdcnet.evaluation.scoring import Method
from sdcnet.metrics import mask_iou

#: A frame's value of one factor, as the label of its bin.
FactorFn = Callable[[Sample], str]

#: Frames scoring below this IOU are counted apart: whole parts missed, not outlines.
POOR_IOU = 0.5


def binned(value: float, edges: tuple[float, ...], unit: str = "") -> str:
    """The label of the bin of ``value`` among ``edges`` (ascending): "<e0", "e0-e1", ...,
    ">=en"."""
    if value < edges[0]:
        return f"<{edges[0]:g}{unit}"
    for lo, hi in itertools.pairwise(edges):
        if value < hi:
            return f"{lo:g}-{hi:g}{unit}"
    return f">={edges[-1]:g}{unit}"


def bin_order(label: str) -> tuple[int, float, str]:
    """Sort key of a value's label: the bins "<a", "a-b", ">=b" in ascending order, then
    numbers ("512 px"), then names alphabetically."""
    rank = 0 if label.startswith("<") else 2 if label.startswith(">=") else 1
    number = label.lstrip("<>=").split("-")[0].rstrip("abcdefghijklmnopqrstuvwxyz ")
    try:
        return (rank, float(number), label)
    except ValueError:
        return (3, 0.0, label)


def _hfov_deg(sample: Sample) -> float:
    k = sample.meta["intrinsics"]
    return math.degrees(2 * math.atan(k["width"] / 2 / k["fx"]))


def _returns_on_target(sample: Sample) -> int:
    return int(np.count_nonzero((sample.sparse > 0) & sample.mask))


def _offset(sample: Sample) -> str:
    metres = float(np.linalg.norm(sample.meta["lidar"]["offset_m"]))
    return "none" if metres == 0 else binned(metres, (0.1,), " m")


#: The factors, in the table's order: name -> the frame's bin.
FACTORS: dict[str, FactorFn] = {
    "background": lambda s: s.meta["background"]["kind"],
    "LIDAR": lambda s: s.meta["lidar"]["kind"],
    "LIDAR's offset from the camera": _offset,
    "returns on the spacecraft": lambda s: binned(_returns_on_target(s), (1, 30, 300, 3000)),
    "spacecraft's pixels": lambda s: binned(
        int(np.count_nonzero(s.mask)), (2_000, 20_000, 100_000, 400_000)
    ),
    "range": lambda s: binned(s.meta["distance_m"], (5, 15, 50, 150), " m"),
    "horizontal field of view": lambda s: binned(_hfov_deg(s), (10, 20, 40), " deg"),
    "image width": lambda s: f"{s.meta['intrinsics']['width']} px",
    "bits": lambda s: f"{s.meta['sensor']['bits']}",
    "transfer curve (gamma)": lambda s: f"{s.meta['sensor']['gamma']:g}",
    "JPEG": lambda s: "yes" if s.meta["sensor"]["jpeg_quality"] else "no",
    "exposure (white surface, of full scale)": lambda s: binned(
        s.meta["sensor"]["exposure"], (0.3, 1.0, 2.5)
    ),
    "defocus": lambda s: "yes" if s.meta["sensor"]["defocus_px"] > 0 else "no",
    "Sun from the camera's axis": lambda s: binned(s.meta["sun_angle_deg"], (45, 90, 135), " deg"),
    # frames made before render styles were drawn are ours
    "render style": lambda s: s.meta.get("render_style", {}).get("kind", "ours"),
}


@dataclass(frozen=True)
class FrameFactors:
    """One frame: its id, its bin of every factor, and each method's IOU on it."""

    id: str
    factors: dict[str, str]
    iou: dict[str, float]


def frame_factors(sample: Sample) -> dict[str, str]:
    """The frame's bin of every factor; a ``ValueError`` naming what its metadata lacks
    (frames of another generator, or of sdc-data before it recorded every factor)."""
    try:
        return {name: fn(sample) for name, fn in FACTORS.items()}
    except KeyError as missing:
        raise ValueError(
            f"frame {sample.meta.get('id')} records no {missing} in its metadata: "
            "`sdc-eval factors` needs frames of `sdc-data generate`, which records every factor"
        ) from None


def score_frames(
    methods: dict[str, Method], store: SampleStore, records: list[dict], progress: bool = True
) -> list[FrameFactors]:
    """Every method's IOU on every frame of ``records``, with the frame's factors."""
    frames = []
    for record in tqdm(records, desc="factors", unit="img", disable=not progress, leave=False):
        sample = store.load(record)
        factors = frame_factors(sample)
        scores = {n: mask_iou(method(sample).mask, sample.mask) for n, method in methods.items()}
        frames.append(FrameFactors(sample.meta["id"], factors, scores))
    return frames


def factor_rows(frames: list[FrameFactors], factor: str | None) -> list[dict]:
    """One row per value of ``factor`` (None: one row of all frames): frames, each method's
    mean IOU (%), the first method's share of its whole deficit (%) and its frames below
    ``POOR_IOU``."""
    names = list(frames[0].iou)
    first = names[0]
    total_deficit = sum(1 - f.iou[first] for f in frames) or 1.0
    groups: dict[str, list[FrameFactors]] = {}
    for f in frames:
        groups.setdefault("all" if factor is None else f.factors[factor], []).append(f)
    rows = []
    for value in sorted(groups, key=bin_order):
        group = groups[value]
        rows.append(
            {
                "value": value,
                "frames": len(group),
                "iou": {n: 100 * float(np.mean([f.iou[n] for f in group])) for n in names},
                "deficit_share": 100 * sum(1 - f.iou[first] for f in group) / total_deficit,
                "poor": int(sum(f.iou[first] < POOR_IOU for f in group)),
            }
        )
    return rows


def factors_table(frames: list[FrameFactors]) -> str:
    """The markdown table of all frames, then of every factor's values (``factor_rows``)."""
    names = list(frames[0].iou)
    head = ["factor", "value", "frames", *(f"IOU % {n}" for n in names)]
    head += [f"share of {names[0]}'s deficit %", f"frames < {POOR_IOU:.0%}"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for factor in (None, *FACTORS):
        for i, row in enumerate(factor_rows(frames, factor)):
            cells = [(factor or "all frames") if i == 0 else "", row["value"], str(row["frames"])]
            cells += [f"{row['iou'][n]:.1f}" for n in names]
            cells += [f"{row['deficit_share']:.1f}", str(row["poor"])]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def factors_figure(frames: list[FrameFactors], path: Path) -> None:
    """``factors.png``: one panel a factor, each value's mean IOU per method as bars, its
    frames counted beside its name; the dashed line is the first method's mean over all."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(frames[0].iou)
    overall = factor_rows(frames, None)[0]["iou"][names[0]]
    cols = 4
    fig, axes = plt.subplots(-(-len(FACTORS) // cols), cols, figsize=(4.2 * cols, 11))
    height = 0.8 / len(names)
    for ax, factor in zip(axes.flat, FACTORS, strict=False):
        rows = factor_rows(frames, factor)
        for i, name in enumerate(names):
            y = [k + (i - (len(names) - 1) / 2) * height for k in range(len(rows))]
            ax.barh(y, [r["iou"][name] for r in rows], height, label=name)
        ax.set_yticks(range(len(rows)), [f"{r['value']} ({r['frames']})" for r in rows])
        ax.invert_yaxis()
        ax.axvline(overall, color="k", linestyle="--", linewidth=0.8)
        ax.set_xlim(0, 100)
        ax.set_title(factor, fontsize=10)
        ax.tick_params(labelsize=8)
    for ax in axes.flat[len(FACTORS) :]:
        ax.axis("off")
    fig.legend(*axes.flat[0].get_legend_handles_labels(), loc="lower right", fontsize=10)
    fig.supxlabel("IOU % (frames of each value in brackets)")
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def run_factors(
    methods: dict[str, Method], data: str, split: str, limit: int | None, out: Path
) -> str:
    """Score ``methods`` on ``limit`` frames (evenly spread; None: all) of ``split`` of the
    dataset at ``data``; write ``factors.md`` (the table), ``factors.png`` (``factors_figure``)
    and ``factors.json`` (the table and every frame's factors and IOU) to ``out``; return the
    markdown."""
    store = SampleStore(data)
    records = store.split(split, limit)
    if not records:
        raise ValueError(f"split {split!r} is empty in {data}")
    frames = score_frames(methods, store, records)
    made = store.info.get("command", "")
    text = (
        f"# Where the mask loses, factor by factor\n\n"
        f"{len(frames)} frames of the {split} split of `{data}`"
        + (f" (`{made}`)" if made else "")
        + ": IOU of each method's mask, mean over the frames holding each value; the share of "
        "the first method's deficit (sum of 1 - IOU) those frames hold. Factors are drawn "
        "together, so a value's mean carries the others' mixture with it. "
        "Regenerate: `sdc-eval factors` with the same flags.\n\n![IOU by factor](factors.png)\n\n"
        + factors_table(frames)
        + "\n"
    )
    out.mkdir(parents=True, exist_ok=True)
    (out / "factors.md").write_text(text)
    factors_figure(frames, out / "factors.png")
    report = {
        "data": data,
        "split": split,
        "frames": [vars(f) for f in frames],
        "factors": {k or "all frames": factor_rows(frames, k) for k in (None, *FACTORS)},
    }
    (out / "factors.json").write_text(json.dumps(report, indent=1))
    return text
