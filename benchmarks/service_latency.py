"""Service latency: real HTTP requests of a 1024 x 1024 frame at concurrency 1, 4 and 16.

    python -m benchmarks.service_latency [--model models/sdcnet.onnx] [--requests 60]
                                         [--endpoint complete|v2]

Starts the real service (``sdc-serve`` on 127.0.0.1, a free port, all CPUs as onnxruntime
threads, the default admission limit) on the given model (default: the shipped
``models/sdcnet.onnx``, else SDCNet with random weights, said in the report), and sends it
generated 1024 x 1024 frames (four spacecraft at different distances and attitudes, seeded;
gray PNG + sparse ``.npy`` to ``POST /complete``; with ``--endpoint v2``, raw gray and the
returns as a list to ``POST /v2/models/sdcnet/infer``, every output binary, full frame, as
tritonclient asks by default). At each concurrency, ``--requests``
requests in all from that many clients, each on its own keep-alive connection, back to back;
a client answered 503 waits for its Retry-After, as ``sdc-client`` does. Then, at concurrency
1, each answer format of ``POST /complete``.

Reports p50 / p95 / p99 end-to-end latency of the 200 answers, throughput, the 503 count and
the median split of a request between decode, queue, inference, encode (the service's
``Server-Timing``) and the rest (HTTP, multipart parsing, transfer), and whether the target
(p50 <= 100 ms at concurrency 1, JSON answer) is met. Writes docs/benchmarks/service_latency.md,
.json and .png (``service_latency_v2.*`` for the v2 endpoint).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.returns import returns_from_dense
from sdcnet.service.inference import PHASES
from tests.support.frames import generated_samples, multipart_body, sample_files, v2_body
from tests.support.fuzzing import V2_INFER
from tests.support.serving import temporary_service

TARGET_MS = 100.0  # p50 of a 1024 x 1024 frame at concurrency 1: the LIDAR's 10 Hz
CONCURRENCY = (1, 4, 16)
FORMATS = ("json", "npz", "ply")
ENDPOINTS = ("complete", "v2")


@dataclass(frozen=True)
class Body:
    """One request, encoded once: its path, bytes and headers."""

    path: str
    content: bytes
    headers: dict[str, str]


@dataclass(frozen=True)
class Shot:
    """One request: its status (or the transport error's name), end-to-end seconds, the
    service's phases (milliseconds, from Server-Timing), when it started (s from the run's
    start) and the Retry-After of a 503 (s)."""

    status: int | str
    seconds: float
    phases_ms: dict[str, float]
    started_s: float
    retry_after_s: float = 0.0


@dataclass
class Run:
    """What ``send`` did: every shot, wall-clock seconds of the whole run."""

    shots: list[Shot] = field(default_factory=list)
    seconds: float = 0.0

    def statuses(self) -> dict[str, int]:
        return dict(sorted(Counter(str(s.status) for s in self.shots).items()))

    def ok(self) -> list[Shot]:
        return [s for s in self.shots if s.status == 200]


def frame_bodies(
    count: int, size: int = 1024, seed: int = 5, endpoint: str = "complete"
) -> list[Body]:
    """``count`` generated frames as request bodies, encoded once: multipart forms (gray PNG,
    sparse .npy) for ``POST /complete``, or binary v2 requests (gray UINT8, returns FP32)."""
    bodies = []
    for s in generated_samples(size, count, seed):
        if endpoint == "v2":
            content, headers = v2_body(s.gray, returns_from_dense(s.sparse))
            bodies.append(Body(V2_INFER.split(" ")[1], content, headers))
        else:
            content, content_type = multipart_body(sample_files(s))
            bodies.append(Body("/complete", content, {"content-type": content_type}))
    return bodies


def server_timing(header: str | None) -> dict[str, float]:
    """``Server-Timing: decode;dur=1.2, ...`` -> {"decode": 1.2, ...} (milliseconds)."""
    phases = {}
    for item in (header or "").split(","):
        name, _, duration = item.strip().partition(";dur=")
        if duration:
            phases[name] = float(duration)
    return phases


def send(
    url: str,
    bodies: list[Body],
    requests: int,
    concurrency: int,
    *,
    params: dict | None = None,
    duration_s: float | None = None,
    rate: float | None = None,
    retry_after: bool = True,
) -> Run:
    """``concurrency`` client threads, each on its own keep-alive connection, POST the bodies
    in turn until ``requests`` are sent or ``duration_s`` passes. ``rate`` (requests/s in
    all): request i leaves at i / rate, else back to back. ``retry_after``: a client answered
    503 waits for its Retry-After before its next request."""
    run, lock, t0 = Run(), threading.Lock(), time.perf_counter()
    counter = iter(range(requests))

    def client() -> None:
        with httpx.Client(timeout=120) as http:
            while True:
                with lock:
                    i = next(counter, None)
                if i is None or (duration_s and time.perf_counter() - t0 > duration_s):
                    return
                if rate:
                    time.sleep(max(0.0, t0 + i / rate - time.perf_counter()))
                shot = _post(http, url, bodies[i % len(bodies)], params, t0)
                with lock:
                    run.shots.append(shot)
                if retry_after and shot.status == 503:
                    time.sleep(shot.retry_after_s)

    threads = [threading.Thread(target=client) for _ in range(concurrency)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    run.seconds = time.perf_counter() - t0
    return run


def _post(http: httpx.Client, url: str, body: Body, params: dict | None, t0: float) -> Shot:
    start = time.perf_counter()
    try:
        response = http.post(
            f"{url}{body.path}", content=body.content, headers=body.headers, params=params
        )
        response.read()
    except httpx.HTTPError as exc:
        return Shot(type(exc).__name__, time.perf_counter() - start, {}, start - t0)
    return Shot(
        response.status_code,
        time.perf_counter() - start,
        server_timing(response.headers.get("server-timing")),
        start - t0,
        float(response.headers.get("retry-after", 0)),
    )


def summarise(run: Run) -> dict:
    """Latency percentiles (ms) and throughput of the 200 answers, statuses, median phases."""
    ok = run.ok()
    ms = np.array([s.seconds * 1e3 for s in ok]) if ok else np.array([np.nan])
    phases = {p: [s.phases_ms.get(p, 0.0) for s in ok] for p in PHASES}
    phases["rest"] = [s.seconds * 1e3 - sum(s.phases_ms.get(p, 0.0) for p in PHASES) for s in ok]
    return {
        "requests": len(run.shots),
        "statuses": run.statuses(),
        "p50_ms": float(np.percentile(ms, 50)),
        "p95_ms": float(np.percentile(ms, 95)),
        "p99_ms": float(np.percentile(ms, 99)),
        "throughput_per_s": len(ok) / run.seconds,
        "seconds": run.seconds,
        "median_phase_ms": {p: statistics.median(v) if v else 0.0 for p, v in phases.items()},
    }


def plot(levels: dict[int, dict], path: Path, title: str) -> None:
    """Latency percentiles per concurrency, and the median split of a request."""
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    x = np.arange(len(levels))
    for offset, key in zip((-0.25, 0, 0.25), ("p50_ms", "p95_ms", "p99_ms"), strict=True):
        left.bar(x + offset, [r[key] for r in levels.values()], 0.25, label=key[:3])
    left.axhline(TARGET_MS, color="k", ls="--", lw=1, label=f"target {TARGET_MS:.0f} ms")
    left.set(xticks=x, xticklabels=[f"c={c}" for c in levels], ylabel="end-to-end ms (200s)")
    left.legend(fontsize=8)
    bottom = np.zeros(len(levels))
    for phase in (*PHASES, "rest"):
        values = np.array([r["median_phase_ms"][phase] for r in levels.values()])
        right.bar(x, values, 0.5, bottom=bottom, label=phase)
        bottom += values
    right.set(xticks=x, xticklabels=[f"c={c}" for c in levels], ylabel="median ms per phase")
    right.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def table(rows: dict[str, dict], first: str) -> str:
    """Markdown table of ``summarise`` results, one row per key (column ``first``)."""
    lines = [
        f"| {first} | requests | statuses | p50 ms | p95 ms | p99 ms | 200/s | decode | queue "
        "| inference | encode | rest |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        phases = " | ".join(f"{r['median_phase_ms'][p]:.1f}" for p in (*PHASES, "rest"))
        statuses = ", ".join(f"{k}: {v}" for k, v in r["statuses"].items())
        lines.append(
            f"| {name} | {r['requests']} | {statuses} | {r['p50_ms']:.1f} | {r['p95_ms']:.1f} | "
            f"{r['p99_ms']:.1f} | {r['throughput_per_s']:.1f} | {phases} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--requests", type=int, default=60, help="per concurrency level")
    p.add_argument("--format-requests", type=int, default=20, help="per format, concurrency 1")
    p.add_argument("--frames", type=int, default=4, help="different generated frames")
    p.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    p.add_argument("--endpoint", choices=ENDPOINTS, default="complete", help="which protocol")
    args = p.parse_args(argv)

    v2 = args.endpoint == "v2"
    bodies = frame_bodies(args.frames, endpoint=args.endpoint)
    with temporary_service(args.model, f"--threads={args.threads}") as (service, model):
        meta = httpx.get(f"{service.url}/model").json()
        send(service.url, bodies, 2 * len(bodies), 1)  # warm-up: every frame twice
        levels = {c: summarise(send(service.url, bodies, args.requests, c)) for c in CONCURRENCY}
        formats = {
            f: summarise(send(service.url, bodies, args.format_requests, 1, params={"format": f}))
            for f in ([] if v2 else FORMATS)
        }
    for c, r in levels.items():
        print(f"concurrency {c}: {json.dumps(r)}", flush=True)
    p50 = levels[1]["p50_ms"]
    verdict = "met" if p50 <= TARGET_MS else "not met"
    command = f"python -m benchmarks.service_latency --requests {args.requests}"
    command += f" --model {args.model}" if args.model else ""
    command += " --endpoint v2" if v2 else ""
    if v2:
        request = (
            "raw gray UINT8 + the returns as an FP32 list (a few KiB) in one binary v2 request "
            "to `POST /v2/models/sdcnet/infer`, every output asked binary and full frame (as "
            "tritonclient asks by default): about 5.5 MB back"
        )
        answer = "v2 binary answer"
    else:
        request = (
            "gray PNG + sparse float32 `.npy` (4 MiB) per request to `POST /complete`; the JSON "
            "answer is about 7 MB"
        )
        answer = "JSON answer"
    body = f"""
