"""The wire: what each way of calling the service costs beyond the pipeline itself.

    python -m benchmarks.wire [--model models/sdcnet.onnx] [--rounds 30] [--threads 2]
                              [--meshes ../shared/real-meshes --mesh cassini.stl]

Two 1024 x 1024 frames: one of the test split of ``data/paper`` (a generated frame when the
dataset is absent) and one rendered from a real NASA mesh (``--mesh``, by the dataset
generator, as ``sdc-eval real`` renders them). For each, in one run and interleaved round by
round (every path once per round, in a rotating order, so that the machine's load falls on all
of them alike):

- **in-process pipeline**: what the service does for one request without HTTP, in this process
  on its own onnxruntime session with the same threads: the returns list checked and made a
  map, the crop-infer-paste pipeline, the point cloud and its normals (``frame_of`` +
  ``complete_frame``);
- **Client.complete**: the Python client (arrays in, full-frame arrays out), one keep-alive
  connection;
- **sdc-client infer**: the command as a process (Python start-up included) on a PNG and a
  CSV of returns, writing its four files; its own round-trip figure is reported too;
- **tritonclient.http**: Triton's client, binary tensors (gray UINT8, returns FP32) in, the
  full-frame depth, mask and points out;
- **POST /complete**: a multipart form as curl sends it (gray PNG, returns ``.npy``) on a
  keep-alive connection of the standard library's ``http.client`` (as lean as curl), the
  answer as npz and as JSON, read whole; and, for comparison, the npz answer to the dense
  4 MiB ``.npy`` map the service used to need.

Reports p50 and p95 of each and their ratio to the in-process pipeline's, the server's median
phases (its ``Server-Timing``), the CPU time each call cost the server and the caller (from
/proc and getrusage: a measure of where the time goes that the machine's other load does not
blur as much as wall time) and the bytes each way, against the targets: Client.complete and
tritonclient <= 1.25x the in-process pipeline at p50, POST /complete npz <= 1.5x. Writes
docs/benchmarks/wire.md and wire.json.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import tritonclient.http as triton

from benchmarks.common import DOCS, cpu_description, write_markdown
from benchmarks.service_latency import server_timing
from sdcnet.allocator import configure_malloc
from sdcnet.client.api import Client
from sdcnet.client.transport import Transport
from sdcnet.dataset_format import Sample, SampleStore, read_sample
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense, write_returns_csv
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.service.decode import InputLimits, frame_of
from sdcnet.service.inference import Engine, PhaseTimer, complete_frame
from sdcnet.service.settings import Settings
from tests.support.frames import generated_samples, multipart_body, png_bytes
from tests.support.serving import benchmark_model, service_process

PATHS = (
    "in-process pipeline",
    "Client.complete",
    "sdc-client infer (process)",
    "tritonclient.http, binary",
    "POST /complete, npz",
    "POST /complete, json",
    "POST /complete, npz, dense map",
)
TARGETS = {"Client.complete": 1.25, "tritonclient.http, binary": 1.25, "POST /complete, npz": 1.5}
_CLI_LATENCY = re.compile(r"latency\s+([\d.]+) ms round trip")


@dataclass
class Shot:
    """One call: wall seconds, the server's phases (ms), bytes sent and received, CPU
    seconds it cost the server and the caller (this process and its children)."""

    seconds: float
    phases_ms: dict[str, float] = field(default_factory=dict)
    sent: int = 0
    received: int = 0
    reported_ms: float | None = None  # what sdc-client itself printed
    server_cpu_s: float = 0.0
    caller_cpu_s: float = 0.0


def process_cpu_s(pid: int) -> float:
    """CPU seconds (user + system) process ``pid`` has used, from /proc/PID/stat."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def caller_cpu_s() -> float:
    """CPU seconds this process and its finished children have used."""
    own, children = (
        resource.getrusage(w) for w in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
    )
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def test_split_frame(data: Path) -> tuple[Sample, str]:
    """The first frame of the test split of ``data``, else of a test model among the files
    written so far (a dataset still being generated), else a generated frame."""
    if (data / "manifest.jsonl").exists():
        store = SampleStore(data)
        record = store.split("test")[0]
        return store.load(record), f"`{data}` test split, {record['id']}"
    if (data / "dataset.json").exists():
        splits = json.loads((data / "dataset.json").read_text())["model_split"]
        for path in sorted((data / "samples").glob("*.npz")):
            if splits.get(str(int(path.name[1:5]))) == "test":
                return read_sample(path), f"`{data}` test split, {path.stem}"
    return generated_samples(1024, 1)[0], "a generated frame (seed 5; no dataset at data/paper)"


