"""The cost of every frame: the whole in-process pipeline per condition, beside the previous model.

    python -m benchmarks.pipeline_latency --onnx models/sdcnet.onnx --data data/robustness \\
        --previous e6a386e

What the service does between decoding and encoding a frame, on the robustness suite's frames
(``sdc-eval robustness`` renders them: the paper's camera and others from 5 to 60 deg, 512 to
2048 px, docking to 300 m): crop to the LIDAR-bounded region, resample to the working grid,
onnxruntime, paste back, back-project the cloud (at most ``MAX_POINTS``, as the service's
default), with malloc set as the service sets it
(``sdcnet.allocator``), at the share of each frame's budget ``sdc-serve`` chooses on this CPU
(``sdcnet.frame_budget.calibrate``, measured first, then re-read from the frames as they are
served: ``ServedBudget``), beside it at the share chosen first and held, and at the whole
budget (``--shares``: at other shares of it too; with two or more, the line through their
p95, the constants ``sdcnet.frame_budget`` holds). Each model is first warmed up as
``sdc-serve`` warms it at start-up (``sdcnet.service.inference.warm_up``, at its largest
accepted frame), so that no frame pays for the process's first memory. Per condition and
over all frames: the frames' mean share, median, p95 and max in milliseconds, p95 / median,
against the 100 ms a 10 Hz LIDAR leaves; and the slowest frames with their milliseconds on
every pass, which tell a frame that is slow from a machine that was. With
``--previous COMMIT``, the same frames through the previous shipped model and its own
pipeline (``benchmarks/previous_model.py``, run after this one in the same command). Writes
docs/benchmarks/pipeline_latency.md and .json.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.allocator import configure_malloc
from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import SampleStore
from sdcnet.frame_budget import (
    DEADLINE_SHARE,
    REFERENCE_MS,
    SUITE_P95_MS,
    FrameBudget,
    ServedBudget,
    answer_in_process,
    calibrate,
    fixed,
    frame_milliseconds,
)
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.service.inference import warm_up
from sdcnet.service.settings import MAX_PIXELS

BUDGET_MS = 100.0


#: A model, the working pixels it is run at and the budget whose share frames get (one that
#: never changes, or one re-read from the frames as ``sdc-serve`` re-reads it).
Runner = tuple[OnnxModel, int, ServedBudget]


#: Slowest frames of --onnx at the share served listed with their milliseconds on every pass.
SLOWEST = 8


def time_frames(
    runners: dict[str, Runner], store: SampleStore, repeats: int
) -> dict[str, list[list[tuple[float, float]]]]:
    """(milliseconds, share of its budget) of each frame of ``store`` on each of ``repeats``
    passes (one list a frame) through the pipeline, the back-projection and the points'
    normals, per runner; each frame's milliseconds go to its runner's budget. The runners
    take turns frame by frame, so that a machine that slows down or speeds up weighs on each
    alike, and which of them goes first moves on with every frame: the first to complete a
    frame can pay for memory the next ones find ready (a 2048 x 2048 frame's first sigma
    paste-back took 15-34 ms, the same copy 0.8 ms on the next frame). Each frame is read
    just before its turn, as the service decodes a request's frame: with a whole condition
    read at once (2 GB of 2048 x 2048 frames), its first frame's maps landed on memory never
    touched and took 260-380 ms, 77-91 on the next pass."""

    def run(runner: Runner, sample) -> tuple[float, float]:
        model, work_pixels, budget = runner
        K = Intrinsics(**sample.meta["intrinsics"])
        share = budget.budget.frame_share
        start = time.perf_counter()
        answer_in_process(
            model.run, sample.gray, sample.sparse, K, model.stride, work_pixels, share
        )
        milliseconds = (time.perf_counter() - start) * 1e3
        budget.observe(milliseconds, share)
        return milliseconds, share

    times = {name: [[] for _ in store.records] for name in runners}
    names = list(runners)
    for _ in range(repeats):
        for i, record in enumerate(store.records):
            sample = store.load(record)
            for name in names[i % len(names) :] + names[: i % len(names)]:
                times[name][i].append(run(runners[name], sample))
    return times


def slowest_frames(
    stores: dict[str, SampleStore],
    timed: dict[str, dict[str, list[list[tuple[float, float]]]]],
    name: str,
) -> list[dict]:
    """The ``SLOWEST`` frames of runner ``name`` by their slowest pass: condition, sample id,
    size (pixels), LIDAR returns, and the milliseconds and share of its budget of every
    pass."""
    frames = []
    for condition, store in stores.items():
        for record, passes in zip(store.records, timed[condition][name], strict=True):
            intrinsics = record["intrinsics"]
            frames.append(
                {
                    "condition": condition,
                    "id": record["id"],
                    "size": f"{intrinsics['width']} x {intrinsics['height']}",
                    "returns": record["returns"],
                    "ms": [round(t, 1) for t, _ in passes],
                    "shares": [round(share, 2) for _, share in passes],
                }
            )
    return sorted(frames, key=lambda f: -max(f["ms"]))[:SLOWEST]


def slowest_rows(frames: list[dict]) -> str:
    """The slowest frames as a markdown table."""
    lines = [
        "| condition | frame | size | returns | ms (share) on each pass |",
        "|---|---|---|---|---|",
    ]
    for f in frames:
        passes = " / ".join(
            f"{t:.1f} ({share:.2f})" for t, share in zip(f["ms"], f["shares"], strict=True)
        )
        lines.append(f"| {f['condition']} | {f['id']} | {f['size']} | {f['returns']} | {passes} |")
    return "\n".join(lines)


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


def stats(ms: list[float], shares: list[float] | None = None) -> dict[str, float]:
    """Median, p95, max and p95 / median of ``ms``, their count, and the frames' mean share
    of their budget (None where not known: the previous model)."""
    t = np.array(ms)
    p50, p95 = float(np.percentile(t, 50)), float(np.percentile(t, 95))
    share = float(np.mean(shares)) if shares else None
    return {
        "p50": p50,
        "p95": p95,
        "max": float(t.max()),
        "p95_over_p50": p95 / p50,
        "n": len(t),
        "share": share,
    }


def row(name: str, condition: str, s: dict[str, float]) -> str:
    verdict = "within" if s["p95"] <= BUDGET_MS else "over"
    share = "" if s["share"] is None else f"{s['share']:.2f}"
    return (
        f"| {condition} | {name} | {s['n']} | {share} | {s['p50']:.1f} | {s['p95']:.1f} "
        f"| {s['max']:.1f} | {s['p95_over_p50']:.2f} | {verdict} |"
    )


def suite_line(results: dict, shares: list[float]) -> tuple[float, float] | None:
    """(a, b): the least-squares line p95 = a + b * share through the p95 over all frames of
    --onnx at each of ``shares`` of its budget; None for fewer than two shares."""
    if len(set(shares)) < 2:
        return None
    p95 = [results[f"this model at {share:g} of its budget"]["all"]["p95"] for share in shares]
    b, a = np.polyfit(shares, p95, 1)
    return round(float(a), 1), round(float(b), 1)


def budget_note(
    budget: FrameBudget, served: ServedBudget, reference_ms: float, fit: tuple[float, float] | None
) -> str:
    """What the calibration chose here (``sdcnet.frame_budget``), as sdc-serve does at start-up,
    where the frames' re-reading left it, and the constants this run measured."""
    now = served.budget
    lines = [
        f"**This model's frames** start at {budget.frame_share:.2f} of their budget (at most "
        f"{budget.work_pixels} working pixels, fewer where a frame's own work is large): "
        f"`sdcnet.frame_budget.calibrate` on this CPU, as "
        f"`sdc-serve` does at start-up, for a p95 within {DEADLINE_SHARE:g} of "
        f"{budget.deadline_ms:g} ms. The reference frame took {budget.reference_ms:.1f} ms at "
        f"the whole budget then, {reference_ms:.1f} ms after the run (the constants' CPU: "
        f"{REFERENCE_MS:g} ms); expected p95 {budget.expected_p95_ms:.1f} ms. "
        f"`this model` is served as `sdc-serve` serves it, the share re-read from the "
        f"latest {served.window} frames every {served.every} "
        f"(`sdcnet.frame_budget.ServedBudget`; its frames' mean share per row): after "
        f"{now.served_frames} frames, {now.frame_share:.2f} (the latest frames' p95 "
        f"{now.served_p95_ms:.1f} ms); `this model, start-up share` holds the first."
    ]
    if fit:
        lines.append(
            f"The line through the p95 of all frames at each share of the budget: "
            f"{fit[0]:.1f} + {fit[1]:.1f} x share ms (`sdcnet.frame_budget.SUITE_P95_MS` "
            f"holds {SUITE_P95_MS[0]:g} + {SUITE_P95_MS[1]:g} x share)."
        )
    return " ".join(lines)


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
    p.add_argument(
        "--shares",
        nargs="*",
        default=[1.0],
        type=float,
        help="--onnx also at these shares of its own budget, in turn with the rest; with two or "
        "more, the line through their p95 over all frames and the reference frame's ms: "
        "sdcnet.frame_budget's constants for this CPU",
    )
    p.add_argument("--deadline-ms", type=float, default=BUDGET_MS, help="the service's --frame-ms")
    p.add_argument("--repeats", type=int, default=2, help="passes over the frames")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)

    configure_malloc()  # as sdc-serve does
    model, *beside = (
        OnnxModel(path, provider="cpu", threads=args.threads, spin_wait=False)
        for path in [args.onnx, *args.beside]
    )
    for runtime in (model, *beside):
        warm_up(runtime, math.isqrt(MAX_PIXELS))  # as sdc-serve does at start-up
    own = model.info.work_pixels
    budget = calibrate(model.run, model.stride, own, args.deadline_ms)
    runners: dict[str, Runner] = {
        "this model": (model, own, ServedBudget(budget)),
        "this model, start-up share": (model, own, ServedBudget(budget, window=0)),
    }
    for share in args.shares:
        at_share = ServedBudget(replace(fixed(own, own), frame_share=share), window=0)
        runners[f"this model at {share:g} of its budget"] = (model, own, at_share)
    for path, other in zip(args.beside, beside, strict=True):
        whole = fixed(other.info.work_pixels, other.info.work_pixels)
        runners[path.stem] = (other, other.info.work_pixels, ServedBudget(whole, window=0))
    conditions = sorted(d for d in args.data.iterdir() if (d / "manifest.jsonl").exists())
    stores = {c.name: SampleStore(c) for c in conditions}
    timed = {name: time_frames(runners, store, args.repeats) for name, store in stores.items()}
    reference_ms = frame_milliseconds(model.run, model.stride, own)
    results = {}
    for name in runners:
        frames = {c: [f for passes in ts[name] for f in passes] for c, ts in timed.items()}
        results[name] = {c: stats(*zip(*f, strict=True)) for c, f in frames.items()}
        results[name]["all"] = stats(*zip(*(f for fs in frames.values() for f in fs), strict=True))
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
    fit = suite_line(results, args.shares)
    served = runners["this model"][2]
    calibration_note = budget_note(budget, served, reference_ms, fit)
    print(calibration_note)
    slowest = slowest_frames(stores, timed, "this model")
    slowest_table = slowest_rows(slowest)
    print(slowest_table)
    command = " ".join(
        [
            "python -m benchmarks.pipeline_latency",
            *("--onnx", str(args.onnx), "--data", str(args.data)),
            *(["--beside", *map(str, args.beside)] if args.beside else []),
            *(["--previous", args.previous] if args.previous else []),
            *(["--shares", *map(str, args.shares)] if args.shares != [1.0] else []),
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
region, resample to the working grid, the network, paste back,
back-project the cloud: the service's work between decode and encode.{beside_note}{previous_note}
Regenerate: `{command}`.

{calibration_note}

| condition | model | frames | share | p50 ms | p95 ms | max ms | p95 / p50 | {BUDGET_MS:.0f} ms |
|---|---|---|---|---|---|---|---|---|
{chr(10).join(rows)}

**The slowest frames** of this model as served, by their slowest pass (the passes alike at
one share: the frame is slow; one pass alone: the machine was, or the share had moved):

{slowest_table}
"""
    print(write_markdown("pipeline_latency", "The cost of every frame, per condition", body))
    results["frame budget"] = {**budget.describe(), "reference_ms_after": reference_ms}
    results["frame budget served"] = served.budget.describe()
    results["slowest frames"] = slowest
    if fit:
        results["frame budget"]["suite_p95_line_ms"] = fit
    (DOCS / "pipeline_latency.json").write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
