"""G: more clients than the service serves, sending frames back to back and ignoring
Retry-After."""

from __future__ import annotations

import multiprocessing
import os
import statistics
import threading
import time
from collections.abc import Callable

import httpx
import numpy as np

from benchmarks.hostile.client import Context, Outcome, count_statuses
from sdcnet.npyio import npy_bytes
from tests.support.frames import multipart_body, png_bytes, synthetic_frame

Shot = tuple[int | str, float, float]  # status (or error), seconds, the service's ms


def hammer(url: str, body: bytes, headers: dict, until: float) -> list[Shot]:
    """POST ``body`` back to back until ``until`` (time.monotonic), ignoring Retry-After."""
    shots: list[Shot] = []
    with httpx.Client(base_url=url, timeout=120) as http:
        while time.monotonic() < until:
            start = time.perf_counter()
            try:
                response = http.post("/complete", content=body, headers=headers)
                shots.append(
                    (response.status_code, time.perf_counter() - start, server_ms(response))
                )
            except httpx.HTTPError as exc:
                shots.append((f"{type(exc).__name__} ({exc})", time.perf_counter() - start, 0.0))
    return shots


def _hammers(url: str, body: bytes, headers: dict, until: float, count: int, out) -> None:
    """``count`` hammering clients at nice 10 (in a process of their own: clients on other
    machines take none of the service's CPU); their shots go to the pipe ``out``."""
    os.nice(10)
    shots: list[Shot] = []
    threads = [
        threading.Thread(target=lambda: shots.extend(hammer(url, body, headers, until)))
        for _ in range(count)
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    out.send(shots)


def server_ms(response: httpx.Response) -> float:
    """The service's own time for an answer, milliseconds: the sum of its Server-Timing
    (waiting for an in-flight place, decode, queue, inference, encode)."""
    header = response.headers.get("server-timing", "")
    return sum(float(part.split("dur=")[1]) for part in header.split(",") if "dur=" in part)


def overload(clients: int, duration_s: float = 20.0) -> Callable[[Context], Outcome]:
    """``clients`` clients sending 1024 x 1024 frames back to back for ``duration_s``,
    ignoring Retry-After: one in this process, whose answers' latency is measured, and the
    others in a process at a lower priority, as clients on other machines would be."""

    def attack(ctx: Context) -> Outcome:
        s = synthetic_frame(1024, 2)
        body, content_type = multipart_body(
            {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}
        )
        headers = {"content-type": content_type}
        quiet = hammer(ctx.url, body, headers, time.monotonic() + 2.0)[1:]
        until = time.monotonic() + duration_s
        receive, send = multiprocessing.Pipe(duplex=False)
        others = multiprocessing.get_context("fork").Process(
            target=_hammers, args=(ctx.url, body, headers, until, clients - 1, send)
        )
        others.start()
        measured = hammer(ctx.url, body, headers, until)
        shots = measured + receive.recv()
        others.join()
        statuses = [status for status, _, _ in shots]
        ctx.statuses.extend(s for s in statuses if isinstance(s, int))
        answered = [t * 1e3 for status, t, _ in measured if status == 200]
        inside = [ms for status, _, ms in shots if status == 200]
        alone_ms = statistics.median(t * 1e3 for _, t, _ in quiet)
        alone_inside = statistics.median(ms for _, _, ms in quiet)
        if not answered:
            return Outcome(
                f"{count_statuses(statuses)}; none of the measured answered", None, False
            )
        p50, p99 = (float(np.percentile(answered, q)) for q in (50, 99))
        inside_p99 = float(np.percentile(inside, 99))
        bound_ms = OVERLOAD_FRAMES * alone_ms
        ok = set(statuses) <= {200, 503} and p99 <= bound_ms
        answer = (
            f"{count_statuses(statuses)}; the measured client's answers: p50 {p50:.0f} ms, "
            f"p99 {p99:.0f} ms ({len(answered)}); alone {alone_ms:.0f} ms, bound "
            f"{OVERLOAD_FRAMES} x that = {bound_ms:.0f} ms. In the service (wait for a place, "
            f"decode to encode) p99 {inside_p99:.0f} ms of every answer, alone {alone_inside:.0f}"
        )
        return Outcome(answer, None, ok)

    return attack


#: An answered request's p99 under overload, in frame times (one request alone, measured
#: just before): "within a few frame times".
OVERLOAD_FRAMES = 5
