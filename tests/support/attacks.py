"""Hostile and careless clients, as building blocks for ``benchmarks.hostile`` and the tests:
raw sockets that trickle, stall or never finish a request, payloads that are large or deep
for their size, a watch on ``/ready`` while an attack runs, and the server's peak memory reset
between attacks (``/proc/PID/clear_refs``).

Everything talks to a real ``sdc-serve`` over TCP; nothing here imports the service.
"""

from __future__ import annotations

import socket
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import numpy as np

from sdcnet.npyio import npy_bytes
from tests.support.background import BackgroundLoop
from tests.support.frames import png_bytes

#: What a client library or the Python runtime says that a service should not echo: hints
#: on how to get round a safety limit, and names of the code behind the service.
LIBRARY_HINTS = (
    "allow_pickle",
    "set_int_max_str_digits",
    "Traceback",
    "numpy",
    "pydantic",
    "starlette",
    "uvicorn",
    "json.decoder",
    'File "',
)


def reset_peak(pid: int) -> None:
    """Reset the process's peak resident memory (VmHWM) to its current resident memory, so
    that the next reading is the peak of what happened since (Linux >= 4.0)."""
    Path(f"/proc/{pid}/clear_refs").write_text("5")


@dataclass
class ReadyWatch(BackgroundLoop):
    """Polls ``GET /ready`` every ``interval_s`` in a thread while in use; ``max_ms`` is the
    slowest answer (a probe that failed or took over ``timeout_s`` counts as ``timeout_s``)."""

    url: str
    interval_s: float = 0.1
    timeout_s: float = 5.0
    latencies_ms: list[float] = field(default_factory=list)
    failures: int = 0

    def loop(self, stop: threading.Event) -> None:
        with httpx.Client(base_url=self.url, timeout=self.timeout_s) as http:
            while not stop.is_set():
                start = time.perf_counter()
                try:
                    ok = http.get("/ready").status_code == 200
                except httpx.HTTPError:
                    ok = False
                elapsed = (time.perf_counter() - start) * 1e3
                if not ok:
                    self.failures += 1
                    elapsed = max(elapsed, self.timeout_s * 1e3)
                self.latencies_ms.append(elapsed)
                stop.wait(self.interval_s)

    @property
    def max_ms(self) -> float:
        return max(self.latencies_ms, default=0.0)


def address(url: str) -> tuple[str, int]:
    parts = urlsplit(url)
    return parts.hostname or "127.0.0.1", parts.port or 80


def connect(url: str, receive_buffer: int | None = None) -> socket.socket:
    """A TCP connection to the service; ``receive_buffer``: SO_RCVBUF bytes (a slow reader)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if receive_buffer is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer)
    sock.connect(address(url))
    return sock


def request_head(path: str, content_length: int, content_type: str, *extra: str) -> bytes:
    """The head of a POST of ``content_length`` body bytes."""
    lines = [f"POST {path} HTTP/1.1", "Host: 127.0.0.1", f"Content-Type: {content_type}"]
    lines += [f"Content-Length: {content_length}", *extra]
    return ("\r\n".join(lines) + "\r\n\r\n").encode()


def closed_within(sock: socket.socket, limit_s: float) -> tuple[float | None, bytes]:
    """Seconds until the server closes ``sock`` (None: still open after ``limit_s``), and
    what it sent before closing."""
    start = time.monotonic()
    received = b""
    while (left := limit_s - (time.monotonic() - start)) > 0:
        sock.settimeout(left)
        try:
            chunk = sock.recv(65536)
        except TimeoutError:
            break
        except OSError:  # reset by the server
            return time.monotonic() - start, received
        if not chunk:
            return time.monotonic() - start, received
        received += chunk
    return None, received


def status_of(response: bytes) -> int | None:
    """The status code of the raw HTTP response ``response`` (None: no response)."""
    if not response.startswith(b"HTTP/1."):
        return None
    return int(response.split(b" ", 2)[1])


class Trickler(BackgroundLoop):
    """Connections that each send a request head and then its ``body`` one byte every
    ``interval_s`` (a slow or hostile upload that stays valid as far as it goes), in a thread
    while in use; records when and how the server ended each one (seconds after its start,
    the status it answered)."""

    def __init__(
        self, url: str, path: str, count: int, body: bytes, content_type: str, interval_s: float
    ):
        self.socks = [connect(url) for _ in range(count)]
        self.ended: list[tuple[float, int | None] | None] = [None] * count
        self.body, self.sent, self.interval_s = body, 0, interval_s
        head = request_head(path, len(body), content_type)
        for sock in self.socks:
            sock.sendall(head)
            sock.setblocking(False)
        self.start = time.monotonic()

    def loop(self, stop: threading.Event) -> None:
        while not stop.wait(self.interval_s) and self.sent < len(self.body):
            for k, sock in enumerate(self.socks):
                if self.ended[k] is None:
                    self._poke(k, sock)
            self.sent += 1

    def _poke(self, k: int, sock: socket.socket) -> None:
        try:
            answer = sock.recv(65536)
            self.ended[k] = (time.monotonic() - self.start, status_of(answer))
            return
        except BlockingIOError:
            pass
        except OSError:
            self.ended[k] = (time.monotonic() - self.start, None)
            return
        try:
            sock.send(self.body[self.sent : self.sent + 1])
        except OSError:
            self.ended[k] = (time.monotonic() - self.start, None)

    def __exit__(self, *exc: object) -> None:
        super().__exit__(*exc)
        for sock in self.socks:
            sock.close()


# -- payloads ------------------------------------------------------------------------------


def bright_frame(side: int, every: int = 2) -> tuple[bytes, bytes]:
    """The worst frame of ``side`` x ``side`` pixels for the tiny model: gray PNG of 255
    everywhere (all foreground) and a LIDAR return at 100 m on every ``every``-th row and
    column (``every`` = 2: a quarter of the pixels), as a returns ``.npy`` (N, 3)."""
    gray = np.full((side, side), 255, np.uint8)
    rows, cols = np.mgrid[0:side:every, 0:side:every]
    returns = np.stack([rows.ravel(), cols.ravel(), np.full(rows.size, 100.0)], 1)
    return png_bytes(gray), npy_bytes(returns.astype(np.float32))


def csv_returns(lines: int, bad_last: bool = True) -> bytes:
    """A returns CSV of ``lines`` returns at pixel (0, 0), the last one not three numbers."""
    body = b"row,col,z_m\n" + b"0,0,100\n" * (lines - 1)
    return body + (b"0,0,zero\n" if bad_last else b"0,0,100\n")


def v2_json_zeros(count: int) -> bytes:
    """A v2 JSON request whose [1, 1] gray carries ``count`` zeros in its ``data``."""
    zeros = b"0," * (count - 1) + b"0"
    return (
        b'{"inputs": [{"name": "gray", "datatype": "UINT8", "shape": [1, 1], "data": ['
        + zeros
        + b']}, {"name": "returns", "datatype": "FP32", "shape": [1, 3], "data": [0, 0, 1]}]}'
    )


def nested_json(depth: int) -> str:
    """JSON arrays nested ``depth`` levels deep."""
    return "[" * depth + "]" * depth


def huge_integer(digits: int = 5000) -> str:
    """An integer literal longer than Python's 4300-digit conversion limit."""
    return "1" * digits


@contextmanager
def quiet_connections(url: str, count: int):
    """``count`` connections that send nothing."""
    socks = [connect(url) for _ in range(count)]
    try:
        yield socks
    finally:
        for sock in socks:
            sock.close()
