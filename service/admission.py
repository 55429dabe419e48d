"""What happens to a request before the application sees it and after it answered, and the count
of how it ended: admission, deadlines and shedding.

A pure ASGI middleware, so that it can answer before a body is read and keep a request's
phases apart. Every request: a body above ``max_upload_bytes`` gets 413 (from its
Content-Length when declared, else as soon as the bytes pass it). The inference routes, those
that declare ``dependencies=[TAKES_SLOT]`` (``POST /complete``, ``POST
/v2/models/sdcnet/infer``, ``POST /pose``), then go through four phases, each bounded
(``docs/service.md``, "Hostile and careless clients"):

1. **held**: at most ``max_requests`` inference requests at once, in all the phases below;
   the next gets 503 at once, its body unread;
2. **receiving**: the body is read into a ``Spool`` (memory up to 2 MiB, a temporary file
   beyond) before the request takes an in-flight place, so that a slow upload holds no place
   and little memory: a body that stalls ``body_timeout_s`` between two chunks, or arrives at
   less than ``min_rate`` bytes/s on average once its first ``body_timeout_s`` are over,
   gets 408 and its connection closed;
3. **in flight**: at most ``max_in_flight`` requests are decoded, completed and encoded at
   once, each within the memory budget; a received request waits for a place at most
   ``queue_timeout_s``, in order of arrival, then gets 503: shed early rather than answer late;
4. **answering**: the answer (which the routes spool) must leave at ``min_rate`` on average
   once its first ``body_timeout_s`` are over, else the connection is closed; the in-flight
   place is given back as the answer starts, so that a client that reads slowly holds none.

The whole request, from its head to the last byte of its answer, must end within
``request_timeout_s``: past it, 408 while the body arrives, 503 before the answer starts, the
connection closed after. Every 503 says Retry-After. The pending gauge, the success and
failure counters and the request latency are kept here, where every outcome passes, the
early refusals included. Probes and metrics are never limited.
"""

from __future__ import annotations

import asyncio
import collections
import time
from collections.abc import Callable, Sequence

from fastapi import APIRouter, Depends
from fastapi.routing import APIRoute
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from sdcnet.service.errors import ApiError, error_response, is_v2
from sdcnet.service.metrics import ServiceMetrics
from sdcnet.service.protocol import ABORT
from sdcnet.service.settings import Settings
from sdcnet.service.spool import Spool


async def inference_slot() -> None:
    """FastAPI dependency that marks a route as an inference one, ``dependencies=[TAKES_SLOT]``
    on the route (or its router). It does nothing itself: ``Admission``, which runs before
    routing, finds the marked routes among the application's routers (``slot_routes``) and
    bounds their requests."""


TAKES_SLOT = Depends(inference_slot)


def slot_routes(routers: Sequence[APIRouter]) -> tuple[APIRoute, ...]:
    """The routes of ``routers`` (included in the application without a prefix) that take an
    inference slot (``TAKES_SLOT``, on the route or its router)."""
    return tuple(
        route
        for router in routers
        for route in router.routes
        if isinstance(route, APIRoute)
        and any(depends.dependency is inference_slot for depends in route.dependencies)
    )


class _ClientGoneError(Exception):
    """The client went away, or read its answer too slowly: nobody to answer."""


def abort(scope: Scope) -> None:
    """Drop the request's connection at once, what it has not sent of its answer with it
    (``sdcnet.service.protocol``; a close would wait for a client that reads nothing)."""
    drop = scope.get("extensions", {}).get(ABORT)
    if drop is not None:
        drop()


def declared_length(scope: Scope) -> int:
    """The request's Content-Length, bytes (0 when it declares none)."""
    value = dict(scope["headers"]).get(b"content-length", b"0")
    try:
        return int(value)
    except ValueError:  # uvicorn's h11 parser refuses such a request before it gets here
        return 0


