"""Hostile and careless clients against the real service: every attack of issue 21 and more,
with the server's peak memory, ``/ready``'s latency meanwhile and a verdict for each.

    python -m benchmarks.hostile [--model PATH] [--only A,B1,...] [--name hostile] [--note TEXT]

Starts ``sdc-serve`` on 127.0.0.1 (a free port, 2 onnxruntime threads, every other setting its
default, a targets folder of one mesh for ``POST /pose``) on the tiny sdcnet-shaped model
(``sdcnet.devtools.models.tiny_model``: it calls every bright pixel spacecraft, so a bright
frame is all foreground, the worst case for the point cloud) or ``--model``. After a warm-up
(valid frames on every route) the resident memory is the baseline. Then each attack runs in
turn: the server's peak resident memory is reset (``/proc/PID/clear_refs``) before it and read
(VmHWM) after it, and a thread polls ``GET /ready`` every 0.1 s meanwhile.

An attack passes when its own check holds (the status it must get, valid clients served, the
connection closed in time), its peak stays under 512 MiB above the baseline and ``/ready``
answered within 1 s throughout. The start-up attacks (I) run ``sdc-serve`` on broken targets
folders instead. Writes docs/benchmarks/NAME.md and NAME.json; exits 1 when an attack fails.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
from pathlib import Path

import httpx
import numpy as np
import yaml

from benchmarks.common import DOCS, cpu_description, write_markdown
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense
from tests.support.attacks import (
    LIBRARY_HINTS,
    ReadyWatch,
    Trickler,
    bright_frame,
    closed_within,
    connect,
    csv_returns,
    huge_integer,
    nested_json,
    request_head,
    reset_peak,
    status_of,
    v2_json_zeros,
)
from tests.support.frames import multipart_body, png_bytes, synthetic_frame, v2_body
from tests.support.models import tiny_model
from tests.support.serving import memory_kib, service_process
from tests.support.targets import probe_mesh, write_targets

PEAK_LIMIT_MIB = 512.0  # no request may raise the peak by more over the warm baseline
READY_LIMIT_MS = 1000.0  # /ready answers within this during every attack
REFUSE_LIMIT_S = 2.0  # oversized inputs are refused within this
CLOSE_LIMIT_S = 30.0  # a half-open or idle connection is closed within this
WAIT_S = 35.0  # how long the connection attacks wait for the server to close
V2 = "/v2/models/sdcnet/infer"
#: Resident memory an attack may leave above the warm baseline (the allocators keep what they
#: freed, for reuse) before the service is restarted, so that the next attack's peak is its own.
RETAINED_LIMIT_MIB = 64
DEPLOYMENT = Path(__file__).resolve().parent.parent / "deploy" / "deployment.yaml"


@dataclass(frozen=True)
class Outcome:
    """What one attack did: its answer in words, the seconds it took (None: not a request),
    and whether its own check held."""

    answer: str
    seconds: float | None
    ok: bool


@dataclass
class Context:
    """The running service and what the attacks share."""

    url: str
    pid: int
    model: Path
    work: Path
    limits: dict
    warm_kib: int = 0
    peaks_mib: dict[str, float] = field(default_factory=dict)  # each attack's, once run
    messages: list[str] = field(default_factory=list)  # every error message answered
    statuses: list[int] = field(default_factory=list)  # every status answered

    @property
    def side(self) -> int:
        """Side of the largest square frame the service takes, pixels."""
        return math.isqrt(self.limits["max_pixels"])

    def post(self, path: str, timeout: float = 300.0, **kwargs) -> tuple[httpx.Response, float]:
        """POST, recording the status and the error message; (response, seconds)."""
        start = time.perf_counter()
        response = httpx.post(f"{self.url}{path}", timeout=timeout, **kwargs)
        seconds = time.perf_counter() - start
        self.statuses.append(response.status_code)
        if response.status_code >= 400:
            self.messages.append(error_message(response))
        return response, seconds


def error_message(response: httpx.Response) -> str:
    """The message of an error answer (either shape), else its text."""
    try:
        error = response.json()["error"]
    except (ValueError, KeyError, TypeError):
        return response.text[:300]
    return error["message"] if isinstance(error, dict) else str(error)


def code_of(response: httpx.Response) -> str:
    """'STATUS code' of an answer (the code from the body or the v2 header)."""
    code = response.headers.get("sdcnet-error-code")
    if code is None and response.status_code >= 400:
        try:
            code = response.json()["error"]["code"]
        except (ValueError, KeyError, TypeError):
            code = None
    return f"{response.status_code}" + (f" {code}" if code else "")


# -- requests the attacks are made of ---------------------------------------------------------


def frame_files(size: int = 256, seed: int = 1) -> dict:
    s = synthetic_frame(size, seed)
    return {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}


def valid(ctx: Context, size: int = 256) -> int:
    """A valid ``POST /complete``'s status."""
    response, _ = ctx.post("/complete", files=frame_files(size), timeout=60)
    return response.status_code


