"""What stray LIDAR returns cost the mask, and what leaving them out (``sdcnet.stray_returns``)
buys back: each frame answered as it is and with ``--strays`` returns added at random pixels
off the spacecraft (the sky or the Earth behind it), at 0.7-1.3 of the frame's median range,
through ``sdcnet.pipeline.complete`` as the service runs it, without and with the strays left
out.

    python -m benchmarks.stray_returns --onnx models/sdcnet.onnx --sets data/robustness/* \\
        data/real data/paper:test --strays 3 10

Each set is a dataset directory, ``DIR:SPLIT`` for one split of it, at most ``--limit`` frames
each, evenly spread. The strays of a frame come from a generator seeded with ``--seed`` and
the frame's index. Writes docs/benchmarks/stray_returns.md and .json.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from tqdm import tqdm

import sdcnet.pipeline
from benchmarks.common import DOCS, cpu_description, set_records, write_markdown
from sdcnet.dataset_format import Sample
from sdcnet.evaluation.scoring import network
from sdcnet.metrics import frame_metrics
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.stray_returns import MIN_RETURNS_TO_JUDGE, STRAY_SPACINGS, without_strays


def with_strays(sample: Sample, count: int, rng: np.random.Generator) -> tuple[Sample, np.ndarray]:
    """``sample`` with ``count`` returns added at random pixels off the spacecraft (its true
    depth 0), at 0.7-1.3 of its returns' median range (100 m without returns), and those
    pixels (rows, cols) as an (n, 2) array."""
    off = np.argwhere(sample.depth <= 0)
    picked = off[rng.choice(len(off), min(count, len(off)), replace=False)]
    returns = sample.sparse[sample.sparse > 0]
    median = float(np.median(returns)) if returns.size else 100.0
    sparse = sample.sparse.copy()
    sparse[picked[:, 0], picked[:, 1]] = median * rng.uniform(0.7, 1.3, len(picked))
    return dataclasses.replace(sample, sparse=sparse), picked


@contextlib.contextmanager
def strays_kept() -> Iterator[None]:
    """The pipeline as it was before ``sdcnet.stray_returns``: every return used."""
    original = sdcnet.pipeline.without_strays
    sdcnet.pipeline.without_strays = lambda sparse: (sparse, 0)
    try:
        yield
    finally:
        sdcnet.pipeline.without_strays = original


def iou(method, sample: Sample) -> float:
    """The mask's IOU, 0 for a frame the pipeline refuses (no return)."""
    try:
        answer = method(sample)
    except ValueError:
        return 0.0
    return float(frame_metrics(answer.depth, answer.mask, sample.depth)["IOU"])


def set_rows(model: OnnxModel, spec: str, strays: list[int], seed: int, limit: int | None):
    """Per frame and stray count: the IOU with every return used and with the strays left
    out, how many returns were left out, how many of the added ones stayed, the filter's ms."""
    method = network(model.run, model.stride, model.info.work_pixels)
    store, records = set_records(spec, limit)
    rows = []
    for index, record in enumerate(tqdm(records, desc=spec, unit="frame", leave=False)):
        sample = store.load(record)
        rng = np.random.default_rng([seed, index])
        for count in [0, *strays]:
            noisy, picked = with_strays(sample, count, rng)
            start = time.perf_counter()
            kept, left_out = without_strays(noisy.sparse)
            ms = (time.perf_counter() - start) * 1e3
            with strays_kept():
                before = iou(method, noisy)
            rows.append(
                {
                    "strays": count,
                    "iou_kept": before,
                    "iou_left_out": iou(method, noisy),
                    "left_out": left_out,
                    "added_kept": int(np.count_nonzero(kept[picked[:, 0], picked[:, 1]])),
                    "ms": ms,
                }
            )
    return rows


def summary(rows: list[dict], count: int) -> dict:
    """One set's figures at one stray count."""
    mine = [r for r in rows if r["strays"] == count]
    left_out = sum(r["left_out"] for r in mine)
    return {
        "frames": len(mine),
        "iou_kept": float(np.mean([r["iou_kept"] for r in mine])),
        "iou_left_out": float(np.mean([r["iou_left_out"] for r in mine])),
        # with none added, every return left out was the frame's own
        "own_left_out": left_out if count == 0 else None,
        "added_kept": sum(r["added_kept"] for r in mine),
        "added": count * len(mine),
        "ms_median": float(np.median([r["ms"] for r in mine])),
        "ms_max": float(np.max([r["ms"] for r in mine])),
    }


def table(summaries: dict[str, dict[int, dict]], strays: list[int]) -> str:
    head = ["set", "frames", "IOU % as sent: every return used / strays left out"]
    head += [f"{k} strays added: every return used / left out" for k in strays]
    head += ["the frames' own returns left out", "added strays kept", "ms median / max"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for spec, by_count in summaries.items():
        base = by_count[0]
        cells = [spec, str(base["frames"])]
        cells += [
            f"{100 * by_count[k]['iou_kept']:.2f} / **{100 * by_count[k]['iou_left_out']:.2f}**"
            for k in [0, *strays]
        ]
        cells.append(str(base["own_left_out"]))
        cells.append(
            ", ".join(f"{by_count[k]['added_kept']} of {by_count[k]['added']}" for k in strays)
        )
        ms = [by_count[k] for k in [0, *strays]]
        cells.append(
            f"{np.median([m['ms_median'] for m in ms]):.2f} / {max(m['ms_max'] for m in ms):.2f}"
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--onnx", type=Path, default=Path("models/sdcnet.onnx"))
    p.add_argument("--sets", nargs="+", required=True, help="DIR or DIR:SPLIT, each a set")
    p.add_argument("--strays", type=int, nargs="+", default=[3, 10], help="returns added")
    p.add_argument("--limit", type=int, default=None, help="frames per set, evenly spread")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    model = OnnxModel(args.onnx, threads=args.threads)
    summaries = {}
    for spec in args.sets:
        rows = set_rows(model, spec, args.strays, args.seed, args.limit)
        summaries[spec] = {k: summary(rows, k) for k in [0, *args.strays]}
        print(spec, {k: round(100 * s["iou_left_out"], 2) for k, s in summaries[spec].items()})
    command = f"python -m benchmarks.stray_returns --onnx {args.onnx} --sets {' '.join(args.sets)}"
    command += f" --strays {' '.join(map(str, args.strays))} --seed {args.seed}"
    command += f" --limit {args.limit}" if args.limit else ""
    body = f"""
A stray return is one with no other within {STRAY_SPACINGS:g} return spacings, in a frame of at
least {MIN_RETURNS_TO_JUDGE} returns (`sdcnet.stray_returns`). Per set, the mask's IOU (mean
over frames) with the frame's returns as sent and with strays added at random pixels off the
spacecraft (0.7-1.3 of the frame's median range), every return used (the pipeline before) /
the strays left out (as served, in bold); how many of the frames' own returns were left out
(none added), how many of the added strays stayed (too near the spacecraft, or in a frame of
too few returns to judge), and what finding them took. Model `{args.onnx}`; {cpu_description()}.
Regenerate: `{command}`

{table(summaries, args.strays)}
"""
    path = write_markdown("stray_returns", "Stray LIDAR returns", body)
    (DOCS / "stray_returns.json").write_text(
        json.dumps(
            {spec: {str(k): v for k, v in s.items()} for spec, s in summaries.items()}, indent=1
        )
    )
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