def real_mesh_frame(folder: Path, mesh: str) -> tuple[Sample, str]:
    """View 0 of ``mesh`` (a file of the mesh ``folder``) rendered by the generator."""
    from sdcnet.meshes import read_mesh_folder
    from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample

    entry = next(e for e in read_mesh_folder(folder) if e.path.name == mesh)
    config = GenerateConfig(models=0, views=1, seed=0, meshes=(entry,), split=(0, 0, 0))
    sample = make_sample(config, build_spacecraft(config, 0), 0, 0, "real")
    return sample, f"real mesh `{mesh}` at {sample.meta['distance_m']:.0f} m (seed 0, view 0)"


class Paths:
    """Every way of completing one frame, each a callable that returns a ``Shot``."""

    def __init__(self, url: str, engine: Engine, sample: Sample, work: Path, limits: InputLimits):
        self.url, self.engine, self.limits = url, engine, limits
        self.gray = sample.gray
        self.returns = returns_from_dense(sample.sparse)
        self.client = Client(url)
        self.triton = triton.InferenceServerClient(url.removeprefix("http://"))
        # curl's part: a lean keep-alive HTTP/1.1 connection (the standard library's)
        self.http = Transport(url, timeout_s=120, connect_timeout_s=5)
        gray_png = png_bytes(sample.gray)
        self.files = work / "gray.png", work / "returns.csv", work / "out"
        self.files[0].write_bytes(gray_png)
        write_returns_csv(self.files[1], self.returns)
        gray_file = ("gray.png", gray_png)
        self.listed = multipart_body(
            {"gray": gray_file, "returns": ("returns.npy", npy_bytes(self.returns))}
        )
        self.dense = multipart_body(
            {"gray": gray_file, "sparse": ("sparse.npy", npy_bytes(sample.sparse))}
        )

    def close(self) -> None:
        self.client.close()
        self.triton.close()
        self.http.close()

    def calls(self) -> dict[str, Callable[[], Shot]]:
        return dict(
            zip(
                PATHS,
                (
                    self.in_process,
                    self.python_client,
                    self.cli,
                    self.tritonclient,
                    lambda: self.form(self.listed, "npz"),
                    lambda: self.form(self.listed, "json"),
                    lambda: self.form(self.dense, "npz"),
                ),
                strict=True,
            )
        )

    def in_process(self) -> Shot:
        timer = PhaseTimer()
        start = time.perf_counter()
        with timer("decode"):
            frame = frame_of(self.gray, None, self.returns, self.limits)
        done = complete_frame(self.engine, frame, timer)
        with timer("encode"):  # the normals are made when an answer carries them
            _ = done.normals
        return Shot(time.perf_counter() - start, {p: s * 1e3 for p, s in timer.seconds.items()})

    def python_client(self) -> Shot:
        start = time.perf_counter()
        result = self.client.complete(self.gray, returns=self.returns)
        seconds = time.perf_counter() - start
        sent = self.gray.nbytes + self.returns.nbytes
        received = result.depth.nbytes + result.mask.nbytes + result.points.nbytes
        phases = {k.removesuffix("_ms"): v for k, v in result.timings_ms.items()}
        return Shot(seconds, phases, sent, received)

    def cli(self) -> Shot:
        gray, csv, out = self.files
        command = [sys.executable, "-m", "sdcnet.client", "infer", str(gray), str(csv)]
        command += ["--url", self.url, "--out", str(out)]
        start = time.perf_counter()
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        seconds = time.perf_counter() - start
        reported = _CLI_LATENCY.search(done.stdout)
        return Shot(seconds, reported_ms=float(reported.group(1)) if reported else None)

    def tritonclient(self) -> Shot:
        inputs = []
        for name, array, datatype in (
            ("gray", self.gray, "UINT8"),
            ("returns", self.returns, "FP32"),
        ):
            tensor = triton.InferInput(name, list(array.shape), datatype)
            tensor.set_data_from_numpy(array, binary_data=True)
            inputs.append(tensor)
        outputs = [triton.InferRequestedOutput(n) for n in ("depth", "mask", "points")]
        start = time.perf_counter()
        result = self.triton.infer("sdcnet", inputs, outputs=outputs)
        arrays = [result.as_numpy(n) for n in ("depth", "mask", "points")]
        seconds = time.perf_counter() - start
        parameters = result.get_response()["parameters"]
        phases = {p: parameters[f"{p}_ms"] for p in ("decode", "queue", "inference", "encode")}
        sent = self.gray.nbytes + self.returns.nbytes
        return Shot(seconds, phases, sent, sum(a.nbytes for a in arrays))

    def form(self, body: tuple[bytes, str], answer: str) -> Shot:
        start = time.perf_counter()
        response = self.http.request(
            "POST",
            "/complete",
            content=body[0],
            headers={"content-type": body[1]},
            params={"format": answer},
        )
        seconds = time.perf_counter() - start
        if response.is_error:
            raise RuntimeError(f"POST /complete answered {response.status_code}: {response.text}")
        phases = server_timing(response.headers.get("server-timing"))
        return Shot(seconds, phases, len(body[0]), len(response.content))


