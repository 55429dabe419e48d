"""Shared by the benchmark commands: timing, this CPU's peak, frames, markdown output."""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sdcnet.dataset_format import SampleStore, evenly_spread
from sdcnet.training.train import cpu_name

DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks"


def time_calls(fn: Callable[[], object], repeats: int, warmup: int = 2) -> dict[str, float]:
    """Median and p95 wall time in milliseconds of ``fn()`` after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append((time.perf_counter() - start) * 1000)
    return {
        "median_ms": statistics.median(times),
        "p95_ms": float(np.percentile(times, 95)),
        "runs": repeats,
    }


def cpu_description() -> str:
    return f"{cpu_name()}, {len(os.sched_getaffinity(0))} cores"


def peak_gflops(cores: int | None = None) -> tuple[float, str]:
    """FP32 peak estimate and how it was made.

    Zen 4 executes AVX-512 on two 256-bit FMA pipes per core: 2 x 8 lanes x 2 FLOP = 32 FP32
    FLOP per cycle per core; times the clock the kernel reports (``cpu MHz``) and the cores.
    """
    cores = cores or len(os.sched_getaffinity(0))
    mhz = (
        [
            float(line.split(":", 1)[1])
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("cpu MHz")
        ]
        if Path("/proc/cpuinfo").exists()
        else []
    )
    ghz = (max(mhz) / 1000) if mhz else 3.0
    peak = 32 * ghz * cores
    return peak, f"32 FP32 FLOP/cycle/core (2 x 256-bit FMA) x {ghz:.2f} GHz x {cores} cores"


def set_records(spec: str, limit: int | None) -> tuple[SampleStore, list[dict]]:
    """The store and records of one ``DIR`` or ``DIR:SPLIT``."""
    root, _, split = spec.partition(":")
    store = SampleStore(root)
    if split:
        return store, store.split(split, limit)
    return store, evenly_spread(store.records, limit) if limit else store.records


def write_markdown(name: str, title: str, body: str) -> Path:
    DOCS.mkdir(parents=True, exist_ok=True)
    path = DOCS / f"{name}.md"
    path.write_text(f"# {title}\n\n{body.strip()}\n")
    return path


def onnx_variants(fp32: Path, threads: int) -> dict:
    """'onnxruntime FP32/FP16/INT8' -> loaded CPU model, for the files that exist beside ``fp32``
    (``NAME.onnx``, ``NAME.fp16.onnx``, ``NAME.int8.onnx``, as ``sdc-export --variants`` writes)."""
    from sdcnet.runtime.onnx import OnnxModel

    found = {}
    for label, suffix in (("FP32", ""), ("FP16", ".fp16"), ("INT8", ".int8")):
        path = fp32.with_suffix(f"{suffix}.onnx")
        if path.exists():
            found[f"onnxruntime {label}"] = OnnxModel(
                path, provider="CPUExecutionProvider", threads=threads
            )
    return found
