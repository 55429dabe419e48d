"""Python API of the sdcnet service: ``Client(url).complete(gray, sparse)``,
``Client(url).pose(gray, sparse, target)``.

Needs numpy and OpenCV only (no torch, onnxruntime or FastAPI; HTTP is the standard library's,
``sdcnet.client.transport``). Inputs may be arrays,
file paths or raw file bytes; the LIDAR returns may be a dense map or a list of returns. They
travel compactly (``sdcnet.client.protocol``): the raw gray image and the returns as a list,
over the service's Open Inference Protocol route, on one keep-alive connection; the answer
comes back as the spacecraft's region and is rebuilt into full-frame numpy arrays, the same
bit for bit as the service's full-frame answers. ``pose`` sends ``POST /pose``'s form
(``sdcnet.client.form``): the image file and the returns, as a list too. Connection errors and
503 answers are retried with exponential backoff (503's Retry-After honoured); any other error
answer raises ``ServiceError`` with the service's code and message.
"""

from __future__ import annotations

import json
import os
import random
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import cv2
import numpy as np

from sdcnet.camera import GivenIntrinsics, Intrinsics
from sdcnet.client import form, protocol
from sdcnet.client.transport import TRANSPORT_ERRORS, ConnectTimeoutError, Reply, Transport
from sdcnet.formats import FormatError, Reading
from sdcnet.formats.sparse import FORMATS, described, sparse_format
from sdcnet.formats.v2 import HEADER_LENGTH
from sdcnet.pipeline import to_gray
from sdcnet.returns import ReturnsError, check_returns, returns_from_dense
from sdcnet.rigid import Pose, parse_pose

DEFAULT_URL = os.environ.get("SDCNET_URL", "http://127.0.0.1:8000")


Source = str | Path | bytes | np.ndarray
#: Endings of the files of returns that hold a list only (named so in messages).
LIST_ENDINGS = tuple(e for f in FORMATS if "map" not in f.carries for e in f.endings)


