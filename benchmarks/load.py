"""Load and soak tests against the real service: statuses, memory and open files over time.

    python -m benchmarks.load --requests 2000 --concurrency 32      # load: docs/benchmarks/load.*
    python -m benchmarks.load --soak --duration-s 300 --rate 4      # soak: docs/benchmarks/soak.*
    python -m benchmarks.load --endpoint v2 ...     # Open Inference Protocol: load_v2.*, soak_v2.*

Starts the real service (``sdc-serve`` on 127.0.0.1, a free port, default admission limit) on
the given model (default: the shipped ``models/sdcnet.onnx``, else SDCNet with random weights),
and sends generated frames (``--size`` pixels square): gray PNG + sparse ``.npy`` to
``POST /complete``, or with ``--endpoint v2`` raw gray + the returns as a list to
``POST /v2/models/sdcnet/infer``, every output binary (as tritonclient sends by default).

- warm-up (load): ``--warmup`` requests from as many clients as the service admits at once
  (``max_in_flight``), honouring Retry-After, then a tenth of the load as the load sends it,
  so that the buffers the service keeps (Python's and glibc's allocators hold freed memory for
  reuse) exist before the RSS is read;
- load: then ``--concurrency`` clients send ``--requests`` requests back to back, ignoring
  Retry-After (the worst case: every refused client comes straight back), bounded by
  ``--duration-s`` too;
- soak: ``--rate`` requests/s in all (below what the service completes) from 4 clients for
  ``--duration-s`` seconds; the first fifth is the warm-up.

Meanwhile the server's resident memory (VmRSS) and open file descriptors are read from /proc
every ``--interval`` seconds. Passes (exit 0) when every answer is 200 or 503 (no 5xx but the
503s of admission, no transport error), the RSS grew less than ``--growth-limit-mib`` from the
end of the warm-up to the end, and the process holds no more file descriptors after the run
than after the warm-up (plus ``--fd-slack``). Writes NAME.md, NAME.json and NAME.png (RSS and
file descriptors over time) under docs/benchmarks/.

The growth bound, 64 MiB by default, is about what one 1024 x 1024 request allocates (a 5 MB
upload, the decoded and completed arrays, a 7 MB JSON answer): the allocators keep such
buffers for reuse, so the RSS at rest moves by that much from one moment to the next; a leak
grows with the number of requests instead, which the soak's slope shows.
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from benchmarks.common import DOCS, cpu_description, write_markdown
from benchmarks.service_latency import ENDPOINTS, Run, frame_bodies, send
from tests.support.background import BackgroundLoop
from tests.support.serving import memory_kib, open_fds, temporary_service

KIB_PER_MIB = 1024  # RSS is read from /proc in KiB


@dataclass(frozen=True)
class Sample:
    """The server process at one moment: seconds since the start, RSS (KiB), open fds."""

    t_s: float
    rss_kib: int
    fds: int


class Sampler(BackgroundLoop):
    """Reads the server's RSS and file descriptors from /proc every ``interval`` seconds in a
    background thread while in use."""

    def __init__(self, pid: int, interval: float):
        self.pid, self.interval = pid, interval
        self.samples: list[Sample] = []
        self.t0 = time.perf_counter()

    def now(self) -> Sample:
        sample = Sample(
            time.perf_counter() - self.t0, memory_kib(self.pid)["rss"], open_fds(self.pid)
        )
        self.samples.append(sample)
        return sample

    def loop(self, stop: threading.Event) -> None:
        while not stop.wait(self.interval):
            self.now()


def settled(sampler: Sampler, seconds: float = 2.0) -> Sample:
    """A sample taken ``seconds`` after the clients closed their connections."""
    time.sleep(seconds)
    return sampler.now()


def verdict(run: Run, warm: Sample, end: Sample, limit_mib: float, fd_slack: int) -> dict:
    """Every check the run must pass, and whether it did."""
    statuses = run.statuses()
    unexpected = {k: v for k, v in statuses.items() if k not in ("200", "503")}
    growth_mib = (end.rss_kib - warm.rss_kib) / KIB_PER_MIB
    checks = {
        "no 5xx": not any(k.startswith("5") and k != "503" for k in statuses),
        "every answer 200 or 503": not unexpected,
        f"RSS growth after warm-up < {limit_mib:g} MiB": growth_mib < limit_mib,
        f"fds after the run <= after warm-up + {fd_slack}": end.fds <= warm.fds + fd_slack,
    }
    return {"checks": checks, "unexpected": unexpected, "rss_growth_mib": growth_mib}


def plot(samples: list[Sample], warm_t: float, title: str, path: Path) -> None:
    """RSS (MiB) and open file descriptors over time, the end of the warm-up marked."""
    t = [s.t_s for s in samples]
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t, [s.rss_kib / KIB_PER_MIB for s in samples], label="RSS (MiB)", color="tab:blue")
    ax.axvline(warm_t, color="gray", ls="--", lw=1, label="end of warm-up")
    ax.set(xlabel="seconds", ylabel="server RSS (MiB)", title=title)
    fds = ax.twinx()
    fds.plot(t, [s.fds for s in samples], color="tab:orange", lw=1, label="open fds")
    fds.set_ylabel("open file descriptors")
    ax.legend(loc="upper left", fontsize=8)
    fds.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def slope_mib_per_min(samples: list[Sample], after_s: float) -> float:
    """Least-squares slope of the RSS after ``after_s``, MiB per minute."""
    points = [(s.t_s, s.rss_kib / KIB_PER_MIB) for s in samples if s.t_s >= after_s]
    if len(points) < 3:
        return 0.0
    t, rss = np.array(points).T
    return float(np.polyfit(t, rss, 1)[0] * 60)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: shipped)")
    p.add_argument("--requests", type=int, default=2000, help="load: requests in all")
    p.add_argument("--concurrency", type=int, default=32, help="load: clients")
    p.add_argument("--warmup", type=int, default=60, help="load: warm-up requests")
    p.add_argument("--soak", action="store_true", help="a soak at --rate instead of a load")
    p.add_argument("--rate", type=float, default=4.0, help="soak: requests/s in all")
    p.add_argument("--duration-s", type=float, default=None, help="bound (soak: 180 s)")
    p.add_argument("--size", type=int, default=1024, help="frame side, pixels")
    p.add_argument("--interval", type=float, default=0.5, help="seconds between samples")
    p.add_argument(
        "--growth-limit-mib",
        type=float,
        default=64.0,
        help="RSS growth allowed after the warm-up: about one 1024 x 1024 request's buffers",
    )
    p.add_argument("--fd-slack", type=int, default=4)
    p.add_argument("--endpoint", choices=ENDPOINTS, default="complete", help="which protocol")
    args = p.parse_args(argv)

    bodies = frame_bodies(4, args.size, endpoint=args.endpoint)
    with temporary_service(args.model, "--threads=2") as (service, model):
        limits = httpx.get(f"{service.url}/model").json()["limits"]
        with Sampler(service.pid, args.interval) as sampler:
            start = sampler.now()
            if args.soak:
                duration = args.duration_s or 180.0
                rate, clients = args.rate, 4
                total = int(duration * rate) + 1
                warm_t = duration / 5
                run = send(service.url, bodies, total, clients, duration_s=duration, rate=rate)
                window = [s for s in sampler.samples if warm_t <= s.t_s <= warm_t + 10]
                warm = sorted(window, key=lambda s: s.rss_kib)[len(window) // 2]  # median
            else:
                rate, clients = None, args.concurrency
                send(service.url, bodies, args.warmup, limits["max_in_flight"])
                send(service.url, bodies, args.requests // 10, clients, retry_after=False)
                warm = settled(sampler)
                warm_t = warm.t_s
                run = send(
                    service.url,
                    bodies,
                    args.requests,
                    clients,
                    duration_s=args.duration_s,
                    retry_after=False,
                )
            end = settled(sampler)
        peak = memory_kib(service.pid)["peak"]
    result = verdict(run, warm, end, args.growth_limit_mib, args.fd_slack)
    name = ("soak" if args.soak else "load") + ("_v2" if args.endpoint == "v2" else "")
    figures = {
        "model": model,
        "requests": len(run.shots),
        "clients": clients,
        "rate_per_s": rate,
        "seconds": run.seconds,
        "statuses": run.statuses(),
        "p50_ms_200": _median_ms(run, 200),
        "p50_ms_503": _median_ms(run, 503),
        "rss_mib": {
            "start": start.rss_kib / KIB_PER_MIB,
            "after_warmup": warm.rss_kib / KIB_PER_MIB,
            "end": end.rss_kib / KIB_PER_MIB,
            "peak": peak / KIB_PER_MIB,
        },
        "rss_slope_after_warmup_mib_per_min": slope_mib_per_min(sampler.samples, warm_t),
        "fds": {
            "start": start.fds,
            "after_warmup": warm.fds,
            "max": max(s.fds for s in sampler.samples),
            "end": end.fds,
        },
        **result,
    }
    print(json.dumps(figures, indent=1))
    write_report(name, args, figures, limits)
    (DOCS / f"{name}.json").write_text(json.dumps(figures, indent=1))
    plot(sampler.samples, warm_t, f"{name}: server RSS and open files", DOCS / f"{name}.png")
    return 0 if all(result["checks"].values()) else 1


def write_report(name: str, args: argparse.Namespace, f: dict, limits: dict) -> None:
    if args.soak:
        command = f"python -m benchmarks.load --soak --duration-s {args.duration_s or 180:g} "
        command += f"--rate {args.rate:g}"
        how = (
            f"{f['clients']} clients at {args.rate:g} requests/s in all for {f['seconds']:.0f} s; "
            "the first fifth is the warm-up"
        )
    else:
        command = f"python -m benchmarks.load --requests {args.requests} "
        command += f"--concurrency {args.concurrency}"
        command += f" --duration-s {args.duration_s:g}" if args.duration_s else ""
        how = (
            f"Warm-up: {args.warmup} requests from {limits['max_in_flight']} clients (the "
            f"admission limit), then {args.requests // 10} as the load. Load: {f['clients']} "
            "clients back to back, ignoring Retry-After (each refused client comes straight "
            "back); the figures below are the load's"
        )
    if args.endpoint == "v2":
        command += " --endpoint v2"
        frames = (
            "raw gray UINT8 + the returns as an FP32 list to `POST /v2/models/sdcnet/infer`, "
            "binary full-frame answers"
        )
    else:
        frames = "gray PNG + sparse float32 `.npy` to `POST /complete`, JSON answers"
    checks = "\n".join(f"| {k} | {'pass' if v else 'FAIL'} |" for k, v in f["checks"].items())
    statuses = ", ".join(f"{k}: {v}" for k, v in f["statuses"].items())
    rss, fds = f["rss_mib"], f["fds"]
    slope = f" (trend {f['rss_slope_after_warmup_mib_per_min']:+.2f} MiB/min)" if args.soak else ""
    body = f"""
