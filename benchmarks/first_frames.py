"""The first frames after start-up, against the same frames once the service has seen them.

    python -m benchmarks.first_frames [--model models/sdcnet.onnx] [--data data/robustness]
                                      [--conditions docking-2048 any] [--frames 8] [--starts 3]

A LIDAR at 10 Hz sends its first frame a tenth of a second after the service says it is ready,
and that frame must fit the budget as the thousandth does. Each start: a fresh ``sdc-serve``
as a user starts it (2 threads, the frame budget it chooses for this CPU: ``--frame-ms`` 100),
then the first ``--frames`` frames of each condition of ``--data`` (``sdc-eval robustness``'s
frames) sent once, in order, one at a time, through ``sdcnet.client.Client`` as users send
them (the v2 route, the returns as a list, the spacecraft's window answered; the frame's
intrinsics), the cold pass; then the same frames again, the warm pass. Per frame the service's
own milliseconds (its summary's timings: inference; encode, which holds the cloud, its normals
and the answer) and the client's round trip.

Reports per condition the cold and the warm pass's median / p95 / max over every start, the
slowest cold frame, and per start the time from the process's start to ready and its resident
memory then and at the end. Writes docs/benchmarks/first_frames.md and .json.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.camera import Intrinsics
from sdcnet.client.api import Client
from sdcnet.dataset_format import SampleStore
from tests.support.serving import benchmark_model, memory_kib, service_process

PASSES = ("cold", "warm")


def condition_frames(
    root: Path, frames: int
) -> list[tuple[str, np.ndarray, np.ndarray, Intrinsics]]:
    """The first ``frames`` frames of the dataset ``root``: (frame id, gray, sparse metres,
    intrinsics)."""
    store = SampleStore(root)
    found = []
    for record in store.records[:frames]:
        sample = store.load(record)
        K = Intrinsics(**sample.meta["intrinsics"])
        found.append((record["id"], sample.gray, sample.sparse, K))
    return found


def ask(client: Client, gray: np.ndarray, sparse: np.ndarray, K: Intrinsics) -> dict[str, float]:
    """One frame's milliseconds: the service's work (inference; encode: the cloud, its normals
    and the answer) and the client's round trip."""
    answer = client.complete(gray, sparse, intrinsics=K)
    phases = answer.timings_ms
    inference = phases.get("inference_ms", 0.0)
    return {
        "work": inference + phases.get("encode_ms", 0.0),
        "inference": inference,
        "round_trip": answer.latency_s * 1e3,
    }


def one_start(model: Path, frames: dict[str, list], workdir: Path) -> dict:
    """A fresh service: the cold pass over every condition's frames, then the warm pass."""
    started = time.perf_counter()
    with service_process(model, workdir / "serve.log", "--threads=2", "--frame-ms=100") as service:
        ready_s = time.perf_counter() - started
        memory_ready = memory_kib(service.pid)["rss"] / 1024
        timings: dict[str, dict[str, list]] = {name: {p: [] for p in PASSES} for name in frames}
        with Client(service.url) as client:
            share = client.model()["frame_budget"]["frame_share"]
            for kind in PASSES:
                for name, found in frames.items():
                    for frame_id, gray, sparse, K in found:
                        shot = ask(client, gray, sparse, K)
                        timings[name][kind].append({"frame": frame_id, **shot})
        memory_end = memory_kib(service.pid)["rss"] / 1024
    return {
        "ready_s": ready_s,
        "rss_ready_mib": memory_ready,
        "rss_end_mib": memory_end,
        "frame_share": share,
        "timings": timings,
    }


def summary(starts: list[dict], name: str, kind: str, key: str) -> dict[str, float]:
    """Median, p95 and max of one pass's ``key`` milliseconds over every start."""
    ms = np.array([shot[key] for s in starts for shot in s["timings"][name][kind]])
    return {
        "median": float(np.median(ms)),
        "p95": float(np.percentile(ms, 95)),
        "max": float(ms.max()),
    }


def report(starts: list[dict], conditions: list[str], command: str, model: str) -> str:
    """The markdown report: each condition's passes, each start's readiness and memory, and
    the slowest cold frame."""
    lines = [
        f"Measured on {cpu_description()}: {len(starts)} fresh starts of `sdc-serve` on {model} "
        "(2 threads, the frame budget it chose for this CPU), each sent the first frames of "
        "each condition once (cold), then the same frames again (warm), one at a time, by "
        "`sdcnet.client.Client`. The service's work is its inference and encode (the cloud, its "
        "normals and the answer); the round trip is the client's.",
        "",
        f"Regenerate: `{command}`.",
        "",
        "| condition | pass | frames | work ms median | p95 | max | round trip ms median | p95 "
        "| max |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in conditions:
        for kind in PASSES:
            work = summary(starts, name, kind, "work")
            trip = summary(starts, name, kind, "round_trip")
            count = sum(len(s["timings"][name][kind]) for s in starts)
            lines.append(
                f"| {name} | {kind} | {count} | {work['median']:.1f} | {work['p95']:.1f} | "
                f"{work['max']:.1f} | {trip['median']:.1f} | {trip['p95']:.1f} | "
                f"{trip['max']:.1f} |"
            )
    lines += ["", "| start | ready s | frame share | resident MiB at ready | at the end |"]
    lines.append("|---|---|---|---|---|")
    for i, s in enumerate(starts, 1):
        lines.append(
            f"| {i} | {s['ready_s']:.2f} | {s['frame_share']:.3f} | {s['rss_ready_mib']:.0f} | "
            f"{s['rss_end_mib']:.0f} |"
        )
    slowest = max(
        (
            (shot["work"], name, shot["frame"], i)
            for i, s in enumerate(starts, 1)
            for name in conditions
            for shot in s["timings"][name]["cold"]
        ),
    )
    lines += [
        "",
        f"The slowest cold frame: {slowest[1]} `{slowest[2]}` in start {slowest[3]}, "
        f"{slowest[0]:.1f} ms of the service's work.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--data", type=Path, default=Path("data/robustness"))
    p.add_argument("--conditions", nargs="+", default=["docking-2048", "any"])
    p.add_argument("--frames", type=int, default=8, help="per condition")
    p.add_argument("--starts", type=int, default=3, help="fresh services")
    p.add_argument("--out", default="first_frames", help="report name under docs/benchmarks/")
    args = p.parse_args(argv)

    for name in args.conditions:
        if not (args.data / name).is_dir():
            p.error(f"{args.data / name} does not exist: `make reports` generates the suite")
    frames = {name: condition_frames(args.data / name, args.frames) for name in args.conditions}
    starts = []
    with tempfile.TemporaryDirectory() as work:
        model, description = benchmark_model(args.model, Path(work))
        for i in range(args.starts):
            starts.append(one_start(model, frames, Path(work)))
            cold = max(shot["work"] for t in starts[-1]["timings"].values() for shot in t["cold"])
            print(
                f"start {i + 1}: ready in {starts[-1]['ready_s']:.2f} s, slowest cold frame "
                f"{cold:.1f} ms",
                flush=True,
            )
    command = (
        f"python -m benchmarks.first_frames --conditions {' '.join(args.conditions)} "
        f"--frames {args.frames} --starts {args.starts}"
    )
    body = report(starts, args.conditions, command, description)
    print(body)
    write_markdown(args.out, "The first frames after start-up", body)
    (DOCS / f"{args.out}.json").write_text(json.dumps(starts, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