class Admission:
    """The middleware (see the module doc); ``app.add_middleware(Admission, ...)`` with the
    application's ``routers``."""

    def __init__(
        self,
        app: ASGIApp,
        metrics: ServiceMetrics,
        settings: Settings,
        routers: Sequence[APIRouter],
    ):
        self.app = app
        self.metrics = metrics
        self.settings = settings
        self.slot_routes = slot_routes(routers)
        # touched on the event loop only: no lock needed
        self.requests = 0  # inference requests held, whatever their phase
        self.in_flight = 0  # of which holding an in-flight place
        self.waiting: collections.deque[asyncio.Future[None]] = collections.deque()

    # -- the errors it answers ----------------------------------------------------------------

    def _too_large(self) -> ApiError:
        limit = self.settings.max_upload_bytes
        return ApiError(
            413, "too_large", f"request body above this service's limit of {limit} bytes"
        )

    def _too_slow(self, stalled: bool) -> ApiError:
        s = self.settings
        if stalled:
            why = (
                f"stalled for more than {s.body_timeout_s:g} s (less data than its "
                "Content-Length, or a cut connection?)"
            )
        else:
            why = (
                f"arrived at less than {s.min_rate:g} bytes/s after its first "
                f"{s.body_timeout_s:g} s, or took more than the {s.request_timeout_s:g} s a "
                "request may take"
            )
        return ApiError(408, "request_timeout", f"the request body {why}", {"Connection": "close"})

    def _overloaded(self, why: str) -> ApiError:
        retry = self.settings.retry_after_s
        return ApiError(
            503, "overloaded", f"{why}; retry after {retry} s", {"Retry-After": str(retry)}
        )

    # -- every request ------------------------------------------------------------------------

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        inference = any(route.matches(scope)[0] is Match.FULL for route in self.slot_routes)
        if declared_length(scope) > self.settings.max_upload_bytes:
            await self._refuse(self._too_large(), inference, scope, receive, send)
        elif not inference:
            await self.app(scope, self._limited(receive), send)
        elif self.requests >= self.settings.max_requests:
            why = f"{self.requests} requests are held, the most this service takes at once"
            await self._refuse(self._overloaded(why), True, scope, receive, send)
        else:
            self.requests += 1
            self.metrics.pending.inc()
            try:
                await self._serve(scope, receive, send)
            finally:
                self.requests -= 1
                self.metrics.pending.dec()

    async def _refuse(
        self, error: ApiError, counted: bool, scope: Scope, receive: Receive, send: Send
    ) -> None:
        """Answer ``error`` before reading the body. A body too large is not read at all: the
        connection is closed after the answer (uvicorn would otherwise read it only to discard
        it: 134 MB took 2 s); others are drained, so that their clients read the answer on a
        connection they can keep."""
        if counted:
            self.metrics.failure.labels(error.code).inc()
        headers = dict(error.headers)
        if error.status_code == 413:
            headers["Connection"] = "close"
        response = error_response(
            error.status_code, error.code, error.message, headers, v2=is_v2(scope)
        )
        await response(scope, receive, send)

    def _limited(self, receive: Receive) -> Receive:
        """``receive`` of a route that is not an inference one: 413 once the body passes the
        byte limit, 408 when the next chunk of an unfinished body takes more than
        ``body_timeout_s``."""
        received, finished = 0, False

        async def wrapped() -> Message:
            nonlocal received, finished
            if finished:  # after the body, receive() waits for the disconnect: no deadline
                return await receive()
            try:
                async with asyncio.timeout(self.settings.body_timeout_s):
                    message = await receive()
            except TimeoutError:
                raise self._too_slow(stalled=True) from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.settings.max_upload_bytes:
                    raise self._too_large()
                finished = not message.get("more_body", False)
            return message

        return wrapped

    # -- an inference request -----------------------------------------------------------------

    async def _serve(self, scope: Scope, receive: Receive, send: Send) -> None:
        """One inference request through its phases (see the module doc)."""
        start = time.perf_counter()
        answer = _Answer(send, self.settings, self._give_back)
        spool = Spool()
        try:
            async with asyncio.timeout(self.settings.request_timeout_s):
                await self._receive(receive, spool)
                answer.phase = "waiting"
                waited = time.perf_counter()
                if not await self._take_place():
                    why = (
                        f"{self.settings.max_in_flight} requests are in flight and none ended "
                        f"within {self.settings.queue_timeout_s:g} s"
                    )
                    raise self._overloaded(why)
                answer.holds_place = True
                answer.waited_s = time.perf_counter() - waited
                answer.phase = "in flight"
                await self.app(scope, _replay(spool, receive), answer.send)
        except ApiError as error:
            await self._answer(error, answer, scope, receive)
        except TimeoutError:  # the whole-request deadline
            if answer.phase == "receiving":
                await self._answer(self._too_slow(stalled=False), answer, scope, receive)
            else:
                why = (
                    f"no answer within the {self.settings.request_timeout_s:g} s a request may take"
                )
                await self._answer(self._overloaded(why), answer, scope, receive)
        except _ClientGoneError:
            self.metrics.failure.labels("disconnected").inc()
            abort(scope)
            return
        except Exception:
            self.metrics.failure.labels("internal_error").inc()
            raise
        finally:
            answer.give_back()
            spool.close()
        if answer.status < 400:
            self.metrics.success.inc()
            self.metrics.request_duration.observe(time.perf_counter() - start)
            self.metrics.phase_duration.labels("wait").observe(answer.waited_s)
        elif answer.code is None:  # answered by the application
            reason = scope.get("state", {}).get("error_code", f"http_{answer.status}")
            self.metrics.failure.labels(reason).inc()

    async def _answer(
        self, error: ApiError, answer: _Answer, scope: Scope, receive: Receive
    ) -> None:
        """Answer ``error`` unless the answer has started (then the connection is aborted)."""
        self.metrics.failure.labels(error.code).inc()
        answer.code = error.code
        if answer.started:
            abort(scope)
            return
        response = error_response(
            error.status_code, error.code, error.message, error.headers, v2=is_v2(scope)
        )
        try:
            await response(scope, receive, answer.send)
        except _ClientGoneError:  # nobody reads it
            abort(scope)

    async def _receive(self, receive: Receive, spool: Spool) -> None:
        """The whole body into ``spool``; 408 for a body too slow, 413 too large;
        ``_ClientGoneError`` when the client goes away."""
        s = self.settings
        loop = asyncio.get_running_loop()
        started, received = loop.time(), 0
        while True:
            by_rate = started + s.body_timeout_s + received / s.min_rate
            by_stall = loop.time() + s.body_timeout_s
            try:
                async with asyncio.timeout_at(min(by_rate, by_stall)):
                    message = await receive()
            except TimeoutError:
                raise self._too_slow(stalled=by_stall <= by_rate) from None
            if message["type"] == "http.disconnect":
                raise _ClientGoneError
            body = message.get("body", b"")
            received += len(body)
            if received > s.max_upload_bytes:
                raise self._too_large()
            spool.write(body)
            if not message.get("more_body", False):
                return

    async def _take_place(self) -> bool:
        """Take an in-flight place, waiting ``queue_timeout_s`` at most behind the requests
        that came first; whether one was taken."""
        if self.in_flight < self.settings.max_in_flight and not self.waiting:
            self.in_flight += 1
            return True
        handed: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.waiting.append(handed)
        try:
            async with asyncio.timeout(self.settings.queue_timeout_s):
                await handed  # a request that ends hands its place over (give_back)
            return True
        except TimeoutError:
            if handed.done() and not handed.cancelled():  # handed over as the wait ended
                self._give_back()
            return False
        finally:
            if handed in self.waiting:
                self.waiting.remove(handed)

    def _give_back(self) -> None:
        """An in-flight place is free: to the first request still waiting, else to the pool."""
        while self.waiting:
            handed = self.waiting.popleft()
            if not handed.done():
                handed.set_result(None)
                return
        self.in_flight -= 1