Real HTTP on 127.0.0.1: `sdc-serve` in its own process ({args.threads} onnxruntime threads,
at most {meta["limits"]["max_in_flight"]} requests in flight, the rest 503), clients in another
process on the same {cpu_description()}. Model: {model} (version `{meta["version"]}`,
{meta["provider"]}). Frames: {args.frames} generated 1024 x 1024 spacecraft (seed 5), {request}.
Each client holds a keep-alive connection and sends back to back; after a 503 it waits for
Retry-After. Latency: end-to-end at the client, 200 answers only; phases: medians of the
service's `Server-Timing`, "rest" = end-to-end minus the four phases (HTTP, body parsing,
upload and download). Regenerate: `{command}`.

**Target: p50 <= {TARGET_MS:.0f} ms for a 1024 x 1024 frame at concurrency 1 ({answer}):
{verdict}** (p50 {p50:.1f} ms).

{table({str(c): r for c, r in levels.items()}, "concurrency")}
"""
    if formats:
        body += f"""
Answer formats at concurrency 1 ({args.format_requests} requests each; phases in ms):

{table(formats, "format")}
"""
    name = "service_latency_v2" if v2 else "service_latency"
    title = "Service latency (HTTP, 1024 x 1024" + (", Open Inference Protocol)" if v2 else ")")
    print(write_markdown(name, title, body))
    results = {"model": model, "target_met": p50 <= TARGET_MS, "concurrency": levels}
    results["formats"] = formats
    (DOCS / f"{name}.json").write_text(json.dumps(results, indent=1))
    plot(
        levels,
        DOCS / f"{name}.png",
        f"POST {bodies[0].path}, 1024 x 1024 frame, {answer}",
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
