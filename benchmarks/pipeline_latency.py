"""The whole in-process pipeline, model against model, side by side in one run.

    python -m benchmarks.pipeline_latency --onnx models/sdcnet.onnx runs/previous.onnx

What the service does between decoding and encoding a 1024 x 1024 frame, on real test frames:
crop to the LIDAR-bounded region, onnxruntime on the crop, paste back, drop stars, back-project
the cloud. The models take turns frame by frame (so a busy neighbour slows all alike), after a
warm-up; medians and p95 per model and their ratio to the first. The budget: 45 ms per frame
on 2 threads. Writes docs/benchmarks/pipeline_latency.md and .json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore, evenly_spread
from sdcnet.pipeline import complete
from sdcnet.pointcloud import back_project
from sdcnet.runtime import OnnxModel

BUDGET_MS = 45.0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--onnx", nargs="+", required=True, type=Path, help="models; ratios to the first"
    )
    p.add_argument("--data", default="data/paper", help="dataset (sdc-data generate)")
    p.add_argument("--split", default="test")
    p.add_argument("--frames", type=int, default=48, help="test frames, evenly spread")
    p.add_argument("--repeats", type=int, default=3, help="passes over the frames")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    store = SampleStore(args.data)
    samples = [store.load(r) for r in evenly_spread(store.split(args.split), args.frames)]
    models = {
        str(path): OnnxModel(path, provider="cpu", threads=args.threads) for path in args.onnx
    }
    times: dict[str, list[float]] = {name: [] for name in models}

    def run(model: OnnxModel, sample) -> None:
        result = complete(model.run, sample.gray, sample.sparse, stride=model.stride)
        back_project(result.depth, result.mask, Intrinsics(**sample.meta["intrinsics"]))

    for model in models.values():  # warm-up: onnxruntime's first calls allocate
        for sample in samples[:3]:
            run(model, sample)
    for _ in range(args.repeats):
        for sample in samples:
            for name, model in models.items():
                start = time.perf_counter()
                run(model, sample)
                times[name].append((time.perf_counter() - start) * 1000)

    first = next(iter(models))
    results = {
        name: {
            "version": models[name].info.version,
            "median_ms": float(np.median(t)),
            "p95_ms": float(np.percentile(t, 95)),
            "runs": len(t),
        }
        for name, t in times.items()
    }
    rows = []
    for name, r in results.items():
        ratio = r["median_ms"] / results[first]["median_ms"]
        verdict = "within" if r["median_ms"] <= BUDGET_MS else "over"
        rows.append(
            f"| `{name}` ({r['version']}) | {r['median_ms']:.1f} | {r['p95_ms']:.1f} | "
            f"{ratio:.2f}x | {verdict} the {BUDGET_MS:.0f} ms budget |"
        )
        print(rows[-1], flush=True)
    body = f"""
Measured on {cpu_description()}, onnxruntime with {args.threads} intra-op threads, on
{len(samples)} frames of the {args.split} split of `{args.data}` (1024 x 1024, evenly spread),
{args.repeats} passes, the models taking turns on each frame. Per frame: crop to the LIDAR-bounded
region, the network on the crop, paste back, drop stars, back-project the cloud (the service's
work between decode and encode).
Regenerate: `python -m benchmarks.pipeline_latency --onnx {" ".join(map(str, args.onnx))}`.

| model | median ms | p95 ms | vs first | |
|---|---|---|---|---|
{chr(10).join(rows)}
"""
    print(write_markdown("pipeline_latency", "Whole pipeline per frame, model against model", body))
    (DOCS / "pipeline_latency.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
