"""Accuracy against speed: the six metrics and the per-frame latency of every variant.

    python -m benchmarks.accuracy_speed --checkpoint models/sdcnet.pt --onnx models/sdcnet.onnx \\
        --data data/paper --split test

Each method runs the whole pipeline (crop to the LIDAR region, infer, paste) on the same
frames; latency is the median over those frames of that call, after warm-up, on this CPU.
Writes docs/benchmarks/accuracy_speed.md and .png.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import torch

from benchmarks.common import DOCS, cpu_description, onnx_variants, write_markdown
from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.scoring import Method, classical, network, torch_model_fn
from sdcnet.metrics import MetricTable, frame_metrics, markdown_table
from sdcnet.training.checkpoint import load_checkpoint


def measure(method: Method, store: SampleStore, records: list[dict]) -> tuple[MetricTable, float]:
    """Metrics over ``records`` and the median pipeline latency (ms) per frame."""
    table, times = MetricTable(), []
    first = store.load(records[0])
    for _ in range(2):  # warm-up
        method(first)
    for record in records:
        sample = store.load(record)
        start = time.perf_counter()
        depth, mask = method(sample)[:2]
        times.append((time.perf_counter() - start) * 1000)
        table.add(frame_metrics(depth, mask, sample.depth))
    return table, statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--checkpoint", type=Path, required=True)
    p.add_argument(
        "--onnx", type=Path, required=True, help="FP32 model; .fp16/.int8 siblings if present"
    )
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--split", default="test")
    p.add_argument("--limit", type=int, default=None, help="frames, evenly spread (default: all)")
    p.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    store = SampleStore(args.data)
    records = store.split(args.split, args.limit)
    model, _ = load_checkpoint(args.checkpoint)
    methods = {"PyTorch eager FP32": network(torch_model_fn(model), model.config.stride)}
    for name, runner in onnx_variants(args.onnx, args.threads).items():
        methods[name] = network(runner.run, runner.stride, runner.info.work_pixels)
    methods["classical fill (floor)"] = classical
    results, latency = {}, {}
    for name, method in methods.items():
        table, ms = measure(method, store, records)
        results[name], latency[name] = table.mean(), ms
        print(f"{name}: {ms:.1f} ms/frame, {results[name]}", flush=True)
    rows = [
        f"| {n} | {latency[n]:.1f} | {results[n]['MAEI']:.3f} | {results[n]['MATE']:.3f} | "
        f"{100 * results[n]['IOU']:.2f} |"
        for n in methods
    ]
    command = (
        f"python -m benchmarks.accuracy_speed --checkpoint {args.checkpoint} --onnx {args.onnx} "
        f"--data {args.data} --split {args.split}"
        + (f" --limit {args.limit}" if args.limit else "")
    )
    body = f"""
{len(records)} frames of the {args.split} split of `{args.data}`; {cpu_description()},
{args.threads} threads. Latency: median per frame of the whole pipeline (crop, infer, paste),
not counting decoding or encoding. Regenerate:
`{command}`

| method | ms / frame | MAEI m | MATE m | IOU % |
|---|---|---|---|---|
{chr(10).join(rows)}

All six metrics:

{markdown_table(results)}
"""
    print(write_markdown("accuracy_speed", "Accuracy against speed", body))
    fig, ax = plt.subplots(figsize=(6, 4))
    for name in methods:
        ax.scatter(latency[name], results[name]["MATE"], s=40)
        ax.annotate(
            name,
            (latency[name], results[name]["MATE"]),
            fontsize=7,
            xytext=(4, 4),
            textcoords="offset points",
        )
    ax.set_xlabel("median ms per frame (pipeline)")
    ax.set_ylabel("MATE (m), lower is better")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(DOCS / "accuracy_speed.png", dpi=110)
    (DOCS / "accuracy_speed.json").write_text(
        json.dumps({"latency_ms": latency, "metrics": results}, indent=1)
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