def expect(
    response: httpx.Response, seconds: float, status: int, code: str, limit_s: float
) -> Outcome:
    """The answer must be ``status`` with the error ``code`` within ``limit_s``."""
    ok = code_of(response) == f"{status} {code}" and seconds <= limit_s
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, ok)


def expect_refused(response: httpx.Response, seconds: float) -> Outcome:
    """An oversized input: a 4xx within ``REFUSE_LIMIT_S``."""
    ok = 400 <= response.status_code < 500 and seconds <= REFUSE_LIMIT_S
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, ok)


def count_statuses(statuses: list[int | str]) -> str:
    return ", ".join(f"{k}: {statuses.count(k)}" for k in sorted(set(statuses), key=str))


# -- A: uploads that trickle ------------------------------------------------------------------


def trickling_uploads(ctx: Context) -> Outcome:
    """4 uploads of a valid frame's form, one byte every 2 s; 10 valid requests, one a
    second, meanwhile."""
    body, content_type = multipart_body(frame_files(128))
    with Trickler(ctx.url, "/complete", 4, body, content_type, 2.0) as trickle:
        time.sleep(1.0)
        statuses = []
        for _ in range(10):
            statuses.append(valid(ctx))
            time.sleep(1.0)
        ended = list(trickle.ended)
        elapsed = time.monotonic() - trickle.start
    cut = [e for e in ended if e is not None]
    fate = (
        f"{len(cut)} of 4 tricklers cut ({', '.join(f'{s} at {t:.1f} s' for t, s in cut)})"
        if cut
        else f"the 4 tricklers still uploading after {elapsed:.0f} s"
    )
    ok = statuses.count(200) >= 9
    return Outcome(
        f"{statuses.count(200)}/10 valid 200 ({count_statuses(statuses)}); {fate}", None, ok
    )


# -- B: memory ---------------------------------------------------------------------------------


def v2_json(count: int) -> Callable[[Context], Outcome]:
    def attack(ctx: Context) -> Outcome:
        body = v2_json_zeros(count)
        headers = {"content-type": "application/json"}
        return expect_refused(*ctx.post(V2, content=body, headers=headers))

    attack.__doc__ = f"v2 JSON: a [1, 1] gray whose data holds {count:,} zeros"
    return attack


def bright_form(side: int, every: int = 4) -> tuple[bytes, str]:
    gray, returns = bright_frame(side, every)
    files = {"gray": ("g.png", gray), "returns": ("r.npy", returns)}
    return multipart_body(files, {"outlier_removal": "true"})


def frame_4096(ctx: Context) -> Outcome:
    body, content_type = bright_form(4096)
    response, seconds = ctx.post("/complete", content=body, headers={"content-type": content_type})
    ok = response.status_code < 500 and (response.status_code != 200 or seconds < 10)
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, ok)


def largest_upload(ctx: Context) -> Outcome:
    """The largest frame with the largest files it may come in: a 16-bit gray PNG of noise
    (incompressible) and a float64 dense sparse ``.npy``; outlier removal, JSON answer."""
    rng = np.random.default_rng(0)
    gray = rng.integers(32768, 65536, (ctx.side, ctx.side), dtype=np.uint16)
    sparse = np.zeros((ctx.side, ctx.side))
    sparse[::4, ::4] = 100.0
    files = {"gray": ("g.png", png_bytes(gray)), "sparse": ("s.npy", npy_bytes(sparse))}
    body, content_type = multipart_body(files, {"outlier_removal": "true"})
    response, seconds = ctx.post("/complete", content=body, headers={"content-type": content_type})
    answer = f"{len(body) / 2**20:.0f} MiB: {code_of(response)} in {seconds:.2f} s"
    return Outcome(answer, seconds, response.status_code in (200, 413))


def largest_pose(ctx: Context) -> Outcome:
    """The largest bright frame on ``POST /pose``: a cloud of a quarter of the frame's pixels
    to register (or refuse)."""
    gray, returns = bright_frame(ctx.side, 4)
    files = {"gray": ("g.png", gray), "returns": ("r.npy", returns)}
    response, seconds = ctx.post("/pose", files=files, data={"target": "probe"})
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, response.status_code < 500)


def largest_frame(ctx: Context) -> Outcome:
    body, content_type = bright_form(ctx.side)
    response, seconds = ctx.post("/complete", content=body, headers={"content-type": content_type})
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, response.status_code == 200)


