"""What happens to a request before the application sees it, and the count of how it ended.

A pure ASGI middleware, so that it can answer before the body is read:

- every request: a body larger than ``max_upload_bytes`` gets 413, from its Content-Length
  when declared, else as soon as the streamed bytes pass the limit; a body that stalls for
  ``body_timeout_s`` between two chunks (a client that sent less than its Content-Length and
  waits, or a slow-loris) gets 408, so that it cannot hold an in-flight place for ever;
- inference (``POST /complete``, ``POST /v2/models/sdcnet/infer``, ``POST /pose``): at most
  ``max_in_flight`` at once between them, the next ones get 503 with
  Retry-After at once (no unbounded queue; Triton and Ray Serve do the same); the pending gauge,
  the success / failure counters and the request latency are kept here, where every outcome
  passes, the early refusals included. Probes and metrics are never limited.
"""

from __future__ import annotations

import asyncio
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from sdcnet.service.deps import MODEL_NAME
from sdcnet.service.errors import ApiError, error_response, is_v2, route_path
from sdcnet.service.metrics import ServiceMetrics

INFERENCE_PATHS = ("/complete", f"/v2/models/{MODEL_NAME}/infer", "/pose")


class Admission:
    """The middleware (see the module doc); ``app.add_middleware(Admission, ...)``."""

    def __init__(
        self,
        app: ASGIApp,
        metrics: ServiceMetrics,
        max_in_flight: int,
        max_upload_bytes: int,
        retry_after_s: int,
        body_timeout_s: float,
    ):
        self.app = app
        self.metrics = metrics
        self.max_in_flight = max_in_flight
        self.max_upload_bytes = max_upload_bytes
        self.retry_after_s = retry_after_s
        self.body_timeout_s = body_timeout_s
        self.in_flight = 0  # only touched on the event loop: no lock needed

    def _too_large(self) -> ApiError:
        return ApiError(
            413,
            "too_large",
            f"request body above this service's limit of {self.max_upload_bytes} bytes",
        )

    def _stalled(self) -> ApiError:
        return ApiError(
            408,
            "request_timeout",
            f"the request body stalled for more than {self.body_timeout_s:g} s (less data than "
            "its Content-Length, or a cut connection?)",
        )

    def _overloaded(self) -> ApiError:
        return ApiError(
            503,
            "overloaded",
            f"{self.max_in_flight} requests are in flight, the most this service takes; "
            f"retry after {self.retry_after_s} s",
            headers={"Retry-After": str(self.retry_after_s)},
        )

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        inference = scope["method"] == "POST" and route_path(scope) in INFERENCE_PATHS
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and int(declared) > self.max_upload_bytes:
            await self._refuse(self._too_large(), inference, scope, receive, send)
        elif not inference:
            await self.app(scope, self._limited(receive), send)
        elif self.in_flight >= self.max_in_flight:
            await self._refuse(self._overloaded(), inference, scope, receive, send)
        else:
            await self._admit(scope, self._limited(receive), send)

    async def _refuse(
        self, error: ApiError, counted: bool, scope: Scope, receive: Receive, send: Send
    ) -> None:
        """Answer ``error`` without reading the body (uvicorn discards what is left of it)."""
        if counted:
            self.metrics.failure.labels(error.code).inc()
        response = error_response(
            error.status_code, error.code, error.message, error.headers, v2=is_v2(scope)
        )
        await response(scope, receive, send)

    def _limited(self, receive: Receive) -> Receive:
        """``receive`` that raises 413 once the body passes the byte limit and 408 when the
        next chunk of an unfinished body takes more than ``body_timeout_s``."""
        received = 0
        finished = False

        async def wrapped() -> Message:
            nonlocal received, finished
            if finished:  # after the body, receive() waits for the disconnect: no deadline
                return await receive()
            try:
                async with asyncio.timeout(self.body_timeout_s):
                    message = await receive()
            except TimeoutError:
                raise self._stalled() from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_upload_bytes:
                    raise self._too_large()
                finished = not message.get("more_body", False)
            return message

        return wrapped

    async def _admit(self, scope: Scope, receive: Receive, send: Send) -> None:
        self.in_flight += 1
        self.metrics.pending.inc()
        start = time.perf_counter()
        status = 500

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        except Exception:
            self.metrics.failure.labels("internal_error").inc()
            raise
        else:
            if status < 400:
                self.metrics.success.inc()
                self.metrics.request_duration.observe(time.perf_counter() - start)
            else:
                reason = scope.get("state", {}).get("error_code", f"http_{status}")
                self.metrics.failure.labels(reason).inc()
        finally:
            self.in_flight -= 1
            self.metrics.pending.dec()