def measure(paths: Paths, server_pid: int, rounds: int, warmup: int = 2) -> dict[str, list[Shot]]:
    """``rounds`` rounds of every path, in an order that rotates each round; one call at a
    time, so the server's CPU during a call is that call's."""
    calls = paths.calls()
    names = list(calls)
    for _ in range(warmup):
        for name in names:
            calls[name]()
    shots: dict[str, list[Shot]] = {name: [] for name in names}
    for r in range(rounds):
        for name in names[r % len(names) :] + names[: r % len(names)]:
            server, caller = process_cpu_s(server_pid), caller_cpu_s()
            shot = calls[name]()
            shot.server_cpu_s = process_cpu_s(server_pid) - server
            shot.caller_cpu_s = caller_cpu_s() - caller
            shots[name].append(shot)
    return shots


def summarise(shots: dict[str, list[Shot]]) -> dict[str, dict]:
    """p50 / p95 (ms) of each path, ratios to the in-process pipeline, median phases, bytes."""
    base = np.array([s.seconds for s in shots[PATHS[0]]]) * 1e3
    base_p50, base_p95 = np.percentile(base, 50), np.percentile(base, 95)
    rows = {}
    for name, runs in shots.items():
        ms = np.array([s.seconds for s in runs]) * 1e3
        phases = {
            p: float(np.median([s.phases_ms.get(p, 0.0) for s in runs]))
            for p in ("decode", "queue", "inference", "encode")
        }
        reported = [s.reported_ms for s in runs if s.reported_ms is not None]
        rows[name] = {
            # means: /proc counts CPU in clock ticks (10 ms), too coarse for a median
            "server_cpu_ms": 1e3 * float(np.mean([s.server_cpu_s for s in runs])),
            "caller_cpu_ms": 1e3 * float(np.mean([s.caller_cpu_s for s in runs])),
            "p50_ms": float(np.percentile(ms, 50)),
            "p95_ms": float(np.percentile(ms, 95)),
            "ratio_p50": float(np.percentile(ms, 50) / base_p50),
            "ratio_p95": float(np.percentile(ms, 95) / base_p95),
            "median_phase_ms": phases,
            "sent_bytes": runs[0].sent,
            "received_bytes": runs[0].received,
            "runs": len(runs),
            "reported_round_trip_p50_ms": float(np.median(reported)) if reported else None,
        }
    return rows