def four_largest_frames(ctx: Context) -> Outcome:
    """4 of ``largest_frame`` at once: the server's peak must stay within the Deployment's
    memory limit."""
    alone = ctx.peaks_mib.get("B4")
    if alone is None or alone > PEAK_LIMIT_MIB:
        return Outcome("not run: B4 alone was not run, or exceeded the peak limit", None, False)
    body, content_type = bright_form(ctx.side)
    results: list[tuple[int, float]] = []

    def one() -> None:
        response, seconds = ctx.post(
            "/complete", content=body, headers={"content-type": content_type}
        )
        results.append((response.status_code, seconds))

    threads = [threading.Thread(target=one) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    peak_mib = memory_kib(ctx.pid)["peak"] / 1024
    limit_mib = deployment_limit_mib()
    statuses = [s for s, _ in results]
    ok = peak_mib <= limit_mib and all(s in (200, 503) for s in statuses)
    answer = (
        f"{count_statuses(statuses)}, slowest {max(t for _, t in results):.1f} s; server peak "
        f"{peak_mib:.0f} MiB, Deployment limit {limit_mib:.0f} MiB"
    )
    return Outcome(answer, None, ok)


#: Side of the frames of B6 and B7 at most, pixels: what they cost before issue 21 grows with
#: the square of the side (gigabytes at 4096), and 2048 shows it.
JSON_SIDE = 2048


def largest_frame_json_outputs(ctx: Context) -> Outcome:
    """The largest bright frame (at most ``JSON_SIDE``) over v2 (binary inputs), every output
    asked as JSON data."""
    side = min(ctx.side, JSON_SIDE)
    gray = np.full((side, side), 255, np.uint8)
    rows, cols = np.mgrid[0:side:4, 0:side:4]
    returns = np.stack([rows.ravel(), cols.ravel(), np.full(rows.size, 100.0)], 1)
    content, headers = v2_body(gray, returns.astype(np.float32))
    header_length = int(headers["Inference-Header-Content-Length"])
    document = json.loads(content[:header_length])
    document["parameters"] = {"binary_data_output": False}
    header = json.dumps(document).encode()
    headers = {"Inference-Header-Content-Length": str(len(header))}
    response, seconds = ctx.post(V2, content=header + content[header_length:], headers=headers)
    ok = response.status_code in (200, 413)
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, ok)


def json_gray_of_largest_frame(ctx: Context) -> Outcome:
    """v2 JSON: the largest gray (at most ``JSON_SIDE``) as JSON data (a legitimate, heavy
    request)."""
    side = min(ctx.side, JSON_SIDE)
    gray = synthetic_frame(side, 1)
    inputs = [
        {"name": "gray", "datatype": "UINT8", "shape": [side] * 2},
        {"name": "returns", "datatype": "FP32", "shape": [0, 3]},
    ]
    returns = returns_from_dense(gray.sparse)
    inputs[1]["shape"] = list(returns.shape)
    inputs[0]["data"] = gray.gray.ravel().tolist()
    inputs[1]["data"] = returns.ravel().tolist()
    body = json.dumps({"inputs": inputs, "outputs": [{"name": "mask"}]}).encode()
    response, seconds = ctx.post(V2, content=body, headers={"content-type": "application/json"})
    ok = response.status_code in (200, 413)
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, ok)


# -- C: long CSV files -------------------------------------------------------------------------


def long_csv(lines: int | None) -> Callable[[Context], Outcome]:
    """A returns CSV of ``lines`` lines (None: as many as the service takes for the largest
    frame) with a bad last line, beside the largest frame's gray."""

    def attack(ctx: Context) -> Outcome:
        count = lines or min(ctx.limits.get("max_returns", ctx.side**2), ctx.side**2)
        gray = png_bytes(np.zeros((ctx.side, ctx.side), np.uint8))
        files = {"gray": ("g.png", gray), "returns": ("r.csv", csv_returns(count))}
        body, content_type = multipart_body(files)
        response, seconds = ctx.post(
            "/complete", content=body, headers={"content-type": content_type}
        )
        oversized = count > min(ctx.limits.get("max_returns", ctx.side**2), ctx.side**2)
        limit = REFUSE_LIMIT_S if oversized else 10.0
        ok = 400 <= response.status_code < 500 and seconds <= limit
        return Outcome(f"{count:,} lines: {code_of(response)} in {seconds:.2f} s", seconds, ok)

    return attack


# -- D, E: intrinsics --------------------------------------------------------------------------


def form_intrinsics(fields: dict[str, str], path: str = "/complete") -> Callable:
    def attack(ctx: Context) -> Outcome:
        data = dict(fields)
        if path == "/pose":
            data["target"] = "probe"
        files = frame_files(1024 if fields.get("fx") == "1" else 256)
        response, seconds = ctx.post(path, files=files, data=data)
        return expect(response, seconds, 422, "invalid_intrinsics", 10.0)

    return attack


