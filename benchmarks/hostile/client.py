"""What every attack shares: the limits an attack is held to, the running service's context
(``Context``), what an attack did (``Outcome``), and the requests the attacks are made of."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from sdcnet.npyio import npy_bytes
from tests.support.attacks import bright_frame
from tests.support.frames import multipart_body, png_bytes, synthetic_frame

PEAK_LIMIT_MIB = 512.0  # no request may raise the peak by more over the warm baseline
READY_LIMIT_MS = 1000.0  # /ready answers within this during every attack
REFUSE_LIMIT_S = 2.0  # oversized inputs are refused within this
V2 = "/v2/models/sdcnet/infer"


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


def bright_form(side: int, every: int = 4) -> tuple[bytes, str]:
    gray, returns = bright_frame(side, every)
    files = {"gray": ("g.png", gray), "returns": ("r.npy", returns)}
    return multipart_body(files, {"outlier_removal": "true"})