class _Answer:
    """The ``send`` of one inference request: its status, the in-flight place given back as
    the answer starts, and the answer's pace (``min_rate`` after its first
    ``body_timeout_s``)."""

    def __init__(self, send: Send, settings: Settings, give_back: Callable[[], None]):
        self._send, self._settings, self._give_back = send, settings, give_back
        self.phase = "receiving"
        self.holds_place = False
        self.started = False
        self.status = 500
        self.code: str | None = None  # the error the middleware answered, if it did
        self.waited_s = 0.0  # for an in-flight place
        self._begun = 0.0
        self._sent = 0

    def give_back(self) -> None:
        if self.holds_place:
            self.holds_place = False
            self._give_back()

    async def send(self, message: Message) -> None:
        loop = asyncio.get_running_loop()
        if message["type"] == "http.response.start":
            self.give_back()
            self.phase, self.started, self.status = "answering", True, message["status"]
            self._begun = loop.time()
            await self._send(_with_wait(message, self.waited_s))
            return
        self._sent += len(message.get("body", b""))
        s = self._settings
        try:
            async with asyncio.timeout_at(self._begun + s.body_timeout_s + self._sent / s.min_rate):
                await self._send(message)
        except TimeoutError:
            raise _ClientGoneError from None


def _with_wait(start: Message, waited_s: float) -> Message:
    """An answer's start with the wait for an in-flight place added to its Server-Timing
    (answers that have one: the completed frames)."""
    headers = list(start.get("headers", []))
    for k, (name, value) in enumerate(headers):
        if name.lower() == b"server-timing":
            headers[k] = (name, value + b", wait;dur=%.3f" % (waited_s * 1e3))
            return {**start, "headers": headers}
    return start


def _replay(spool: Spool, receive: Receive) -> Receive:
    """``receive`` that gives the spooled body, a chunk at a time, then the real channel's
    messages (the disconnect)."""
    chunks = spool.chunks()
    ahead: bytes | None = next(chunks, b"")
    finished = False

    async def replayed() -> Message:
        nonlocal ahead, finished
        if finished:
            return await receive()
        body, ahead = ahead, next(chunks, None)
        finished = ahead is None
        return {"type": "http.request", "body": body, "more_body": not finished}

    return replayed
