"""Deadlines and shedding, against the real service (``sdc-serve`` in a subprocess on
127.0.0.1) with short settings, so that each case takes a second or two: uploads that trickle,
connections that never finish a head, answers read slowly, requests past the byte limit and
more requests than the service completes at once (``sdcnet.service.admission``,
``sdcnet.service.protocol``)."""

from __future__ import annotations

import http.client
import json
import socket
import time

import httpx
import pytest

from sdcnet.npyio import npy_bytes
from tests.support.attacks import (
    Trickler,
    bright_frame,
    closed_within,
    connect,
    request_head,
    status_of,
)
from tests.support.frames import multipart_body, png_bytes, synthetic_frame
from tests.support.serving import service_process

HEAD_TIMEOUT_S = 1.0
BODY_TIMEOUT_S = 1.0
MIN_RATE = 4 * 2**20  # bytes/s
QUEUE_TIMEOUT_S = 0.3
MAX_UPLOAD_BYTES = 8 * 2**20
SLACK_S = 1.5  # a loaded 2-core machine's delay beyond a deadline


@pytest.fixture(scope="module")
def url(tmp_path_factory, tiny_model_path):
    """One request completed at once, four held in all."""
    log = tmp_path_factory.mktemp("deadlines") / "serve.log"
    flags = ["--max-in-flight=1", "--max-requests=4", f"--queue-timeout={QUEUE_TIMEOUT_S}"]
    flags += [f"--body-timeout={BODY_TIMEOUT_S}", f"--min-rate={MIN_RATE}"]
    flags += [f"--head-timeout={HEAD_TIMEOUT_S}", "--keep-alive=1"]
    flags += [f"--max-upload-bytes={MAX_UPLOAD_BYTES}"]
    with service_process(tiny_model_path, log, *flags) as running:
        yield running.url


def form(size: int = 128) -> tuple[bytes, str]:
    s = synthetic_frame(size, seed=1)
    return multipart_body(
        {"gray": ("g.png", png_bytes(s.gray)), "sparse": ("s.npy", npy_bytes(s.sparse))}
    )


def valid(url: str) -> int:
    body, content_type = form()
    return httpx.post(
        f"{url}/complete", content=body, headers={"content-type": content_type}, timeout=30
    ).status_code


def test_trickling_uploads_hold_no_place_and_are_cut_at_the_minimum_rate(url):
    """Two uploads of a valid form, five bytes a second: before, each held an in-flight
    place for as long as it trickled (the stall timeout restarted with every byte)."""
    body, content_type = form()
    with Trickler(url, "/complete", 2, body, content_type, 0.2) as trickle:
        statuses = [valid(url) for _ in range(3)]
        deadline = time.monotonic() + BODY_TIMEOUT_S + 2 * SLACK_S
        while None in trickle.ended and time.monotonic() < deadline:
            time.sleep(0.1)
        ended = list(trickle.ended)
    assert statuses == [200, 200, 200]
    assert None not in ended, "a trickling upload was never cut"
    for seconds, status in ended:
        assert status == 408 and seconds <= BODY_TIMEOUT_S + SLACK_S


@pytest.mark.parametrize(
    "sends",
    [
        [b"POST /compl"],  # half a request line
        [b"POST /complete HTTP/1.1\r\n"] + [b"X-Slow: 1\r\n"] * 20,  # slowloris, 0.3 s apart
        [],  # nothing
    ],
    ids=["half_request_line", "slowloris", "silent"],
)
def test_a_connection_without_a_complete_head_is_closed(url, sends):
    sock = connect(url)
    start = time.monotonic()
    for chunk in sends:
        try:
            sock.sendall(chunk)
        except OSError:  # closed already
            break
        if closed_within(sock, 0.3)[0] is not None:
            break
    closed, _ = closed_within(sock, HEAD_TIMEOUT_S + SLACK_S)
    sock.close()
    assert closed is not None, "the connection is still open"
    assert time.monotonic() - start <= HEAD_TIMEOUT_S + SLACK_S + 0.3
    assert valid(url) == 200


