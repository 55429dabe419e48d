"""Python API of the sdcnet service, on httpx: ``Client(url).complete(gray, sparse)``,
``Client(url).pose(gray, sparse, target)``.

Needs numpy, OpenCV and httpx only (no torch, onnxruntime or FastAPI). Inputs may be arrays,
file paths or raw file bytes; answers come back as numpy arrays (the service's npz format,
which is exact and compact). Connection errors and 503 answers are retried with exponential
backoff (503's Retry-After honoured); any other error answer raises ``ServiceError`` with the
service's code and message.
"""

from __future__ import annotations

import io
import json
import os
import random
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np

from sdcnet.npyio import npy_bytes
from sdcnet.rigid import Pose, parse_pose

DEFAULT_URL = os.environ.get("SDCNET_URL", "http://127.0.0.1:8000")

#: Transport failures worth another try: the request did not get through, or the answer was
#: cut off. Completing a frame has no side effect, so a repeat is harmless.
_RETRYABLE = (
    httpx.ConnectError,
    httpx.ConnectTimeout,
    httpx.RemoteProtocolError,
    httpx.ReadError,
    httpx.WriteError,
)

Source = str | Path | bytes | np.ndarray


class ClientError(Exception):
    """Base of what the client raises; the message is meant for a person."""


class InputError(ClientError):
    """A local input cannot be used: missing, unreadable, or an unusable array."""


class ServiceUnreachableError(ClientError):
    """No answer from the service: refused, timed out or cut off, after the retries."""


class ServiceError(ClientError):
    """The service answered with an error (4xx, or 5xx after the retries)."""

    def __init__(self, status: int, code: str, message: str):
        super().__init__(f"service answered {status} {code}: {message}")
        self.status = status
        self.code = code
        self.message = message


@dataclass
class Completion:
    """One completed frame."""

    depth: np.ndarray  # float32 (H, W), camera-frame Z in metres, 0 outside the mask
    mask: np.ndarray  # bool (H, W), True = spacecraft
    points: np.ndarray  # float32 (N, 3), camera frame (x right, y down, z forward), metres
    meta: dict[str, Any] = field(default_factory=dict)  # the service's summary (meta.json)
    latency_s: float = 0.0  # round trip, seconds, retries included

    @property
    def model_version(self) -> str:
        return self.meta.get("model_version", "")

    @property
    def provider(self) -> str:
        return self.meta.get("provider", "")

    @property
    def timings_ms(self) -> dict[str, float]:
        """Server-side milliseconds per phase: decode_ms, queue_ms, inference_ms, encode_ms."""
        return self.meta.get("timings", {})


@dataclass
class PoseAnswer:
    """One ``POST /pose`` answer: the pose (p_camera = R p_target + t, metres) and the rest of
    the service's JSON (fitness, ambiguity, alternatives, the completion's summary...)."""

    pose: Pose
    answer: dict[str, Any]
    latency_s: float = 0.0  # round trip, seconds, retries included

    @property
    def ambiguous(self) -> bool:
        return bool(self.answer.get("ambiguous"))

    @property
    def alternatives(self) -> list[Pose]:
        return [parse_pose(a["pose"]) for a in self.answer.get("alternatives", [])]

    @property
    def timings_ms(self) -> dict[str, float]:
        return self.answer.get("timings", {})


def read_file(path: str | Path, what: str = "input") -> bytes:
    """The bytes of a local file; ``InputError`` with a clear message if it cannot be read."""
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{what} file not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"{what} is a directory, not a file: {path}") from None
    except OSError as exc:
        raise InputError(f"cannot read {what} file {path}: {exc.strerror or exc}") from None


def _gray_upload(gray: Source) -> tuple[str, bytes]:
    if isinstance(gray, np.ndarray):
        if gray.dtype not in (np.uint8, np.uint16) or gray.ndim not in (2, 3):
            raise InputError(
                f"gray array must be uint8 or uint16 (H, W), got {gray.dtype} {gray.shape}"
            )
        ok, png = cv2.imencode(".png", gray)
        if not ok:
            raise InputError(f"cannot encode the gray array {gray.shape} as PNG")
        return "gray.png", png.tobytes()
    if isinstance(gray, bytes):
        return "gray", gray
    return Path(gray).name, read_file(gray, "gray image")


def _sparse_upload(sparse: Source) -> tuple[str, bytes]:
    if isinstance(sparse, np.ndarray):
        if sparse.dtype not in (np.float32, np.float64) or sparse.ndim != 2:
            raise InputError(
                f"sparse array must be float32 or float64 (H, W) metres, got "
                f"{sparse.dtype} {sparse.shape}"
            )
        return "sparse.npy", npy_bytes(sparse)
    if isinstance(sparse, bytes):
        return "sparse", sparse
    return Path(sparse).name, read_file(sparse, "sparse depth")


def _frame_form(
    gray: Source, sparse: Source, outlier_removal: bool, **numbers: float | None
) -> tuple[dict, dict[str, str]]:
    """The multipart files and fields of one frame (``POST /complete``, ``POST /pose``)."""
    files = {"gray": _gray_upload(gray), "sparse": _sparse_upload(sparse)}
    data = {k: repr(float(v)) for k, v in numbers.items() if v is not None}
    data["outlier_removal"] = "true" if outlier_removal else "false"
    return files, data


def _error_of(response: httpx.Response) -> ServiceError:
    try:
        error = response.json()["error"]
        return ServiceError(response.status_code, error["code"], error["message"])
    except (ValueError, KeyError, TypeError):
        text = response.text.strip()[:200] or response.reason_phrase
        return ServiceError(response.status_code, f"http_{response.status_code}", text)


