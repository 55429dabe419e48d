"""Model latency: PyTorch eager vs onnxruntime FP32 / FP16 / INT8, side by side in one run.

    python benchmarks/model_latency.py --checkpoint CKPT --onnx models/sdcnet.onnx

Batch 1 at 512 x 512 and 1024 x 1024 (the whole frame, no cropping: the network's own cost),
medians and p95 over repeated runs after warm-up, GFLOPs per frame (PyTorch's FLOP counter:
convolutions and matrix products) and the achieved GFLOP/s beside this CPU's peak estimate.
Writes docs/benchmarks/model_latency.md and .png.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from benchmarks.common import (
    DOCS,
    cpu_description,
    onnx_variants,
    peak_gflops,
    time_calls,
    write_markdown,
)
from sdcnet.export.cli import parity_frames
from sdcnet.training.checkpoint import load_checkpoint


def frame_inputs(size: int, seed: int = 11) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A real rendered frame, centre-cropped to size x size, as the network's inputs: (1, 1,
    H, W) float32 gray and sparse, (1, 1, 1, 1) focal length."""
    gray, sparse, fx = parity_frames(seed, count=1)[0]
    y = (gray.shape[0] - size) // 2
    crop = (slice(y, y + size), slice(y, y + size))
    return (
        (gray[crop].astype(np.float32) / 255)[None, None],
        sparse[crop].astype(np.float32)[None, None],
        np.full((1, 1, 1, 1), fx, np.float32),
    )


def gflops(model: torch.nn.Module, inputs: tuple[np.ndarray, ...]) -> float:
    with torch.no_grad(), FlopCounterMode(display=False) as counter:
        model(*map(torch.from_numpy, inputs))
    return counter.get_total_flops() / 1e9


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--checkpoint", required=True, type=Path)
    p.add_argument(
        "--onnx", required=True, type=Path, help="FP32 model; .fp16/.int8 siblings if present"
    )
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    args = p.parse_args(argv)

    torch.set_num_threads(args.threads)
    model, _ = load_checkpoint(args.checkpoint)
    runners = {"PyTorch eager FP32": None, **onnx_variants(args.onnx, args.threads)}
    peak, peak_note = peak_gflops(args.threads)
    rows, results = [], {}
    for size in (512, 1024):
        inputs = frame_inputs(size)
        flops = gflops(model, inputs)
        for name, runner in runners.items():
            if runner is None:
                tensors = tuple(map(torch.from_numpy, inputs))

                def call(tensors=tensors):
                    with torch.no_grad():
                        model(*tensors)
            else:

                def call(runner=runner, inputs=inputs):
                    runner.run(*inputs)

            t = time_calls(call, args.repeats)
            achieved = flops / (t["median_ms"] / 1000)
            results[f"{name} @{size}"] = {**t, "gflop": flops, "gflops_per_s": achieved}
            rows.append(
                f"| {name} | {size} x {size} | {t['median_ms']:.1f} | {t['p95_ms']:.1f} | "
                f"{flops:.2f} | {achieved:.0f} | {100 * achieved / peak:.0f} % |"
            )
            print(rows[-1], flush=True)
    base = {s: results[f"PyTorch eager FP32 @{s}"]["median_ms"] for s in (512, 1024)}
    fp32 = {s: results.get(f"onnxruntime FP32 @{s}", {}).get("median_ms") for s in (512, 1024)}
    ratios = []
    for key, r in results.items():
        size = int(key.rsplit("@", 1)[1])
        vs_fp32 = f"{fp32[size] / r['median_ms']:.2f}x" if fp32[size] else "-"
        ratios.append(f"| {key} | {base[size] / r['median_ms']:.2f}x | {vs_fp32} |")
    body = f"""
Measured on {cpu_description()}, {args.threads} threads (torch.set_num_threads and onnxruntime
intra_op_num_threads = {args.threads}, inter_op = 1), batch 1, whole frame (no cropping),
{args.repeats} runs after 2 warm-up runs. Peak estimate: {peak:.0f} GFLOP/s ({peak_note}).
Regenerate: `python -m benchmarks.model_latency --checkpoint {args.checkpoint} --onnx {args.onnx}`.

| runtime | input | median ms | p95 ms | GFLOP/frame | GFLOP/s | of peak |
|---|---|---|---|---|---|---|
{chr(10).join(rows)}

Speed-up (median time ratios measured in this run):

| runtime | vs PyTorch eager | vs onnxruntime FP32 |
|---|---|---|
{chr(10).join(ratios)}
"""
    print(write_markdown("model_latency", "Model latency on this CPU", body))
    (DOCS / "model_latency.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
