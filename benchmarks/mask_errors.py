"""Where the foreground mask errs, per set: the IOU deficit split into the spacecraft the
network never saw and, of the rest, errors by distance to the true outline.

    python -m benchmarks.mask_errors --onnx models/sdcnet.onnx \\
        --sets data/robustness/* data/real data/paper:test --limit 288

Each set is a dataset directory, ``DIR:SPLIT`` for one split of it, at most ``--limit`` frames
each, evenly spread; every frame runs through ``sdcnet.pipeline.complete`` as the service runs
it. Every frame's 1 - IOU is split (``sdcnet.metrics.mask_error_bands``) into the true
foreground outside the crops the network was shown (its first look's and a second look's:
``Completion.region``; the whole spacecraft for a frame without returns, which the service
refuses), and the rest by distance to the outline: touching it, 2-3 px from it and farther.
What each share says: unseen, the crop (the returns' extent, the second look's budget);
at the outline, the resolution the network saw the crop at; farther, the network's mistakes
(false parts glued to the spacecraft, missed booms and panels). Writes
docs/benchmarks/mask_errors.md and .json.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from tqdm import tqdm

from benchmarks.common import DOCS, set_records, write_markdown
from sdcnet.dataset_format import Sample
from sdcnet.evaluation.scoring import FrameAnswer, network
from sdcnet.metrics import mask_error_bands, mask_iou
from sdcnet.pipeline import return_pixels
from sdcnet.runtime.onnx import OnnxModel

COLUMNS = (
    "IOU",
    "missed_unseen",
    "fp_edge",
    "fn_edge",
    "miss_near",
    "fp_far",
    "miss_far",
    "IOU_off_edge",
)


def frame_row(sample: Sample, answer: FrameAnswer, has_returns: bool) -> dict:
    """One frame's IOU and error shares. The pipeline answers a frame without returns with an
    empty mask over the whole frame; counted here as unseen, since the network had nothing to
    look at."""
    seen = np.zeros(sample.depth.shape, bool)
    if has_returns:
        seen[answer.completion.region.slices] = True
    truth = sample.depth > 0
    return {
        "no_returns": not has_returns,
        "IOU": mask_iou(answer.mask, truth),
        **mask_error_bands(answer.mask, sample.depth, seen),
    }


def set_rows(model: OnnxModel, spec: str, limit: int | None) -> list[dict]:
    """Per frame of one set: IOU and error shares."""
    method = network(model.run, model.stride, model.info.work_pixels)
    store, records = set_records(spec, limit)
    rows = []
    for record in tqdm(records, desc=spec, unit="frame", leave=False):
        sample = store.load(record)
        has_returns = len(return_pixels(sample.sparse)[0]) > 0
        rows.append(frame_row(sample, method(sample), has_returns))
    return rows


def summary(rows: list[dict]) -> dict:
    """Means over a set's frames (frames whose union is empty left out of the shares)."""
    means = {k: float(np.nanmean([r[k] for r in rows])) for k in COLUMNS}
    return {"frames": len(rows), "no_returns": sum(r["no_returns"] for r in rows), **means}


def table(summaries: dict[str, dict]) -> str:
    lines = [
        "| set | frames | no returns | IOU % | unseen | at the outline: false / missed "
        "| 2-3 px from it | farther: false / missed | IOU off the outline % |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summaries.items():
        pct = {k: f"{100 * s[k]:.2f}" for k in COLUMNS}
        far_missed = f"{100 * (s['miss_far'] - s['fp_far']):.2f}"
        lines.append(
            f"| {name} | {s['frames']} | {s['no_returns']} | {pct['IOU']} | "
            f"{pct['missed_unseen']} | {pct['fp_edge']} / {pct['fn_edge']} | "
            f"{pct['miss_near']} | {pct['fp_far']} / {far_missed} | {pct['IOU_off_edge']} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--onnx", type=Path, default=Path("models/sdcnet.onnx"))
    p.add_argument("--sets", nargs="+", required=True, help="DIR or DIR:SPLIT, each a set")
    p.add_argument("--limit", type=int, default=None, help="frames per set, evenly spread")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    model = OnnxModel(args.onnx, threads=args.threads)
    summaries = {spec: summary(set_rows(model, spec, args.limit)) for spec in args.sets}
    command = (
        f"python -m benchmarks.mask_errors --onnx {args.onnx} --sets {' '.join(args.sets)}"
        + (f" --limit {args.limit}" if args.limit else "")
    )
    body = f"""
Model `{args.onnx}` ({model.info.version}), every frame through `sdcnet.pipeline.complete`
as the service answers it. Means over frames, in % of each frame's union |A ∪ Â|: the error
columns add up to 1 - IOU. "Unseen": the spacecraft outside the crops the network was shown
(the returns' extent with its margin, and a second look's where the frame's budget gave one),
all of it on a frame without returns. The rest by distance to the true outline: "at the
outline" touches it (<= 1.5 px), then 2-3 px, then farther. "IOU off the outline": the IOU
with the outline's pixels left out. Regenerate:
`{command}`

{table(summaries)}
"""
    print(write_markdown("mask_errors", "Where the mask errs", body))
    (DOCS / "mask_errors.json").write_text(json.dumps(summaries, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
