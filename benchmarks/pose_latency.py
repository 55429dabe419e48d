"""``POST /pose`` latency beside ``POST /complete``: from scratch and tracking, 1024 x 1024.

    python -m benchmarks.pose_latency [--model models/sdcnet.onnx] [--meshes ../shared/real-meshes]
        [--frames 12] [--threads 2]

Starts the real service (``sdc-serve`` on 127.0.0.1, ``--threads`` onnxruntime threads,
``--targets`` the mesh folder) and renders, for each of the folder's spacecraft, a fly-around
sequence of ``--frames`` frames at 10 Hz (``sdc-data sequence``'s, seed 0). For every frame,
back to back on one keep-alive connection: ``POST /complete`` (JSON answer), ``POST /pose``
from scratch, and ``POST /pose`` tracking (``init``: the constant-velocity prediction of the
previous two tracked answers, as ``sdc-eval pose`` does; from the second frame on). Reports
p50 / p95 round trip per kind, the service's own split (Server-Timing, and the registration's
CPU time, which a busy machine does not inflate) and the targets
(``/pose`` p50 <= 150 ms from scratch, <= 100 ms tracking); the machine's load average is
printed beside them, since the 2 cores may be shared. Writes docs/benchmarks/pose_latency.md
and .json.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import httpx
import numpy as np

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.meshes import read_mesh_folder
from sdcnet.rigid import extrapolate, parse_pose
from sdcnet.training.data.sequence import SequenceConfig, render_sequence
from sdcnet.training.data.spacecraft import load_mesh_file
from tests.support.frames import sample_files
from tests.support.serving import temporary_service

TARGETS_MS = {"pose from scratch": 150.0, "pose tracking": 100.0}


def frames(meshes: Path, count: int):
    """(target name, sample) of a fly-around of every mesh, in order."""
    config = SequenceConfig(frames=count, trajectories=("flyaround",))
    for k, entry in enumerate(read_mesh_folder(meshes)):
        model = load_mesh_file(entry.path, entry.longest_m, entry.scale)
        for sample in render_sequence(model, 1000 + k, "flyaround", config, "real"):
            yield entry.path.stem, sample


def timings(response: httpx.Response) -> dict[str, float]:
    """Server-Timing as {phase: milliseconds}."""
    out = {}
    for part in response.headers.get("server-timing", "").split(","):
        name, _, duration = part.strip().partition(";dur=")
        if duration:
            out[name] = float(duration)
    return out


def percentiles(values: list[float]) -> dict[str, float]:
    return {"p50": float(np.median(values)), "p95": float(np.percentile(values, 95))}


def measure(url: str, rendered: list) -> tuple[dict[str, list[tuple[float, dict]]], tuple]:
    """Round trips (ms) and Server-Timing of each kind of request; load averages around."""
    shots: dict[str, list[tuple[float, dict]]] = {}
    with httpx.Client(base_url=url, timeout=120) as http:

        def shot(kind: str, path: str, sample, **data) -> httpx.Response:
            files = sample_files(sample)
            start = time.perf_counter()
            response = http.post(path, files=files, data=data)
            elapsed = (time.perf_counter() - start) * 1e3
            response.raise_for_status()
            split = timings(response)
            if path == "/pose":
                split["registration_cpu"] = response.json()["timings"]["registration_cpu_ms"]
            shots.setdefault(kind, []).append((elapsed, split))
            return response

        for name, sample in rendered[:2]:  # warm-up
            shot("warm-up", "/complete", sample)
            shot("warm-up", "/pose", sample, target=name)
        tracked: list = []
        previous_target = None
        load_before = os.getloadavg()[0]
        for name, sample in rendered:
            if name != previous_target:
                tracked, previous_target = [], name
            shot("complete", "/complete", sample)
            shot("pose from scratch", "/pose", sample, target=name)
            data = {"target": name}
            if tracked:
                init = extrapolate(*tracked[-2:]) if len(tracked) >= 2 else tracked[-1]
                data["init"] = json.dumps(init.as_dict())
            answer = shot("pose tracking", "/pose", sample, **data).json()
            tracked.append(parse_pose(answer["pose"]))
        load_after = os.getloadavg()[0]
    shots.pop("warm-up")
    return shots, (load_before, load_after)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--meshes", type=Path, default=Path("../shared/real-meshes"))
    p.add_argument("--frames", type=int, default=12, help="frames per spacecraft")
    p.add_argument("--threads", type=int, default=2)
    args = p.parse_args(argv)
    rendered = list(frames(args.meshes, args.frames))
    flags = ("--targets", str(args.meshes), "--threads", str(args.threads))
    with temporary_service(args.model, *flags) as (service, description):
        shots, (load_before, load_after) = measure(service.url, rendered)
    rows, data = [], {}
    for kind, values in shots.items():
        if kind == "pose tracking":  # the first frame of each sequence has no init
            values = [v for k, v in enumerate(values) if k % args.frames]
        latency = percentiles([v for v, _ in values])
        phases = sorted({k for _, t in values for k in t})
        split = {k: float(np.median([t.get(k, 0.0) for _, t in values])) for k in phases}
        target = TARGETS_MS.get(kind)
        met = "" if target is None else (" met" if latency["p50"] <= target else " **missed**")
        data[kind] = {"requests": len(values), **latency, "server_ms": split, "target_ms": target}
        rows.append(
            f"| {kind} | {len(values)} | {latency['p50']:.1f} | {latency['p95']:.1f} | "
            + ", ".join(f"{k} {v:.1f}" for k, v in split.items())
            + f" | {'' if target is None else f'<= {target:.0f}{met}'} |"
        )
    body = "\n".join(
        [
            f"{description}, {args.threads} onnxruntime threads, {cpu_description()}; "
            f"{len(rendered)} frames of 1024 x 1024 ({args.frames}-frame fly-arounds of "
            f"{len({n for n, _ in rendered})} spacecraft at 10 Hz); one client, back to back. "
            f"Load average {load_before:.1f} before, {load_after:.1f} after (2 cores).",
            "",
            "| request | n | p50 ms | p95 ms | server median ms | target p50 |",
            "|---|---|---|---|---|---|",
            *rows,
        ]
    )
    path = write_markdown("pose_latency", "POST /pose beside POST /complete", body)
    (DOCS / "pose_latency.json").write_text(json.dumps(data, indent=1))
    print(body)
    print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
