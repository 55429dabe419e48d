"""uvicorn's HTTP/1.1 protocol (h11) with a deadline on every request head.

uvicorn bounds a request head's size (``h11_max_incomplete_event_size``) and closes a
keep-alive connection idle for ``timeout_keep_alive`` after an answer, but it puts no deadline
on a head that never completes: a connection that sends half a request line, or one header
line every few seconds (slowloris), or nothing at all, is kept for ever. Here a connection
must deliver each request's complete head within ``head_timeout_s`` of being opened or of
its previous answer, else it is closed; while a request is being answered, the service's own
deadlines apply (``sdcnet.service.admission``).

It also hands the application a way to drop a connection (``ABORT`` in the request scope's
``extensions``): uvicorn closes a connection whose answer failed by flushing what it has
buffered first, so a client that reads nothing keeps it (and a megabyte of answer) open for
ever; the service drops such a connection once its answer is late
(``sdcnet.service.admission``).

The class extends uvicorn's ``H11Protocol`` through the hooks it calls on a connection
(``connection_made``, ``handle_events``, ``on_response_complete``, ``connection_lost``) and
reads its ``cycle``, ``scope``, ``transport`` and ``loop``; ``tests/test_deadlines.py`` holds
it to the behaviour.
"""

from __future__ import annotations

import asyncio
import socket
import struct

from uvicorn.protocols.http.h11_impl import H11Protocol

#: Key of the request scope's ``extensions`` whose value drops the connection (no argument).
ABORT = "sdcnet.abort"


class HeadDeadlineProtocol(H11Protocol):
    """``H11Protocol`` that closes a connection whose next request head is not complete within
    ``head_timeout_s`` seconds (a class attribute: ``with_head_timeout`` makes the class)."""

    head_timeout_s: float = 10.0
    _head_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm()

    def handle_events(self) -> None:
        super().handle_events()
        if self.scope is not None:  # the request just parsed, before its application runs
            self.scope.setdefault("extensions", {})[ABORT] = self._drop

    def _drop(self) -> None:
        """Reset the connection: what the kernel still holds of the answer goes too (a plain
        close would leave it, and the socket, to a client that reads nothing)."""
        sock = self.transport.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.transport.abort()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._arm()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def _arm(self) -> None:
        self._disarm()
        self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_timed_out)

    def _disarm(self) -> None:
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None

    def _head_timed_out(self) -> None:
        self._head_timer = None
        answering = self.cycle is not None and not self.cycle.response_complete
        if not answering and not self.transport.is_closing():
            self.transport.close()


def with_head_timeout(head_timeout_s: float) -> type[HeadDeadlineProtocol]:
    """The protocol class for ``uvicorn.run(http=...)`` with this head deadline (seconds)."""
    return type("HeadDeadlineProtocol", (HeadDeadlineProtocol,), {"head_timeout_s": head_timeout_s})