def v2_intrinsics(parameters: dict[str, float]) -> Callable[[Context], Outcome]:
    def attack(ctx: Context) -> Outcome:
        s = synthetic_frame(256, 1)
        content, headers = v2_body(s.gray, returns_from_dense(s.sparse))
        length = int(headers["Inference-Header-Content-Length"])
        document = json.loads(content[:length])
        document["parameters"] = {**document["parameters"], **parameters}
        header = json.dumps(document).encode()
        headers = {"Inference-Header-Content-Length": str(len(header))}
        response, seconds = ctx.post(V2, content=header + content[length:], headers=headers)
        return expect(response, seconds, 422, "invalid_intrinsics", 10.0)

    return attack


# -- F: connections that never finish a request ------------------------------------------------


def half_request_line(ctx: Context) -> Outcome:
    sock = connect(ctx.url)
    sock.sendall(b"POST /compl")
    closed, _ = closed_within(sock, WAIT_S)
    sock.close()
    return connection_outcome([closed], "the connection")


def slowloris(ctx: Context) -> Outcome:
    """50 connections sending their request head one header line every 5 s."""
    socks = [connect(ctx.url) for _ in range(50)]
    for sock in socks:
        sock.sendall(b"POST /complete HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    closed: list[float | None] = [None] * len(socks)
    start = time.monotonic()
    served = None
    while time.monotonic() - start < WAIT_S and None in closed:
        if served is None and time.monotonic() - start > 2:
            served = valid(ctx)
        for k, sock in enumerate(socks):
            if closed[k] is None:
                done, _ = closed_within(sock, 0.01)
                if done is not None:
                    closed[k] = time.monotonic() - start
                    continue
                if int(time.monotonic() - start) % 5 == 0:
                    try:
                        sock.send(b"X-Slow: 1\r\n")
                    except OSError:
                        closed[k] = time.monotonic() - start
        time.sleep(0.2)
    for sock in socks:
        sock.close()
    outcome = connection_outcome(closed, "50 connections")
    ok = outcome.ok and served == 200
    return Outcome(f"{outcome.answer}; a valid request meanwhile: {served}", None, ok)


def silent_connections(ctx: Context) -> Outcome:
    """200 connections that send nothing."""
    socks = [connect(ctx.url) for _ in range(200)]
    start = time.monotonic()
    closed: list[float | None] = [None] * len(socks)
    while time.monotonic() - start < WAIT_S and None in closed:
        for k, sock in enumerate(socks):
            if closed[k] is None:
                done, _ = closed_within(sock, 0.001)
                if done is not None:
                    closed[k] = time.monotonic() - start
        time.sleep(0.2)
    for sock in socks:
        sock.close()
    return connection_outcome(closed, "200 connections")


def connection_outcome(closed: list[float | None], what: str) -> Outcome:
    if None in closed:
        left = closed.count(None)
        return Outcome(f"{left} of {what} still open after {WAIT_S:.0f} s", None, False)
    latest = max(closed)  # type: ignore[type-var]
    return Outcome(f"{what} closed by the server after {latest:.1f} s", None, latest <= 30)


# -- G: overload -------------------------------------------------------------------------------


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


# -- H: POST /pose's init ----------------------------------------------------------------------


def pose_init(init: str) -> Callable[[Context], Outcome]:
    def attack(ctx: Context) -> Outcome:
        response, seconds = ctx.post(
            "/pose", files=frame_files(), data={"target": "probe", "init": init}
        )
        return expect(response, seconds, 422, "invalid_init", REFUSE_LIMIT_S)

    return attack


# -- I: targets folders ------------------------------------------------------------------------


def broken_targets(kind: str) -> Callable[[Context], Outcome]:
    """``sdc-serve --targets`` on a folder broken as ``kind`` says: it must stop with exit
    status 2 and one line, loading nothing from outside the folder."""

    def attack(ctx: Context) -> Outcome:
        folder = targets_folder(ctx.work / f"targets-{kind}", kind)
        command = [sys.executable, "-m", "sdcnet.service", "--model", str(ctx.model)]
        command += ["--targets", str(folder), "--host", "127.0.0.1", "--port", "0"]
        log = ctx.work / f"serve-{kind}.log"
        start = time.perf_counter()
        with log.open("w") as out:
            process = subprocess.Popen(command, stdout=out, stderr=out)
        started = False
        while process.poll() is None and time.perf_counter() - start < 120:
            if "Uvicorn running" in log.read_text():
                started = True
                break
            time.sleep(0.2)
        process.kill()
        process.wait()
        seconds = time.perf_counter() - start
        if started:
            return Outcome("started and served (took the manifest as it is)", seconds, False)
        text = log.read_text()
        lines = text.strip().splitlines()
        last = lines[-1] if lines else ""
        ok = process.returncode == 2 and "Traceback" not in text and last.startswith("sdc-serve:")
        return Outcome(f"exit {process.returncode}: {last[:160]}", seconds, ok)

    return attack


def targets_folder(folder: Path, kind: str) -> Path:
    """A targets folder broken as ``kind`` says (one mesh, ``probe.stl``)."""
    folder.mkdir(parents=True, exist_ok=True)
    write_targets(folder, {"probe": (probe_mesh(), 6.3)})
    elsewhere = folder.parent / "elsewhere.stl"
    probe_mesh().export(elsewhere)
    entry: dict = {"file": "probe.stl", "longest_m": 6.3}
    manifest: object = [entry]
    if kind == "file_not_text":
        entry["file"] = 5
    elif kind == "file_outside":
        entry["file"] = "../elsewhere.stl"
    elif kind == "symlink_outside":
        (folder / "link.stl").symlink_to(elsewhere)
        entry["file"] = "link.stl"
    elif kind == "longest_true":
        entry["longest_m"] = True
    elif kind == "longest_infinite":
        (folder / "manifest.json").write_text('[{"file": "probe.stl", "longest_m": 1e999}]')
        return folder
    elif kind == "longest_nan":
        (folder / "manifest.json").write_text('[{"file": "probe.stl", "longest_m": NaN}]')
        return folder
    elif kind == "degenerate_mesh":
        (folder / "flat.stl").write_text(
            "solid flat\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
            "vertex 2 0 0\nendloop\nendfacet\nendsolid flat\n"
        )
        entry["file"] = "flat.stl"
    elif kind == "manifest_not_a_list":
        manifest = entry
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder


# -- J: what the answers say -------------------------------------------------------------------


def server_header(ctx: Context) -> Outcome:
    response = httpx.get(f"{ctx.url}/health")
    server = response.headers.get("server")
    return Outcome(f"Server: {server}" if server else "no Server header", None, server is None)


def library_hints(ctx: Context) -> Outcome:
    """Requests whose errors tempt a library's own words, then every message of the run."""
    digits = huge_integer()
    header = f"{{'descr': '<f4', 'fortran_order': False, 'shape': ({digits}, 2), }}"
    text = header.encode() + b" " * (-(len(header) + 11) % 64) + b"\n"
    npy = b"\x93NUMPY\x01\x00" + len(text).to_bytes(2, "little") + text
    files = frame_files()
    ctx.post("/complete", files={**files, "sparse": ("s.npy", npy)})
    ctx.post(
        "/complete",
        files={**files, "sparse": ("s.npy", npy_bytes(np.array([1, "a"], object), True))},
    )
    ctx.post("/pose", files=files, data={"target": "probe", "init": f'{{"t": [{digits}, 0, 0]}}'})
    ctx.post(V2, content=f'{{"inputs": [], "id": {digits}}}'.encode())
    found = sorted({m for m in ctx.messages for hint in LIBRARY_HINTS if hint in m})
    answer = f"{len(found)} of {len(ctx.messages)} error messages echo a library: " + (
        " | ".join(m[:120] for m in found[:4]) if found else "none"
    )
    return Outcome(answer, None, not found)


# -- more: slow readers, deep or wide v2 headers -----------------------------------------------


def slow_readers(ctx: Context) -> Outcome:
    """4 clients ask for a large answer (a bright 1024 x 1024 frame as JSON, about 25 MB)
    and, once it has begun, read none of it; 10 valid requests, one a second, meanwhile; the
    readers must be reset once their answers are later than the minimum rate allows."""
    body, content_type = bright_form(1024, every=2)
    head = request_head("/complete", len(body), content_type)
    socks = [connect(ctx.url, receive_buffer=4096) for _ in range(4)]
    for sock in socks:
        sock.sendall(head + body)
    begun = []
    for sock in socks:  # each answer begun, left unread (the service answers 2 at a time)
        sock.settimeout(120)
        begun.append(status_of(sock.recv(12, socket.MSG_PEEK)))
    start = time.monotonic()
    statuses = []
    for _ in range(10):
        statuses.append(valid(ctx))
        time.sleep(1.0)
    readers = [sock for sock, status in zip(socks, begun, strict=True) if status == 200]
    reset: set[int] = set()  # a socket's pending error is cleared once read: keep who had one
    while len(reset) < len(readers) and time.monotonic() - start < SLOW_READER_WAIT_S:
        reset |= {
            k for k, s in enumerate(readers) if s.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        }
        time.sleep(0.2)
    for sock in socks:
        sock.close()
    ok = statuses.count(200) >= 9 and len(reset) == len(readers)
    answer = (
        f"answers begun {count_statuses(begun)}; {statuses.count(200)}/10 valid 200 "
        f"({count_statuses(statuses)}); {len(reset)} of the {len(readers)} readers reset "
        f"{time.monotonic() - start:.0f} s after their answers began"
    )
    return Outcome(answer, None, ok)


#: How long the slow readers of K1 are watched: their 25 MB answers may take 10 s and then
#: 1 MiB/s (the default body_timeout_s and min_rate), 34 s.
SLOW_READER_WAIT_S = 45.0


def v2_deep_header(ctx: Context) -> Outcome:
    body = f'{{"inputs": [], "id": {nested_json(100_000)}}}'.encode()
    response, seconds = ctx.post(V2, content=body, headers={"content-type": "application/json"})
    ok = 400 <= response.status_code < 500 and seconds <= REFUSE_LIMIT_S
    return Outcome(f"{code_of(response)} in {seconds:.2f} s", seconds, ok)


def v2_wide_shape(ctx: Context) -> Outcome:
    shape = ",".join(["1"] * 10_000_000)
    body = f'{{"inputs": [{{"name": "gray", "datatype": "UINT8", "shape": [{shape}]}}]}}'
    response, seconds = ctx.post(
        V2, content=body.encode(), headers={"content-type": "application/json"}
    )
    return expect_refused(response, seconds)


# -- the catalogue -----------------------------------------------------------------------------

#: key -> (what the client sends, what must happen, the attack)
ATTACKS: dict[str, tuple[str, str, Callable[[Context], Outcome]]] = {
    "A": (
        "4 `POST /complete` uploads of a valid form (128 x 128 frame, 67 kB) sending one byte "
        "every 2 s, and 10 valid requests meanwhile",
        ">= 9 of 10 valid 200",
        trickling_uploads,
    ),
    "B1": (
        "v2 JSON: a [1, 1] gray with 15M zeros in `data` (30 MiB)",
        "4xx within 2 s",
        v2_json(15_000_000),
    ),
    "B2": ("v2 JSON: the same with 57M zeros (114 MiB)", "4xx within 2 s", v2_json(57_000_000)),
    "B3": (
        "a 4096 x 4096 bright frame, a return on every 4th pixel (1M), outlier removal, JSON",
        "no 5xx; 4xx, or 200 within 10 s",
        frame_4096,
    ),
    "B4": (
        "the largest frame the service takes (`max_pixels`), bright, 1 return in 16 pixels, "
        "outlier removal, JSON answer",
        "200",
        largest_frame,
    ),
    "B5": ("four B4 at once", "peak within the Deployment's memory limit", four_largest_frames),
    "B6": (
        "the largest bright frame (at most 2048 x 2048) over v2, every output asked as JSON `data`",
        "200 or 413",
        largest_frame_json_outputs,
    ),
    "B7": (
        "v2 JSON: the largest gray (at most 2048 x 2048) and its returns as JSON `data`",
        "200 or 413",
        json_gray_of_largest_frame,
    ),
    "B8": (
        "the largest frame as a 16-bit noise PNG and a float64 dense `.npy` (the largest files "
        "of a frame), outlier removal, JSON answer",
        "200, or 413 when the files exceed `max_upload_bytes`",
        largest_upload,
    ),
    "B9": (
        "the largest bright frame (1 return in 16 pixels) on `POST /pose`",
        "no 5xx",
        largest_pose,
    ),
    "C1": (
        "a returns CSV of 4M lines, the last one bad, beside the largest frame's gray",
        "4xx; within 2 s if more returns than the service takes, else 10 s",
        long_csv(4_000_000),
    ),
    "C2": ("the same with 16.7M lines", "as C1", long_csv(16_777_216)),
    "C3": (
        "the same with as many lines as the service takes (`max_returns`, at most a line per "
        "pixel)",
        "4xx within 10 s",
        long_csv(None),
    ),
    "D": (
        "`fx=1 fy=1` on a 1024 x 1024 frame",
        "422 invalid_intrinsics",
        form_intrinsics({"fx": "1", "fy": "1"}),
    ),
    "E1": (
        "`fx=1e-300` on `POST /complete`",
        "422 invalid_intrinsics",
        form_intrinsics({"fx": "1e-300"}),
    ),
    "E2": (
        "`cx=1e308` on `POST /complete`",
        "422 invalid_intrinsics",
        form_intrinsics({"cx": "1e308"}),
    ),
    "E3": ("`fx=1e-300` on the v2 route", "422 invalid_intrinsics", v2_intrinsics({"fx": 1e-300})),
    "E4": (
        "`cx=1e308` on `POST /pose`",
        "422 invalid_intrinsics",
        form_intrinsics({"cx": "1e308"}, "/pose"),
    ),
    "F1": ("half a request line, then silence", "closed within 30 s", half_request_line),
    "F2": (
        "50 connections sending their request head one line every 5 s (slowloris)",
        "all closed within 30 s; valid requests served",
        slowloris,
    ),
    "F3": ("200 connections that send nothing", "all closed within 30 s", silent_connections),
    "G1": (
        "32 clients sending 1024 x 1024 frames back to back for 20 s, ignoring Retry-After",
        f"200 or 503 only; answered p99 <= {OVERLOAD_FRAMES} frame times",
        overload(32),
    ),
    "G2": ("the same with 64 clients", "as G1", overload(64)),
    "H1": (
        "`POST /pose` with `init` nested 100,000 levels deep",
        "422 invalid_init within 2 s",
        pose_init(nested_json(100_000)),
    ),
    "H2": (
        "`POST /pose` with `init` nested 900 levels deep",
        "422 invalid_init within 2 s",
        pose_init(nested_json(900)),
    ),
    "H3": (
        "`POST /pose` with a 5000-digit number in `init`",
        "422 invalid_init within 2 s",
        pose_init(f'{{"t": [{huge_integer()}, 0, 0], "quaternion_wxyz": [1, 0, 0, 0]}}'),
    ),
    "I1": (
        'targets manifest with `"file": 5`',
        "exit 2, one line",
        broken_targets("file_not_text"),
    ),
    "I2": ('`"file": "../elsewhere.stl"`', "exit 2, one line", broken_targets("file_outside")),
    "I3": ("a symlink out of the folder", "exit 2, one line", broken_targets("symlink_outside")),
    "I4": ('`"longest_m": true`', "exit 2, one line", broken_targets("longest_true")),
    "I5": (
        '`"longest_m": 1e999` (infinite)',
        "exit 2, one line",
        broken_targets("longest_infinite"),
    ),
    "I6": ('`"longest_m": NaN`', "exit 2, one line", broken_targets("longest_nan")),
    "I7": (
        "a mesh whose triangles have no area",
        "exit 2, one line",
        broken_targets("degenerate_mesh"),
    ),
    "I8": (
        "a manifest that is an object, not a list",
        "exit 2, one line",
        broken_targets("manifest_not_a_list"),
    ),
    "J1": ("`GET /health`: the Server header", "none", server_header),
    "J2": (
        "errors that tempt library words (a 5000-digit .npy shape, a pickle, a 5000-digit "
        "number in `init` and in a v2 header), then every error message of this run",
        "no library hint or name",
        library_hints,
    ),
    "K1": (
        "4 clients asking for a 25 MB JSON answer and, once it has begun, reading none of it; "
        "10 valid requests meanwhile",
        ">= 9 of 10 valid 200; the readers reset (1 MiB/s after 10 s)",
        slow_readers,
    ),
    "K2": ("v2 header with `id` nested 100,000 levels deep", "4xx within 2 s", v2_deep_header),
    "K3": ("v2 header with a `shape` of 10M dimensions", "4xx within 2 s", v2_wide_shape),
}


@dataclass(frozen=True)
class Row:
    key: str
    attack: str
    expected: str
    answer: str
    seconds: float | None
    peak_mib: float | None
    ready_ms: float | None
    passed: bool


def warm_up(ctx: Context) -> None:
    """Valid frames on every route (the allocators keep what they grew), then the baseline."""
    s = synthetic_frame(1024, 2)
    files = {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}
    for fmt in ("json", "npz", "ply"):
        for _ in range(3):
            assert ctx.post(f"/complete?format={fmt}", files=files)[0].status_code == 200
    content, headers = v2_body(s.gray, returns_from_dense(s.sparse))
    for _ in range(3):
        assert ctx.post(V2, content=content, headers=headers)[0].status_code == 200
        ctx.post("/pose", files=frame_files(), data={"target": "probe"})
    time.sleep(1.0)
    ctx.warm_kib = memory_kib(ctx.pid)["rss"]


def run_attack(ctx: Context, key: str) -> Row:
    what, expected, attack = ATTACKS[key]
    startup = key.startswith("I")
    reset_peak(ctx.pid)
    with ReadyWatch(ctx.url) as ready:
        try:
            outcome = attack(ctx)
        except Exception as exc:  # a transport error is an answer too
            outcome = Outcome(f"client error: {type(exc).__name__}: {exc}"[:200], None, False)
    peak_mib = (memory_kib(ctx.pid)["peak"] - ctx.warm_kib) / 1024
    ctx.peaks_mib[key] = peak_mib
    passed = outcome.ok and ready.max_ms <= READY_LIMIT_MS
    if not startup and key != "B5":
        passed = passed and peak_mib <= PEAK_LIMIT_MIB
    row = Row(
        key,
        what,
        expected,
        outcome.answer,
        outcome.seconds,
        None if startup else peak_mib,
        ready.max_ms,
        passed,
    )
    print(
        f"{key}: {'pass' if passed else 'FAIL'}: {outcome.answer} (peak +{peak_mib:.0f} MiB, "
        f"/ready max {ready.max_ms:.0f} ms)",
        flush=True,
    )
    return row


def deployment_limit_mib() -> float:
    """The memory limit of deploy/deployment.yaml's container, MiB."""
    pod = yaml.safe_load(DEPLOYMENT.read_text())["spec"]["template"]["spec"]
    value = pod["containers"][0]["resources"]["limits"]["memory"]
    number, unit = re.fullmatch(r"(\d+)(Mi|Gi)", value).groups()
    return float(number) * (1024 if unit == "Gi" else 1)


def internal_errors(url: str) -> float:
    """The service's count of requests that ended in an internal error."""
    text = httpx.get(f"{url}/metrics").text
    found = re.findall(
        r'^sdcnet_inference_request_failure_total\{reason="internal_error"\} (\S+)$', text, re.M
    )
    return float(found[0]) if found else 0.0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--model", type=Path, default=None, help="ONNX model (default: the tiny one)")
    p.add_argument("--only", default=None, help="comma-separated keys (default: every attack)")
    p.add_argument("--name", default="hostile", help="report name under docs/benchmarks/")
    p.add_argument("--note", default="", help="a sentence for the report (e.g. a shared machine)")
    args = p.parse_args(argv)
    keys = args.only.split(",") if args.only else list(ATTACKS)
    errors = 0.0
    with tempfile.TemporaryDirectory() as work:
        work_dir = Path(work)
        model = args.model or tiny_model(work_dir)
        targets = write_targets(work_dir / "targets", {"probe": (probe_mesh(), 6.3)})
        flags = ["--threads=2", f"--targets={targets}"]
        ctx = Context("", 0, model, work_dir, {})
        rows, restarts, warm = [], 0, []
        with ExitStack() as running:
            for key in keys:
                if not ctx.url:
                    service = running.enter_context(
                        service_process(model, work_dir / f"serve-{restarts}.log", *flags)
                    )
                    ctx.url, ctx.pid = service.url, service.pid
                    ctx.limits = httpx.get(f"{service.url}/model").json()["limits"]
                    warm_up(ctx)
                    warm.append(ctx.warm_kib / 1024)
                rows.append(run_attack(ctx, key))
                if memory_kib(ctx.pid)["rss"] > ctx.warm_kib + RETAINED_LIMIT_MIB * 1024:
                    errors += internal_errors(ctx.url)
                    running.close()  # a fresh service: the next attack's peak is its own
                    ctx.url, restarts = "", restarts + 1
            if ctx.url:
                errors += internal_errors(ctx.url)
        fives = sorted({s for s in ctx.statuses if s >= 500 and s != 503})
        limits = ctx.limits
    summary = {
        "model": "the tiny test model" if args.model is None else str(args.model),
        "machine": cpu_description(),
        "note": args.note,
        "limits": limits,
        "warm_rss_mib": warm,
        "restarts": restarts,
        "internal_errors": errors,
        "statuses_5xx": fives,
        "rows": [asdict(r) for r in rows],
    }
    (DOCS / f"{args.name}.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(write_report(args, summary, rows))
    failed = [r.key for r in rows if not r.passed]
    return 1 if failed or errors or fives else 0


def write_report(args: argparse.Namespace, summary: dict, rows: list[Row]) -> Path:
    def cell(value: float | None, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    table = "\n".join(
        f"| {r.key} | {r.attack} | {r.expected} | {r.answer} | {cell(r.peak_mib, '+.0f')} | "
        f"{cell(r.ready_ms, '.0f')} | {'pass' if r.passed else '**FAIL**'} |"
        for r in rows
    )
    command = "python -m benchmarks.hostile" + (f" --model {args.model}" if args.model else "")
    limits = ", ".join(f"{k} {v:,}" for k, v in summary["limits"].items())
    warm = " / ".join(f"{w:.0f}" for w in summary["warm_rss_mib"])
    passed = sum(r.passed for r in rows)
    body = f"""
`{command}` on {summary["machine"]}; model: {summary["model"]}. {summary["note"]}

`sdc-serve` with its default settings (limits: {limits}),
2 onnxruntime threads, on 127.0.0.1; warm baseline (resident memory after valid frames on
every route) {warm} MiB. "peak" is the server's peak resident memory (VmHWM, reset before each
attack) above that baseline; an attack that leaves more than {RETAINED_LIMIT_MIB} MiB resident
above it (the allocators keep freed memory for reuse) is followed by a fresh service
({summary["restarts"]} restarts), so that each peak is the attack's own. "/ready" is the slowest
of the probes sent every 0.1 s during the attack. An attack passes when its own check holds,
its peak stays under {PEAK_LIMIT_MIB:.0f} MiB (B5: under the Deployment's limit) and /ready
answered within {READY_LIMIT_MS:.0f} ms. The I rows start `sdc-serve` on a broken targets
folder instead.

**{passed} of {len(rows)} attacks pass**; requests counted as internal errors:
{summary["internal_errors"]:.0f}; 5xx answers other than 503: {summary["statuses_5xx"] or "none"}.

| | what the client sends | must | what happened | peak MiB | /ready ms | verdict |
|---|---|---|---|---|---|---|
{table}
"""
    return write_markdown(args.name, "Hostile and careless clients", body)


if __name__ == "__main__":
    raise SystemExit(main())