Real HTTP on 127.0.0.1 against `sdc-serve` (2 onnxruntime threads, at most
{limits["max_in_flight"]} requests in flight, the others 503 at once) on {cpu_description()};
model: {f["model"]}. Frames: 4 generated {args.size} x {args.size} spacecraft, {frames}.
{how}. The server's RSS (VmRSS) and open file descriptors are read from /proc every
{args.interval:g} s. Regenerate: `{command}`.

| figure | value |
|---|---|
| requests | {f["requests"]} in {f["seconds"]:.1f} s |
| statuses | {statuses} |
| p50 of the 200 / 503 answers | {_ms(f["p50_ms_200"])} / {_ms(f["p50_ms_503"])} ms |
| RSS at start / after warm-up / end (MiB) | {_slashed(rss, "start", "after_warmup", "end")} |
| RSS growth after warm-up | {f["rss_growth_mib"]:+.1f} MiB{slope} |
| peak RSS (VmHWM) | {rss["peak"]:.1f} MiB |
| open fds at start / after warm-up / max / end | {_slashed(fds, *fds)} |

| check | result |
|---|---|
{checks}

![RSS and file descriptors over time]({name}.png)
"""
    title = "Soak: memory and file descriptors" if args.soak else "Load: 200 or 503, never 5xx"
    print(write_markdown(name, title, body))


def _median_ms(run: Run, status: int) -> float | None:
    """Median end-to-end milliseconds of the answers with ``status`` (None when none)."""
    times = [s.seconds * 1e3 for s in run.shots if s.status == status]
    return float(np.median(times)) if times else None


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f}"


def _slashed(values: dict, *keys: str) -> str:
    return " / ".join(
        f"{values[k]:.1f}" if isinstance(values[k], float) else str(values[k]) for k in keys
    )


if __name__ == "__main__":
    raise SystemExit(main())
