"""Values the parsers must refuse: D, E, intrinsics; H, ``POST /pose``'s init; K2, K3, v2
headers nested deep or shaped wide. J: what the answers say (no Server header, no library's
words)."""

from __future__ import annotations

import json
from collections.abc import Callable

import httpx
import numpy as np

from benchmarks.hostile.client import (
    REFUSE_LIMIT_S,
    V2,
    Context,
    Outcome,
    code_of,
    expect,
    expect_refused,
    frame_files,
)
from sdcnet.npyio import npy_bytes
from sdcnet.returns import returns_from_dense
from tests.support.attacks import LIBRARY_HINTS, huge_integer, nested_json
from tests.support.frames import synthetic_frame, v2_body


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


def pose_init(init: str) -> Callable[[Context], Outcome]:
    def attack(ctx: Context) -> Outcome:
        response, seconds = ctx.post(
            "/pose", files=frame_files(), data={"target": "probe", "init": init}
        )
        return expect(response, seconds, 422, "invalid_init", REFUSE_LIMIT_S)

    return attack


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
