"""B: inputs as large as the service takes, or larger (frames, uploads, JSON bodies and
answers); C: long returns CSV files."""

from __future__ import annotations

import json
import re
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from benchmarks.hostile.client import (
    PEAK_LIMIT_MIB,
    REFUSE_LIMIT_S,
    V2,
    Context,
    Outcome,
    bright_form,
    code_of,
    count_statuses,
    expect_refused,
)
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense
from tests.support.attacks import bright_frame, csv_returns, v2_json_zeros
from tests.support.frames import multipart_body, png_bytes, synthetic_frame, v2_body
from tests.support.serving import memory_kib

DEPLOYMENT = Path(__file__).resolve().parents[2] / "deploy" / "deployment.yaml"


def v2_json(count: int) -> Callable[[Context], Outcome]:
    def attack(ctx: Context) -> Outcome:
        body = v2_json_zeros(count)
        headers = {"content-type": "application/json"}
        return expect_refused(*ctx.post(V2, content=body, headers=headers))

    attack.__doc__ = f"v2 JSON: a [1, 1] gray whose data holds {count:,} zeros"
    return attack


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


def deployment_limit_mib() -> float:
    """The memory limit of deploy/deployment.yaml's container, MiB."""
    pod = yaml.safe_load(DEPLOYMENT.read_text())["spec"]["template"]["spec"]
    value = pod["containers"][0]["resources"]["limits"]["memory"]
    number, unit = re.fullmatch(r"(\d+)(Mi|Gi)", value).groups()
    return float(number) * (1024 if unit == "Gi" else 1)


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
