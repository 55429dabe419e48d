"""Connections that hold the service without finishing: A, uploads that trickle; F, requests
never finished (half a request line, slowloris, silence); K1, answers never read."""

from __future__ import annotations

import socket
import time

from benchmarks.hostile.client import (
    Context,
    Outcome,
    bright_form,
    count_statuses,
    frame_files,
    valid,
)
from tests.support.attacks import Trickler, closed_within, connect, request_head, status_of
from tests.support.frames import multipart_body

CLOSE_LIMIT_S = 30.0  # a half-open or idle connection is closed within this
WAIT_S = 35.0  # how long the connection attacks wait for the server to close


#: Seconds the tricklers are watched from their start: the service's body allowance (10 s),
#: two of their 2 s intervals, and a margin.
TRICKLE_WATCH_S = 15.0


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
        # A trickler sees its answer at its next byte: watch until each could have seen one
        # after the service's 10 s allowance.
        while None in trickle.ended and time.monotonic() - trickle.start < TRICKLE_WATCH_S:
            time.sleep(0.1)
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