def test_an_answer_read_slowly_gives_its_place_back_and_is_dropped(url):
    """A client that asks for a 12 MB answer and reads none of it: the others are served
    meanwhile, and once the answer is later than the minimum rate allows, the connection is
    dropped (before, the answer stayed in the server's buffers for as long as the client
    kept the connection)."""
    gray, returns = bright_frame(768, every=2)
    body, content_type = multipart_body({"gray": ("g.png", gray), "returns": ("r.npy", returns)})
    reader = connect(url, receive_buffer=4096)
    reader.sendall(request_head("/complete", len(body), content_type) + body)
    try:
        reader.settimeout(30)
        assert status_of(reader.recv(12, socket.MSG_PEEK)) == 200  # it began, unread
        assert [valid(url) for _ in range(2)] == [200, 200]
        dropped = reset_within(reader, BODY_TIMEOUT_S + 12e6 / MIN_RATE + SLACK_S)
    finally:
        reader.close()
    assert dropped, "the slow reader's connection is still open"


def reset_within(sock: socket.socket, limit_s: float) -> bool:
    """Whether the server resets the connection within ``limit_s``, read from the socket's
    pending error: reading would drain the answer the client is meant to leave unread."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR):
            return True
        time.sleep(0.1)
    return False


def test_requests_past_the_hold_get_503_and_the_held_wait_no_longer_than_the_queue(url):
    """Four requests held (their bodies one byte short), then two more: those two get 503
    with Retry-After at once, unread. The four then finish their bodies together: one place,
    so three queue; each is answered after waiting at most the queue timeout (the wait is in
    its Server-Timing) or shed with 503 "overloaded". Raw sockets, so that every request is
    held at the same time whatever the machine's speed (before, six clients racing each
    other could all be served one after another on a fast machine)."""
    body, content_type = form(512)
    head = request_head("/complete", len(body), content_type)
    held = [connect(url) for _ in range(4)]
    extra = [connect(url) for _ in range(2)]
    try:
        for sock in held:
            sock.sendall(head + body[:-1])
        time.sleep(0.1)  # the four heads read and held before the next two arrive
        for sock in extra:
            sock.sendall(head + body)
        for sock in extra:
            answer = read_answer(sock)
            assert answer.status == 503, answer.status
            assert json.loads(answer.read())["error"]["code"] == "overloaded"
            assert answer.getheader("retry-after")
        for sock in held:
            sock.sendall(body[-1:])
        answers = [read_answer(sock) for sock in held]
        statuses = [a.status for a in answers]
        assert set(statuses) <= {200, 503} and 200 in statuses, statuses
        for answer in answers:
            if answer.status == 503:
                assert json.loads(answer.read())["error"]["code"] == "overloaded"
                continue
            timing = answer.getheader("server-timing")
            waits = dict(part.split(";dur=") for part in timing.split(", "))
            assert float(waits["wait"]) <= QUEUE_TIMEOUT_S * 1e3 + 100
    finally:
        for sock in held + extra:
            sock.close()


def read_answer(sock: socket.socket) -> http.client.HTTPResponse:
    """The HTTP answer on a raw socket, its head parsed (the body left to ``read()``)."""
    sock.settimeout(30)
    answer = http.client.HTTPResponse(sock)
    answer.begin()
    return answer


def test_a_body_past_the_byte_limit_is_refused_unread_and_its_connection_closed(url):
    """A declared 100 MiB body: 413 at once and the connection closed, none of it read
    (before, uvicorn read all of it to discard it)."""
    sock = connect(url)
    sock.sendall(request_head("/complete", 100 * 2**20, "multipart/form-data; boundary=x"))
    sock.sendall(bytes(2**16))
    closed, answer = closed_within(sock, 5.0)
    sock.close()
    assert status_of(answer) == 413
    assert closed is not None and closed < 2.0