class Client:
    """A connection to one sdcnet service; thread-safe, reuse it for many requests.

    ``timeout_s`` bounds each attempt; ``retries`` more attempts follow a connection error or
    a 503, ``backoff_s`` x 2^attempt apart (with jitter, at most ``max_backoff_s``) or as long
    as the 503's Retry-After says.
    """

    def __init__(
        self,
        url: str = DEFAULT_URL,
        timeout_s: float = 60.0,
        retries: int = 3,
        backoff_s: float = 0.25,
        max_backoff_s: float = 10.0,
    ):
        self.url = url.rstrip("/")
        self.retries = retries
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self._http = httpx.Client(
            base_url=self.url, timeout=httpx.Timeout(timeout_s, connect=min(timeout_s, 5.0))
        )

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _pause(self, attempt: int, retry_after: str | None) -> None:
        if retry_after is not None and retry_after.isdigit():
            wait = float(retry_after)
        else:
            wait = self.backoff_s * 2**attempt * random.uniform(0.5, 1.0)
        time.sleep(min(wait, self.max_backoff_s))

    def _request(self, method: str, path: str, retry: bool = True, **kwargs) -> httpx.Response:
        """The answer to one request, retried on connection errors and 503 when ``retry``;
        raises ``ServiceUnreachableError`` or ``ServiceError``."""
        attempts = self.retries + 1 if retry else 1
        attempt = 0
        while True:
            last = attempt == attempts - 1
            try:
                response = self._http.request(method, path, **kwargs)
            except _RETRYABLE as exc:
                if last:
                    raise ServiceUnreachableError(
                        f"cannot reach the sdcnet service at {self.url}: {exc or type(exc)}"
                        " (is sdc-serve running there?)"
                    ) from exc
                self._pause(attempt, None)
            except httpx.TimeoutException as exc:
                raise ServiceUnreachableError(
                    f"no answer from {self.url}{path} within {self._http.timeout.read} s"
                ) from exc
            else:
                if response.status_code != 503 or last:
                    if response.is_error:
                        raise _error_of(response)
                    return response
                self._pause(attempt, response.headers.get("Retry-After"))
            attempt += 1

    def complete(
        self,
        gray: Source,
        sparse: Source,
        *,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        depth_scale: float | None = None,
        outlier_removal: bool = False,
    ) -> Completion:
        """Complete one frame.

        ``gray``: uint8/uint16 array or an image file (PNG, TIFF, JPEG, BMP) as path or bytes.
        ``sparse``: float32/float64 (H, W) metres (0 = no return), or a ``.npy`` file, or a
        16-bit PNG with ``depth_scale`` (metres per unit). Intrinsics in pixels; those not
        given are the model's, scaled to the image size.
        """
        files, data = _frame_form(
            gray,
            sparse,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            depth_scale=depth_scale,
            outlier_removal=outlier_removal,
        )
        start = time.perf_counter()
        response = self._request(
            "POST", "/complete", params={"format": "npz"}, files=files, data=data
        )
        latency = time.perf_counter() - start
        try:
            with np.load(io.BytesIO(response.content), allow_pickle=False) as npz:
                return Completion(
                    depth=npz["depth.npy"],
                    mask=npz["mask.npy"].astype(bool),
                    points=npz["points.npy"],
                    meta=json.loads(npz["meta.json"]),
                    latency_s=latency,
                )
        except (ValueError, KeyError, OSError) as exc:
            raise ClientError(f"unexpected answer from {self.url}/complete: {exc}") from exc

    def pose(
        self,
        gray: Source,
        sparse: Source,
        target: str,
        *,
        init: Pose | dict | None = None,
        fx: float | None = None,
        fy: float | None = None,
        cx: float | None = None,
        cy: float | None = None,
        depth_scale: float | None = None,
        outlier_removal: bool = False,
    ) -> PoseAnswer:
        """The pose of the known ``target`` in one frame (``POST /pose``): from scratch, or
        refined from ``init`` (a previous answer's ``pose``, a ``Pose`` or its JSON dict) to
        track. Inputs as for ``complete``."""
        files, data = _frame_form(
            gray,
            sparse,
            fx=fx,
            fy=fy,
            cx=cx,
            cy=cy,
            depth_scale=depth_scale,
            outlier_removal=outlier_removal,
        )
        data["target"] = target
        if init is not None:
            data["init"] = json.dumps(init.as_dict() if isinstance(init, Pose) else init)
        start = time.perf_counter()
        response = self._request("POST", "/pose", files=files, data=data)
        latency = time.perf_counter() - start
        try:
            answer = response.json()
            return PoseAnswer(parse_pose(answer["pose"]), answer, latency)
        except (ValueError, KeyError, TypeError) as exc:
            raise ClientError(f"unexpected answer from {self.url}/pose: {exc}") from exc

    def target_points(self, name: str) -> np.ndarray:
        """(N, 3) samples of a known target's surface, its frame, metres (to draw it)."""
        points = self._request("GET", f"/targets/{name}").json()["points"]
        return np.asarray(points, np.float64).reshape(-1, 3)

    def health(self) -> dict[str, bool]:
        """{"live": ..., "ready": ...}, asked once (no retries); raises ServiceUnreachableError."""
        live = self._request("GET", "/health", retry=False).json()["live"]
        try:
            ready = self._request("GET", "/ready", retry=False).json()["ready"]
        except ServiceError as exc:
            if exc.status != 503:
                raise
            ready = False
        return {"live": live, "ready": ready}

    def model(self) -> dict[str, Any]:
        """The model's metadata (``GET /model``)."""
        return self._request("GET", "/model").json()