def _given(intrinsics: Intrinsics | GivenIntrinsics | None) -> dict[str, float]:
    """The pinhole values the caller gave, by name, as Python floats (pixels; JSON takes no
    numpy float32); those left out are the service's defaults (its camera's, ``sdc-serve
    --camera``, else the model's)."""
    given = {} if intrinsics is None else intrinsics.pinhole_dict()
    return {name: float(value) for name, value in given.items()}


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
    sigma: np.ndarray  # float32 (H, W), the depth's 1-sigma uncertainty, metres, 0 off the mask
    normals: np.ndarray  # float32 (N, 3), each point's unit surface normal, facing the camera
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
    the service's JSON (verdict, fitness, ambiguity, alternatives, the completion's summary...)."""

    pose: Pose
    answer: dict[str, Any]
    latency_s: float = 0.0  # round trip, seconds, retries included

    @property
    def ambiguous(self) -> bool:
        return bool(self.answer.get("ambiguous"))

    @property
    def verdict(self) -> str:
        """The verdict: "reliable", "ambiguous" or "unreliable" (see ``reasons``)."""
        return str(self.answer.get("verdict"))

    @property
    def reasons(self) -> list[str]:
        """Why the answer is not reliable: codes such as poor_fit, symmetric_twins, left_init."""
        return list(self.answer.get("reasons", []))

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


def gray_array(gray: Source) -> np.ndarray:
    """The gray image as uint8/uint16 (H, W): the array itself, or an image file (PNG, TIFF,
    JPEG, BMP; path or bytes) decoded as the service decodes it, colour converted to gray."""
    if isinstance(gray, np.ndarray):
        image = gray
    else:
        data = gray if isinstance(gray, bytes) else read_file(gray, "gray image")
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise InputError("cannot decode the gray image (PNG, TIFF, JPEG or BMP)")
    if image.dtype not in (np.uint8, np.uint16) or image.ndim not in (2, 3):
        raise InputError(
            f"gray must be an 8- or 16-bit image (H, W), got {image.dtype} {image.shape}"
        )
    return to_gray(image)


def _sparse_array(data: bytes, depth_scale: float | None, label: str) -> np.ndarray:
    """A dense map or a returns list from file bytes, read as the service reads them
    (``sdcnet.formats.sparse``; a format of units times ``depth_scale`` metres per unit); its
    errors start with ``label``."""
    try:
        return sparse_format(data).parse(data, Reading(label, depth_scale=depth_scale))
    except FormatError as exc:
        if exc.code == "unsupported_media_type":
            raise InputError(
                f"sparse must be a dense map, {described('map')}, or a list of returns, "
                f"{described('list')}"
            ) from None
        raise InputError(str(exc)) from None


def returns_list(
    sparse: Source | None, returns: np.ndarray | None, shape: tuple[int, int], depth_scale=None
) -> np.ndarray:
    """The LIDAR returns as float32 (N, 3) (row, column, Z metres) for a frame of ``shape``:
    ``returns`` as given, or those of ``sparse``: a dense (H, W) map in metres (array, .npy
    or 16-bit PNG with ``depth_scale``) or a list ((N, 3) array or .npy, CSV file)."""
    if (sparse is None) == (returns is None):
        raise InputError("give the LIDAR returns once: sparse (map or file) or returns (list)")
    label = str(sparse) if isinstance(sparse, str | Path) else "LIDAR returns"
    try:
        if returns is None and isinstance(sparse, np.ndarray):
            returns = sparse
        elif returns is None:
            if isinstance(sparse, bytes):
                data = sparse
            else:
                listed = str(sparse).lower().endswith(LIST_ENDINGS)
                data = read_file(sparse, "LIDAR returns" if listed else "sparse depth")
            returns = _sparse_array(data, depth_scale, label)
        is_map = returns.ndim == 2 and returns.shape == shape
        if is_map and returns.dtype not in (np.float32, np.float64):
            raise InputError(
                f"a sparse map must hold float32 or float64 metres, got {returns.dtype}"
            )
        if returns.ndim != 2 or not (is_map or returns.shape[1] == 3):
            raise InputError(
                f"sparse must be a (H, W) = {shape} map in metres or an (N, 3) list of "
                f"returns, got shape {returns.shape}"
            )
        return returns_from_dense(returns) if is_map else check_returns(returns, shape)
    except ReturnsError as exc:  # its message names the return (and the line of a file)
        message = str(exc)
        raise InputError(
            message if message.startswith(f"{label}: ") else f"{label}: {message}"
        ) from None


def _gray_file(gray: Source) -> tuple[np.ndarray, bytes]:
    """The gray image's pixels (as ``gray_array``) and its file's bytes: the caller's own file,
    or a PNG of an array."""
    if not isinstance(gray, np.ndarray):
        data = gray if isinstance(gray, bytes) else read_file(gray, "gray image")
        return gray_array(data), data
    image = gray_array(gray)
    ok, png = cv2.imencode(".png", image)
    if not ok:
        raise InputError(f"cannot encode the gray array {image.shape} as PNG")
    return image, png.tobytes()


def _error_of(response: Reply) -> ServiceError:
    """The service's error: its own shape ``{"error": {"code", "message"}}``, or the
    Open Inference Protocol's ``{"error": "message"}`` with the code in a header."""
    status = response.status_code
    try:
        error = response.json()["error"]
        if isinstance(error, str):
            code = response.headers.get("sdcnet-error-code", f"http_{status}")
            return ServiceError(status, code, error)
        return ServiceError(status, error["code"], error["message"])
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
        self._http = Transport(self.url, timeout_s, connect_timeout_s=min(timeout_s, 5.0))

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

    def _request(self, method: str, path: str, retry: bool = True, **kwargs) -> Reply:
        """The answer to one request, retried on connection errors and 503 when ``retry``;
        raises ``ServiceUnreachableError`` or ``ServiceError``."""
        attempts = self.retries + 1 if retry else 1
        attempt = 0
        while True:
            last = attempt == attempts - 1
            try:
                response = self._http.request(method, path, **kwargs)
            except TimeoutError as exc:
                if not isinstance(exc, ConnectTimeoutError):  # a slow answer: not retried
                    raise ServiceUnreachableError(
                        f"no answer from {self.url}{path} within {self._http.timeout_s} s"
                    ) from exc
                unreachable = exc
            except TRANSPORT_ERRORS as exc:  # refused, reset, cut off, unknown host
                unreachable = exc
            else:
                unreachable = None
            if unreachable is not None:
                if last:
                    raise ServiceUnreachableError(
                        f"cannot reach the sdcnet service at {self.url}: "
                        f"{unreachable or type(unreachable).__name__} (is sdc-serve running there?)"
                    ) from unreachable
                self._pause(attempt, None)
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
        sparse: Source | None = None,
        *,
        returns: np.ndarray | None = None,
        intrinsics: Intrinsics | GivenIntrinsics | None = None,
        depth_scale: float | None = None,
        outlier_removal: bool = False,
        max_sigma: float | None = None,
        float16_depth: bool = False,
    ) -> Completion:
        """Complete one frame.

        ``gray``: uint8/uint16 array or an image file (PNG, TIFF, JPEG, BMP) as path or bytes.
        The LIDAR returns, once: ``sparse``, a float32/float64 (H, W) map in metres (0 = no
        return) as an array, a ``.npy`` file or a 16-bit PNG with ``depth_scale`` (metres per
        unit), or a list as an (N, 3) array or ``.npy`` or a CSV file (``row,col,z_m``); or
        ``returns``, an (N, 3) array (row, column, Z metres). ``intrinsics`` in pixels: the
        camera's (``Intrinsics``, for this image's size) or some of them (``GivenIntrinsics``);
        those not given are the service's camera's (``sdc-serve --camera``), else the model's,
        scaled to the image size. ``max_sigma`` (metres) leaves the points whose sigma is
        above it out of the cloud (depth, mask and sigma stay whole). ``float16_depth`` halves
        the depth's bytes at a precision of 8 mm (``sdcnet.compact``); by default the depth is
        exact.
        """
        image = gray_array(gray)
        listed = returns_list(sparse, returns, image.shape, depth_scale)
        parameters: dict[str, Any] = _given(intrinsics)
        parameters["outlier_removal"] = outlier_removal
        if max_sigma is not None:
            parameters["max_sigma"] = float(max_sigma)
        body, headers = protocol.request_body(image, listed, parameters, float16_depth)
        start = time.perf_counter()
        response = self._request("POST", protocol.PATH, content=body, headers=headers)
        latency = time.perf_counter() - start
        try:
            answer = protocol.read_answer(
                response.content, response.headers.get(HEADER_LENGTH), image.shape
            )
        except protocol.AnswerError as exc:
            raise ClientError(f"unexpected answer from {self.url}{protocol.PATH}: {exc}") from exc
        return Completion(
            answer.depth,
            answer.mask,
            answer.points,
            answer.sigma,
            answer.normals,
            answer.meta,
            latency,
        )

    def pose(
        self,
        gray: Source,
        sparse: Source | None,
        target: str,
        *,
        returns: np.ndarray | None = None,
        init: Pose | dict | None = None,
        intrinsics: Intrinsics | GivenIntrinsics | None = None,
        depth_scale: float | None = None,
        outlier_removal: bool = False,
        max_sigma: float | None = None,
    ) -> PoseAnswer:
        """The pose of the known ``target`` in one frame (``POST /pose``): from scratch, or
        refined from ``init`` (a previous answer's ``pose``, a ``Pose`` or its JSON dict) to
        track. The frame's inputs as for ``complete`` (``sparse=None`` with ``returns``); the
        returns travel as a list, the gray image as its file (a PNG of an array). The points
        registered are those of sigma up to ``max_sigma`` (metres), else up to the frame's
        90th percentile of sigma (the service's choice)."""
        image, gray_file = _gray_file(gray)
        listed = returns_list(sparse, returns, image.shape, depth_scale)
        fields = {name: repr(value) for name, value in _given(intrinsics).items()}
        fields["outlier_removal"] = "true" if outlier_removal else "false"
        if max_sigma is not None:
            fields["max_sigma"] = repr(float(max_sigma))
        fields["target"] = target
        if init is not None:
            fields["init"] = json.dumps(init.as_dict() if isinstance(init, Pose) else init)
        body, headers = form.pose_form(gray_file, listed, fields)
        start = time.perf_counter()
        response = self._request("POST", "/pose", content=body, headers=headers)
        latency = time.perf_counter() - start
        try:
            answer = response.json()
            return PoseAnswer(parse_pose(answer["pose"]), answer, latency)
        except (ValueError, KeyError, TypeError) as exc:
            raise ClientError(f"unexpected answer from {self.url}/pose: {exc}") from exc

    def target_points(self, name: str) -> np.ndarray:
        """(N, 3) samples of a known target's surface, its frame, metres (to draw it)."""
        points = self._request("GET", f"/targets/{quote(name, safe='')}").json()["points"]
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
