"""What the working-pixel budget costs and buys: accuracy and time per frame at several budgets.

    python -m benchmarks.budget --onnx models/sdcnet.onnx --data data/robustness \\
        --budgets 256 384 448 512 640

The pipeline resamples every frame's crop to a fixed number of working pixels
(``sdcnet.pipeline.WORK_PIXELS``); the budget is chosen by measurement so that every frame fits
the 100 ms a 10 Hz LIDAR leaves on two cores, in process. Per budget (side x side pixels), on the
frames of every condition of the robustness suite: IOU, depth MAE on the pixels shared with the
classical fill, the in-process milliseconds per frame (median, p95, max). Writes
docs/benchmarks/budget.md and .json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.classical_fill import classical_fill
from sdcnet.metrics import MetricTable, frame_report
from sdcnet.pipeline import complete
from sdcnet.runtime.onnx import OnnxModel


def measure(model: OnnxModel, stores: list[SampleStore], budget: int) -> tuple[dict, list[float]]:
    """Mean metrics and per-frame milliseconds of the pipeline at ``budget`` working pixels."""
    table, times = MetricTable(), []
    for store in stores:
        for record in store.records:
            sample = store.load(record)
            K = Intrinsics(**sample.meta["intrinsics"])
            start = time.perf_counter()
            result = complete(model.run, sample.gray, sample.sparse, K.fx, model.stride, budget)
            times.append((time.perf_counter() - start) * 1e3)
            fill_depth, fill_mask = classical_fill(sample.sparse)
            table.add(
                frame_report(
                    result.depth, result.mask, fill_depth, fill_mask, sample.depth, sample.sparse, K
                )
            )
    return table.mean(), times


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--onnx", required=True, type=Path)
    p.add_argument("--data", default="data/robustness", type=Path, help="a folder of datasets")
    p.add_argument("--budgets", nargs="+", type=int, default=[256, 384, 448, 512, 640])
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    model = OnnxModel(args.onnx, provider="cpu", threads=args.threads, spin_wait=False)
    stores = [
        SampleStore(d) for d in sorted(args.data.iterdir()) if (d / "manifest.jsonl").exists()
    ]
    frames = sum(len(s) for s in stores)
    measure(model, stores[:1], args.budgets[0] ** 2)  # warm-up
    results, rows = {}, []
    for side in args.budgets:
        metrics, times = measure(model, stores, side * side)
        t = np.array(times)
        results[side] = {
            "IOU": metrics["IOU"],
            "MAE": metrics["MAE"],
            "fill_MAE": metrics["fill_MAE"],
            "p50_ms": float(np.percentile(t, 50)),
            "p95_ms": float(np.percentile(t, 95)),
            "max_ms": float(t.max()),
        }
        r = results[side]
        rows.append(
            f"| {side} x {side} | {100 * r['IOU']:.2f} | {r['MAE']:.3f} ({r['fill_MAE']:.3f}) | "
            f"{r['p50_ms']:.1f} | {r['p95_ms']:.1f} | {r['max_ms']:.1f} |"
        )
        print(rows[-1], flush=True)
    body = f"""
Measured on {cpu_description()}, onnxruntime with {args.threads} threads, over the {frames} frames
of every condition in `{args.data}` (the robustness suite), one pass per budget, the budgets in
turn. The model was trained at 512 x 512 with budgets drawn between half and one and a half of it.
Regenerate: `python -m benchmarks.budget --onnx {args.onnx} --data {args.data} --budgets \\
{" ".join(map(str, args.budgets))}`.

| working pixels | IOU % | same-pixel MAE m (fill) | median ms | p95 ms | max ms |
|---|---|---|---|---|---|
{chr(10).join(rows)}
"""
    print(write_markdown("budget", "The working-pixel budget: accuracy against time", body))
    (DOCS / "budget.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