def table(rows: dict[str, dict]) -> str:
    lines = [
        "| path | p50 ms | p95 ms | p50 / in-process | p95 / in-process | target | server "
        "decode / inference / encode ms | CPU ms: server + caller | bytes up / down |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        target = TARGETS.get(name)
        verdict = (
            ""
            if target is None
            else f"<= {target}x: {'met' if r['ratio_p50'] <= target else 'NOT met'}"
        )
        ph = r["median_phase_ms"]
        phases = f"{ph['decode']:.1f} / {ph['inference']:.1f} / {ph['encode']:.1f}"
        size = f"{_kb(r['sent_bytes'])} / {_kb(r['received_bytes'])}" if r["sent_bytes"] else "-"
        label = name
        if r["reported_round_trip_p50_ms"] is not None:
            label += f" (its own round trip: p50 {r['reported_round_trip_p50_ms']:.1f} ms)"
        lines.append(
            f"| {label} | {r['p50_ms']:.1f} | {r['p95_ms']:.1f} | {r['ratio_p50']:.2f}x | "
            f"{r['ratio_p95']:.2f}x | {verdict} | {phases} | {r['server_cpu_ms']:.0f} + "
            f"{r['caller_cpu_ms']:.0f} | {size} |"
        )
    return "\n".join(lines)


def _kb(n: int) -> str:
    return f"{n / 1024:.0f} KiB" if n < 2**20 else f"{n / 2**20:.2f} MiB"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--rounds", type=int, default=30, help="calls of every path per frame")
    p.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    p.add_argument("--data", type=Path, default=Path("data/paper"))
    p.add_argument(
        "--meshes", type=Path, default=Path("../shared/real-meshes"), help="real-mesh folder"
    )
    p.add_argument("--mesh", default="cassini.stl", help="file of the real-mesh folder")
    args = p.parse_args(argv)
    # the in-process pipeline's allocator as sdc-serve sets it: without it, each 2048 x 2048
    # map of every frame was mapped afresh and faulted in, 1.6x the service's CPU per frame
    configure_malloc()

    frames = [test_split_frame(args.data), real_mesh_frame(args.meshes, args.mesh)]
    results = {}
    load_before = os.getloadavg()
    settings = Settings()
    limits = InputLimits(settings.max_pixels, settings.max_returns)
    with tempfile.TemporaryDirectory() as work:
        path, model = benchmark_model(args.model, Path(work))
        log = Path(work) / "serve.log"
        with service_process(path, log, f"--threads={args.threads}") as service:
            meta = httpx.get(f"{service.url}/model").json()
            # the service's own session options: threads, and its idle threads sleeping
            engine = Engine(OnnxModel(path, "cpu", args.threads, Settings().spin_wait))
            for sample, description in frames:
                paths = Paths(service.url, engine, sample, Path(work), limits)
                try:
                    rows = summarise(measure(paths, service.pid, args.rounds))
                finally:
                    paths.close()
                returns = int(np.count_nonzero(sample.sparse))
                results[description] = {"returns": returns, "rows": rows}
                print(description, json.dumps(rows, indent=1), flush=True)
    load = {"before": load_before, "after": os.getloadavg()}
    write_report(args, model, meta, results, load)
    return 0


def write_report(
    args: argparse.Namespace, model: str, meta: dict, results: dict, load: dict
) -> None:
    sections = []
    for description, result in results.items():
        sections.append(
            f"### {description}, {result['returns']} returns\n\n{table(result['rows'])}\n"
        )
    body = f"""
Measured in one run by `python -m benchmarks.wire --rounds {args.rounds} --threads {args.threads}`
on {cpu_description()}: `sdc-serve` in its own process on 127.0.0.1 ({args.threads} onnxruntime
threads), the clients and the in-process pipeline in this one (its own onnxruntime session, the
same threads), {args.rounds} rounds, every path once per round in a rotating order. Model:
{model} (version `{meta["version"]}`, {meta["provider"]}). Times are wall clock at the caller
(for sdc-client: the whole process, Python start-up included; its own round-trip figure beside
it); server phases are the service's medians. "bytes up / down": the request's tensors or body,
and what the caller received (for Client.complete and tritonclient: the full-frame arrays they
hand back). "CPU ms": mean CPU time per call of the server process and of the caller
(for sdc-client: the process it starts). The machine's load average (1, 5, 15 min) was
{_load(load["before"])} before the run and {_load(load["after"])} after it, on 2 cores: other
jobs ran beside it, so wall times are slower than on a quiet machine; the interleaving puts that
load on every path alike.

Targets: Client.complete and tritonclient <= 1.25x the in-process pipeline at p50, POST /complete
npz <= 1.5x.

{chr(10).join(sections)}
"""
    print(
        write_markdown(
            "wire", "The wire: each way of calling the service against the pipeline", body
        )
    )
    (DOCS / "wire.json").write_text(
        json.dumps(
            {"model": model, "rounds": args.rounds, "load_average": load, "frames": results},
            indent=1,
        )
    )


def _load(values: tuple[float, float, float]) -> str:
    return " / ".join(f"{v:.1f}" for v in values)


if __name__ == "__main__":
    raise SystemExit(main())
