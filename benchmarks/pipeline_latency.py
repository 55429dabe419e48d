"""The cost of every frame: the whole in-process pipeline per condition, beside the previous model.

    python -m benchmarks.pipeline_latency --onnx models/sdcnet.onnx --data data/robustness \\
        --previous e6a386e

What the service does between decoding and encoding a frame, on the robustness suite's frames
(``sdc-eval robustness`` renders them: the paper's camera and others from 5 to 60 deg, 512 to
2048 px, docking to 300 m): crop to the LIDAR-bounded region, resample to the working grid,
onnxruntime, paste back, back-project the cloud (at most ``MAX_POINTS``, as the service's
default), with malloc set as the service sets it
(``sdcnet.allocator``). Per condition and over all frames: median,
p95 and max in milliseconds, p95 / median, against the 100 ms a 10 Hz LIDAR leaves. With
``--previous COMMIT``, the same frames through the previous shipped model and its own pipeline
(``benchmarks/previous_model.py``, run after this one in the same command). Writes
docs/benchmarks/pipeline_latency.md and .json.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.allocator import configure_malloc
from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore
from sdcnet.normals import cloud_normals
from sdcnet.pipeline import complete
from sdcnet.pointcloud import MAX_POINTS, back_project, cloud_stride
from sdcnet.runtime.onnx import OnnxModel

BUDGET_MS = 100.0


def time_frames(
    models: dict[str, OnnxModel], store: SampleStore, repeats: int
) -> dict[str, list[float]]:
    """Milliseconds of each frame of ``store`` (each one ``repeats`` times) through the
    pipeline, the back-projection and the points' normals, per model, after a warm-up. The
    models take turns frame by frame, so that a machine that slows down or speeds up weighs on
    each alike, and which of them goes first moves on with every frame: the first to complete
    a frame can pay for memory the next ones find ready (a 2048 x 2048 frame's first sigma
    paste-back took 15-34 ms, the same copy 0.8 ms on the next frame)."""
    samples = [store.load(r) for r in store.records]

    def run(model: OnnxModel, sample) -> None:
        K = Intrinsics(**sample.meta["intrinsics"])
        info = model.info
        result = complete(
            model.run, sample.gray, sample.sparse, K.fx, info.stride, info.work_pixels
        )
        valid = result.mask & (result.depth > 0)
        stride = cloud_stride(valid, MAX_POINTS)  # the service's cloud at its default
        back_project(result.depth, valid, K, stride=stride)
        cloud_normals(result, valid, K, stride=stride)

    for model in models.values():
        for sample in samples[:2]:
            run(model, sample)
    times: dict[str, list[float]] = {name: [] for name in models}
    names = list(models)
    for _ in range(repeats):
        for i, sample in enumerate(samples):
            for name in names[i % len(names) :] + names[: i % len(names)]:
                model = models[name]
                start = time.perf_counter()
                run(model, sample)
                times[name].append((time.perf_counter() - start) * 1e3)
    return times


def previous_times(commit: str, data: Path, threads: int) -> dict[str, list[float]]:
    """Milliseconds per frame of the previous model, per condition (its own pipeline)."""
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [
                sys.executable,
                *("-m", "benchmarks.previous_model", "--commit", commit),
                *("--data", str(data), "--out", tmp, "--threads", str(threads)),
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        return {
            folder.name: [float(np.load(f)["milliseconds"]) for f in sorted(folder.glob("*.npz"))]
            for folder in sorted(Path(tmp).iterdir())
            if folder.is_dir()
        }


def stats(ms: list[float]) -> dict[str, float]:
    t = np.array(ms)
    p50, p95 = float(np.percentile(t, 50)), float(np.percentile(t, 95))
    return {"p50": p50, "p95": p95, "max": float(t.max()), "p95_over_p50": p95 / p50, "n": len(t)}


def row(name: str, condition: str, s: dict[str, float]) -> str:
    verdict = "within" if s["p95"] <= BUDGET_MS else "over"
    return (
        f"| {condition} | {name} | {s['n']} | {s['p50']:.1f} | {s['p95']:.1f} | {s['max']:.1f} "
        f"| {s['p95_over_p50']:.2f} | {verdict} |"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--onnx", required=True, type=Path)
    p.add_argument("--data", default="data/robustness", type=Path, help="a folder of datasets")
    p.add_argument(
        "--beside",
        nargs="*",
        default=[],
        type=Path,
        help="other ONNX models of this pipeline, timed in turn with --onnx frame by frame",
    )
    p.add_argument("--previous", help="commit of the previous shipped model, run beside it")
    p.add_argument("--repeats", type=int, default=2, help="passes over the frames")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    configure_malloc()  # as sdc-serve does
    models = {
        name: OnnxModel(path, provider="cpu", threads=args.threads, spin_wait=False)
        for name, path in [("this model", args.onnx), *((p.stem, p) for p in args.beside)]
    }
    model = models["this model"]
    conditions = sorted(d for d in args.data.iterdir() if (d / "manifest.jsonl").exists())
    timed = {c.name: time_frames(models, SampleStore(c), args.repeats) for c in conditions}
    results = {}
    for name in models:
        times = {c: ts[name] for c, ts in timed.items()}
        results[name] = {c: stats(t) for c, t in times.items()}
        results[name]["all"] = stats([t for ts in times.values() for t in ts])
    if args.previous:
        previous = previous_times(args.previous, args.data, args.threads)
        results["previous model"] = {c: stats(t) for c, t in previous.items()}
        results["previous model"]["all"] = stats([t for ts in previous.values() for t in ts])
    rows = [
        row(name, condition, s)
        for condition in [*timed, "all"]
        for name, by_condition in results.items()
        if (s := by_condition.get(condition))
    ]
    print("\n".join(rows))
    command = " ".join(
        [
            "python -m benchmarks.pipeline_latency",
            *("--onnx", str(args.onnx), "--data", str(args.data)),
            *(["--beside", *map(str, args.beside)] if args.beside else []),
            *(["--previous", args.previous] if args.previous else []),
        ]
    )
    beside_note = (
        " Beside it, taking turns frame by frame: "
        + ", ".join(f"`{p}` (`{p.stem}`)" for p in args.beside)
        + "."
        if args.beside
        else ""
    )
    previous_note = (
        f" The previous model: the version at `{args.previous}`, its own pipeline (crops "
        "resampled to its focal length from each frame's true intrinsics), one pass."
        if args.previous
        else ""
    )
    body = f"""
Measured on {cpu_description()}, onnxruntime with {args.threads} intra-op threads (idle threads
sleep, as in the service), {args.repeats} passes over the frames of `{args.data}` (the
robustness suite's conditions: `sdc-eval robustness`). Per frame: crop to the LIDAR-bounded
region, resample to the working grid ({model.info.work_pixels} pixels), the network, paste back,
back-project the cloud: the service's work between decode and encode.{beside_note}{previous_note}
Regenerate: `{command}`.

| condition | model | frames | median ms | p95 ms | max ms | p95 / median | {BUDGET_MS:.0f} ms |
|---|---|---|---|---|---|---|---|
{chr(10).join(rows)}
"""
    print(write_markdown("pipeline_latency", "The cost of every frame, per condition", body))
    (DOCS / "pipeline_latency.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
