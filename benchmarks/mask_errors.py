"""Where the foreground mask errs: the IOU deficit split by distance to the true outline.

    python -m benchmarks.mask_errors --checkpoint models/sdcnet.pt --data data/paper \\
        --split test --limit 288

Runs each checkpoint's segmentation path through the service's pipeline (crop, infer, paste)
and splits every frame's 1 - IOU into errors touching the outline, 2-3 px from it and farther
(``sdcnet.metrics.mask_error_bands``), by spacecraft size on the image. Also the IOU with the
outline's pixels left out: what the mask scores where the image is not ambiguous.
Writes docs/benchmarks/mask_errors.md and .json.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from benchmarks.common import DOCS, write_markdown
from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.scoring import network, torch_segmentation_fn
from sdcnet.metrics import frame_metrics, mask_error_bands
from sdcnet.training.checkpoint import load_checkpoint

SIZE_BINS_PX = (0, 20_000, 60_000, 200_000, 1024 * 1024 + 1)  # true foreground pixels
COLUMNS = ("IOU", "miss_edge", "fp_edge", "fn_edge", "miss_near", "miss_far", "IOU_off_edge")


def frame_rows(checkpoint: Path, store: SampleStore, records: list[dict]) -> list[dict]:
    """Per frame: foreground size, IOU and the error bands of the checkpoint's mask."""
    model, _ = load_checkpoint(checkpoint)
    method = network(torch_segmentation_fn(model), model.config.stride)
    rows = []
    for record in tqdm(records, desc=checkpoint.name, unit="img", leave=False):
        sample = store.load(record)
        depth, mask = method(sample)[:2]
        rows.append(
            {
                "foreground_px": int((sample.depth > 0).sum()),
                "IOU": frame_metrics(depth, mask, sample.depth)["IOU"],
                **mask_error_bands(mask, sample.depth),
            }
        )
    return rows


def summary(rows: list[dict]) -> list[dict]:
    """Means over frames, for all frames and per size bin."""
    out = []
    bins = [("all", 0, SIZE_BINS_PX[-1])] + [
        (f"{lo // 1000}k-{hi // 1000}k px", lo, hi) for lo, hi in itertools.pairwise(SIZE_BINS_PX)
    ]
    for label, lo, hi in bins:
        chosen = [r for r in rows if lo <= r["foreground_px"] < hi]
        if chosen:
            means = {k: float(np.nanmean([r[k] for r in chosen])) for k in COLUMNS}
            out.append({"frames": label, "n": len(chosen), **means})
    return out


def table(summaries: list[dict]) -> str:
    lines = [
        "| frames | n | IOU % | 1 - IOU at the outline | of which false fg | of which missed "
        "| 2-3 px from it | farther | IOU off the outline % |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        lines.append(
            f"| {s['frames']} | {s['n']} | {100 * s['IOU']:.2f} | {100 * s['miss_edge']:.2f} | "
            f"{100 * s['fp_edge']:.2f} | {100 * s['fn_edge']:.2f} | {100 * s['miss_near']:.2f} | "
            f"{100 * s['miss_far']:.2f} | {100 * s['IOU_off_edge']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--checkpoint", type=Path, nargs="+", required=True)
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--split", default="test")
    p.add_argument("--limit", type=int, default=None, help="frames, evenly spread (default: all)")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    store = SampleStore(args.data)
    records = store.split(args.split, args.limit)
    results = {str(c): summary(frame_rows(c, store, records)) for c in args.checkpoint}
    command = (
        f"python -m benchmarks.mask_errors --checkpoint {' '.join(map(str, args.checkpoint))} "
        f"--data {args.data} --split {args.split}"
        + (f" --limit {args.limit}" if args.limit else "")
    )
    sections = [f"### `{name}`\n\n{table(rows)}" for name, rows in results.items()]
    body = f"""
{len(records)} frames of the {args.split} split of `{args.data}`, mean over frames, in % of each
frame's union |A ∪ Â| (the error columns add up to 1 - IOU). "At the outline": pixels touching
a pixel of the other class in the ground truth (<= 1.5 px). Regenerate:
`{command}`

{(chr(10) * 2).join(sections)}
"""
    print(write_markdown("mask_errors", "Where the mask errs", body))
    (DOCS / "mask_errors.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
