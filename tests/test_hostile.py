"""A catalogue of crafted, hostile requests sent to the real service over real HTTP: image
bombs and huge declared sizes, pickles and object arrays, truncated and stalled uploads,
wrong content types, malformed multipart, extra and repeated fields.

Each must get a 4xx (the status and error code it should), fast, without the server's memory
growing: a bound on each request's wall time catches hangs, and the server's peak resident
memory (VmHWM in /proc) is compared with what it held after a first real frame.
test_service.py covers the plainer bad inputs (empty, truncated or corrupt files, wrong dtype
or shape, bad depths, a simple pickle, a too-large real image): none is repeated here.
"""

from __future__ import annotations

import gzip
import json
import re
import socket
import struct
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import cv2
import httpx
import numpy as np
import pytest

from sdcnet.npyio import npy_bytes
from sdcnet.service.budget import budget
from sdcnet.service.settings import Settings
from tests.support.attacks import (
    LIBRARY_HINTS,
    bright_frame,
    csv_returns,
    huge_integer,
    reset_peak,
    v2_json_zeros,
)
from tests.support.frames import multipart_body, png_bytes, sample_files, synthetic_frame
from tests.support.serving import memory_kib, service_process

V2_INFER = "/v2/models/sdcnet/infer"
MAX_PIXELS = 1024 * 1024
MAX_RETURNS = 50_000
MAX_UPLOAD_BYTES = 8 * 2**20
BODY_TIMEOUT_S = 1.0
WALL_LIMIT_S = 5.0  # per request: generous, only to catch hangs
PEAK_GROWTH_LIMIT_MIB = 160  # the 20000 x 20000 bomb alone would take 381 MiB decoded
MARKER = "hostile-marker"  # a file that only code run by unpickling would create


@pytest.fixture(scope="module")
def service(tmp_path_factory, tiny_model_path):
    """The service with small limits, after one real frame (so its memory is warmed up); a
    point a pixel in every cloud, the heaviest answer the memory budget allows for."""
    log = tmp_path_factory.mktemp("hostile") / "serve.log"
    flags = [f"--max-pixels={MAX_PIXELS}", f"--max-upload-bytes={MAX_UPLOAD_BYTES}"]
    flags += [f"--max-points={MAX_PIXELS}"]
    flags += [f"--max-returns={MAX_RETURNS}"]
    flags += [f"--body-timeout={BODY_TIMEOUT_S}", "--max-in-flight=2"]
    with service_process(tiny_model_path, log, *flags) as running:
        response = httpx.post(f"{running.url}/complete", files=good_files(), timeout=60)
        assert response.status_code == 200, response.text
        yield running


@pytest.fixture(scope="module")
def baseline_kib(service) -> int:
    return memory_kib(service.pid)["rss"]


# -- what the cases are made of ----------------------------------------------------------


def good_files() -> dict[str, tuple[str, bytes]]:
    return sample_files(synthetic_frame(256))


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def png(width: int, height: int, depth: int, colour: int, inflated: int | None = None) -> bytes:
    """A PNG with a valid IHDR and one IDAT of ``inflated`` zero bytes (default: exactly the
    rows its size needs, all black), deflated in 1 MiB steps so none is ever held whole."""
    header = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    if inflated is None:
        channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
        inflated = height * (1 + -(-width * channels * depth // 8))
    stream, block = zlib.compressobj(9), bytes(2**20)
    idat = [stream.compress(block) for _ in range(inflated // len(block))]
    idat += [stream.compress(bytes(inflated % len(block))), stream.flush()]
    return (
        b"\x89PNG\r\n\x1a\n"
        + _chunk(b"IHDR", header)
        + _chunk(b"IDAT", b"".join(idat))
        + _chunk(b"IEND", b"")
    )


def jpeg_with_scans(count: int) -> bytes:
    """The test frame as a progressive JPEG, one of its scans repeated up to ``count`` scans:
    libjpeg decodes it (with a warning), each scan going over the whole frame again."""
    data = png_bytes(synthetic_frame(256).gray, ".jpg", [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])
    starts = [m.start() for m in re.finditer(b"\xff\xda", data)]
    scan = data[starts[-2] : starts[-1]]
    return data[: starts[-1]] + scan * (count - len(starts)) + data[starts[-1] :]


def bmp_header(width: int, height: int) -> bytes:
    info = struct.pack("<IiiHHIIiiII", 40, width, height, 1, 8, 0, 0, 0, 0, 0, 0)
    return b"BM" + struct.pack("<IHHI", 14 + len(info), 0, 0, 14 + len(info)) + info


def tiff_header(width: int, length: int, ifd_offset: int = 8) -> bytes:
    entries = [(256, 4, 1, width), (257, 4, 1, length), (258, 3, 1, 8), (262, 3, 1, 1)]
    ifd = struct.pack("<H", len(entries))
    ifd += b"".join(struct.pack("<HHII", *entry) for entry in entries) + bytes(4)
    return b"II*\x00" + struct.pack("<I", ifd_offset) + ifd


def jpeg_header(width: int, height: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, height, width, 1) + b"\x01\x11\x00"
    return b"\xff\xd8" + sof + b"\xff\xd9"


def npy_with_header(header: str, data: bytes = b"", major: int = 1) -> bytes:
    """A .npy file with a literal header dict (padded as numpy pads it) and raw data."""
    text = header.encode("latin-1")
    length = len(text) + 1
    text += b" " * (-(10 + length) % 64) + b"\n"
    size = struct.pack("<H", len(text)) if major == 1 else struct.pack("<I", len(text))
    return b"\x93NUMPY" + bytes([major, 0]) + size + text + data


class Unpickled:
    """Unpickling this object creates the file ``MARKER`` in the working directory."""

    def __init__(self, path: Path):
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


def pickled_payload(tmp: Path) -> bytes:
    return npy_bytes(np.array([Unpickled(tmp / MARKER)], dtype=object), allow_pickle=True)


def multipart(*parts: tuple[bytes, bytes], boundary: bytes = b"hostile", end: bool = True) -> bytes:
    """A multipart body from (part headers, part data) pairs, by hand, so it can be wrong."""
    body = b"".join(b"--" + boundary + b"\r\n" + h + b"\r\n\r\n" + d + b"\r\n" for h, d in parts)
    return body + (b"--" + boundary + b"--\r\n" if end else b"")


def file_part(name: str, data: bytes) -> tuple[bytes, bytes]:
    header = f'Content-Disposition: form-data; name="{name}"; filename="{name}.bin"'
    return header.encode(), data


def field_part(name: str, value: bytes) -> tuple[bytes, bytes]:
    return f'Content-Disposition: form-data; name="{name}"'.encode(), value


def good_parts() -> list[tuple[bytes, bytes]]:
    return [file_part(name, data) for name, (_, data) in good_files().items()]


MULTIPART = "multipart/form-data; boundary=hostile"


# -- how the cases are sent --------------------------------------------------------------


@dataclass(frozen=True)
class Answer:
    status: int | None  # None: the server closed the connection without an answer
    body: bytes
    seconds: float

    def code(self) -> str | None:
        try:
            return httpx.Response(self.status or 0, content=self.body).json()["error"]["code"]
        except (ValueError, KeyError, TypeError):
            return None


def send(url: str, body: bytes, content_type: str | None, **headers: str) -> Answer:
    """POST /complete with exactly these bytes and headers."""
    if content_type is not None:
        headers["content-type"] = content_type
    start = time.perf_counter()
    response = httpx.post(f"{url}/complete", content=body, headers=headers, timeout=30)
    return Answer(response.status_code, response.content, time.perf_counter() - start)


def send_raw(url: str, request: bytes, half_close: bool = False) -> Answer:
    """Write ``request`` on a socket (``half_close``: then shut the writing side, as a client
    that gives up does) and read until the server closes; HTTP/1.1 with Connection: close."""
    address = urlsplit(url)
    start = time.perf_counter()
    with socket.create_connection((address.hostname, address.port), timeout=30) as sock:
        sock.sendall(request)
        if half_close:
            sock.shutdown(socket.SHUT_WR)
        received = b""
        while chunk := sock.recv(65536):
            received += chunk
    seconds = time.perf_counter() - start
    if not received:
        return Answer(None, b"", seconds)
    head, _, body = received.partition(b"\r\n\r\n")
    return Answer(int(head.split()[1]), body, seconds)


def raw_request(body: bytes, content_length: int | str | None = None, *headers: str) -> bytes:
    lines = ["POST /complete HTTP/1.1", "Host: 127.0.0.1", f"Content-Type: {MULTIPART}"]
    lines += [f"Content-Length: {len(body) if content_length is None else content_length}"]
    lines += ["Connection: close", *headers]
    return ("\r\n".join(lines) + "\r\n\r\n").encode() + body


# -- the catalogue -----------------------------------------------------------------------

Case = Callable[[str, Path], Answer]


def with_gray(make: Callable[[], bytes]) -> Case:
    """The good frame with its gray file replaced by ``make()`` (made when the case runs)."""
    return lambda url, tmp: send(url, *multipart_body({**good_files(), "gray": ("g", make())}))


def with_sparse(make: Callable[[], bytes]) -> Case:
    """The good frame with its sparse file replaced by ``make()``."""
    return lambda url, tmp: send(url, *multipart_body({**good_files(), "sparse": ("s", make())}))


Parts = Callable[[], list[tuple[bytes, bytes]]]


def with_parts(extra: Parts = list, parts: Parts = good_parts, end: bool = True) -> Case:
    """A hand-made multipart body: ``parts()`` (the good frame's two files), then ``extra()``."""
    return lambda url, tmp: send(url, multipart(*parts(), *extra(), end=end), MULTIPART)


def _pickle_case(url: str, tmp: Path) -> Answer:
    return with_sparse(lambda: pickled_payload(tmp))(url, tmp)


def _npy_header_code(url: str, tmp: Path) -> Answer:
    code = f"__import__('pathlib').Path({str(tmp / MARKER)!r}).touch()"
    header = f"{{'descr': {code}, 'fortran_order': False, 'shape': (256, 256), }}"
    return with_sparse(lambda: npy_with_header(header, bytes(256 * 256 * 4)))(url, tmp)


def _stalled_body(url: str, tmp: Path) -> Answer:
    body = multipart(*good_parts())
    return send_raw(url, raw_request(body[: len(body) // 2], len(body)))


def _abandoned_body(url: str, tmp: Path) -> Answer:
    body = multipart(*good_parts())
    return send_raw(url, raw_request(body[: len(body) // 2], len(body)), half_close=True)


def _cut_multipart(url: str, tmp: Path) -> Answer:
    body = multipart(*good_parts())
    return send(url, body[: len(body) - 5000], MULTIPART)


def _gzip_bomb(url: str, tmp: Path) -> Answer:
    bomb = gzip.compress(multipart(*good_parts()) + bytes(64 * 2**20), compresslevel=9)
    return send(url, bomb, MULTIPART, **{"content-encoding": "gzip"})


def gray_png() -> bytes:
    return good_files()["gray"][1]


def returns_files(returns: bytes) -> dict[str, tuple[str, bytes]]:
    """The good frame's gray image with ``returns`` as its list of returns."""
    return {"gray": good_files()["gray"], "returns": ("returns.bin", returns)}


def npy_returns(count: int) -> bytes:
    """``count`` returns at pixel (0, 0), 100 m, as a .npy."""
    return npy_bytes(np.tile(np.float32([0, 0, 100]), (count, 1)))


def v2_with_shape(shape: list[int]) -> bytes:
    gray = {"name": "gray", "datatype": "UINT8", "shape": shape, "data": [0]}
    return json.dumps({"inputs": [gray]}).encode()


def send_v2(url: str, body: bytes) -> Answer:
    """POST a JSON body to the v2 route; the code comes back in a header there."""
    start = time.perf_counter()
    response = httpx.post(
        f"{url}{V2_INFER}", content=body, headers={"content-type": "application/json"}, timeout=30
    )
    seconds = time.perf_counter() - start
    code = response.headers.get("sdcnet-error-code")
    message = response.json().get("error", "") if response.status_code >= 400 else ""
    document = {"error": {"code": code, "message": message}}
    return Answer(response.status_code, json.dumps(document).encode(), seconds)


#: case -> (how it is sent, expected status, expected error code; None: the server's own
#: HTTP-level answer, not the service's JSON)
CATALOGUE: dict[str, tuple[Case, int | None, str | None]] = {
    # images: bombs and huge declared sizes, refused from the header before decoding
    "png_bomb_20000x20000_1bit": (with_gray(lambda: png(20000, 20000, 1, 0)), 413, "too_large"),
    "png_declares_100000x100000": (
        with_gray(lambda: png(100000, 100000, 8, 0, inflated=0)),
        413,
        "too_large",
    ),
    "bmp_declares_50000x50000": (with_gray(lambda: bmp_header(50000, 50000)), 413, "too_large"),
    "bmp_declares_most_negative_height": (
        with_gray(lambda: bmp_header(4, -(2**31))),
        413,
        "too_large",
    ),
    "tiff_declares_100000x100000": (
        with_gray(lambda: tiff_header(100000, 100000)),
        413,
        "too_large",
    ),
    "tiff_ifd_outside_the_file": (
        with_gray(lambda: tiff_header(16, 16, 2**32 - 16)),
        400,
        "unreadable_file",
    ),
    "jpeg_declares_65535x65535": (with_gray(lambda: jpeg_header(65535, 65535)), 413, "too_large"),
    "jpeg_declares_0x16": (with_gray(lambda: jpeg_header(0, 16)), 400, "unreadable_file"),
    "jpeg_restart_marker_flood": (
        with_gray(lambda: b"\xff\xd8" + b"\xff\xd0" * (3 * 2**20)),
        400,
        "unreadable_file",
    ),
    # its header, found past the fill, declares 16 x 16: not the sparse map's size, refused
    # before anything is decoded
    "jpeg_fill_byte_flood": (
        with_gray(lambda: b"\xff\xd8" + b"\xff" * (7 * 2**20) + jpeg_header(16, 16)[3:]),
        422,
        "wrong_shape",
    ),
    # decodes (8 MiB, within the pixel limit, from a 30 kB file), then refused: sizes differ
    "png_rgba16_at_the_pixel_limit": (
        with_gray(lambda: png(1024, 1024, 16, 6)),
        422,
        "wrong_shape",
    ),
    # complete PNGs whose image data inflates to 256 MiB: libpng would inflate it all (1 s)
    "png_16x16_inflating_to_256MiB": (
        with_gray(lambda: png(16, 16, 8, 0, inflated=2**28)),
        400,
        "unreadable_file",
    ),
    "png_at_the_pixel_limit_inflating_to_256MiB": (
        with_gray(lambda: png(1024, 1024, 8, 0, inflated=2**28)),
        400,
        "unreadable_file",
    ),
    # decodes in libjpeg (with a warning): each of the 3000 scans goes over the whole frame
    "jpeg_of_3000_scans": (with_gray(lambda: jpeg_with_scans(3000)), 400, "unreadable_file"),
    # .npy: never unpickled, header never evaluated
    "npy_pickle_that_writes_a_file": (_pickle_case, 400, "pickle_not_allowed"),
    "npy_object_array": (
        with_sparse(lambda: npy_bytes(np.array([1.0, "a", None], dtype=object), allow_pickle=True)),
        400,
        "pickle_not_allowed",
    ),
    "npy_structured_with_object_field": (
        with_sparse(
            lambda: npy_bytes(np.zeros(4, dtype=[("a", "<f4"), ("b", "O")]), allow_pickle=True)
        ),
        400,
        "pickle_not_allowed",
    ),
    "npy_header_with_code": (_npy_header_code, 400, "unreadable_file"),
    "npy_header_length_4GiB": (
        with_sparse(lambda: b"\x93NUMPY\x02\x00\xff\xff\xff\xff{'descr': '<f4'"),
        400,
        "unreadable_file",
    ),
    "npy_negative_shape": (
        with_sparse(
            lambda: npy_with_header(
                "{'descr': '<f4', 'fortran_order': False, 'shape': (-256, -256), }",
                bytes(256 * 256 * 4),
            )
        ),
        400,
        "unreadable_file",
    ),
    # uploads cut short, stalled or abandoned
    "body_shorter_than_content_length_then_stalled": (_stalled_body, 408, "request_timeout"),
    # the multipart parser drops an unfinished last part (here sparse): never a cut file
    "multipart_cut_short": (_cut_multipart, 422, "invalid_request"),
    "multipart_without_closing_boundary": (with_parts(end=False), 422, "invalid_request"),
    # wrong content types
    "json_body": (
        lambda url, tmp: send(url, b'{"gray": "AAAA", "sparse": "AAAA"}', "application/json"),
        422,
        "invalid_request",
    ),
    "raw_png_body": (lambda url, tmp: send(url, gray_png(), "image/png"), 422, "invalid_request"),
    "urlencoded_form": (
        lambda url, tmp: send(url, b"gray=abc&sparse=def", "application/x-www-form-urlencoded"),
        422,
        "invalid_request",
    ),
    "no_content_type": (lambda url, tmp: send(url, gray_png(), None), 422, "invalid_request"),
    "multipart_without_boundary": (
        lambda url, tmp: send(url, multipart(*good_parts()), "multipart/form-data"),
        400,
        "bad_request",
    ),
    "multipart_with_another_boundary": (
        lambda url, tmp: send(url, multipart(*good_parts(), boundary=b"other"), MULTIPART),
        400,
        "bad_request",
    ),
    "gzip_bomb_body": (_gzip_bomb, 400, "bad_request"),
    # fields: extra, repeated, misplaced, too many, too big
    "extra_text_field": (
        with_parts(lambda: [field_part("outlier_remova", b"true")]),
        422,
        "invalid_request",
    ),
    "extra_file_field": (
        with_parts(lambda: [file_part("depth", good_files()["sparse"][1])]),
        422,
        "invalid_request",
    ),
    "duplicated_gray_file": (
        with_parts(lambda: [file_part("gray", gray_png())]),
        422,
        "invalid_request",
    ),
    "duplicated_fx_field": (
        with_parts(lambda: [field_part("fx", b"500"), field_part("fx", b"600")]),
        422,
        "invalid_request",
    ),
    "gray_as_a_text_field": (
        with_parts(lambda: [field_part("gray", b"not a file")], parts=lambda: good_parts()[1:]),
        422,
        "invalid_request",
    ),
    "part_without_a_name": (
        with_parts(lambda: [(b"Content-Disposition: form-data", b"x")]),
        400,
        "bad_request",
    ),
    "2000_fields": (
        with_parts(lambda: [field_part(f"f{i}", b"") for i in range(2000)]),
        400,
        "bad_request",
    ),
    "text_field_above_1MiB": (
        with_parts(lambda: [field_part("fx", b"1" * (2**20 + 10))]),
        400,
        "bad_request",
    ),
    # sizes checked against the frame (256 x 256) and the limits before anything is parsed
    "returns_csv_of_more_lines_than_the_frame_has_pixels": (
        lambda url, tmp: send(url, *multipart_body(returns_files(csv_returns(70_000)))),
        413,
        "too_large",
    ),
    "returns_npy_of_more_than_max_returns": (
        lambda url, tmp: send(url, *multipart_body(returns_files(npy_returns(MAX_RETURNS + 1)))),
        413,
        "too_large",
    ),
    "npy_shape_of_5000_digits": (
        with_sparse(
            lambda: npy_with_header(
                f"{{'descr': '<f4', 'fortran_order': False, 'shape': ({huge_integer()}, 2), }}"
            )
        ),
        400,
        "unreadable_file",
    ),
    "v2_shape_of_100000_dimensions": (
        lambda url, tmp: send_v2(url, v2_with_shape([1] * 100_000)),
        400,
        "invalid_request",
    ),
    "v2_data_beyond_its_shape": (
        lambda url, tmp: send_v2(url, v2_json_zeros(3_500_000)),
        400,
        "invalid_request",
    ),
    # HTTP itself: uvicorn answers this before the service sees it
    "content_length_not_a_number": (
        lambda url, tmp: send_raw(url, raw_request(b"x", "twelve")),
        400,
        None,
    ),
}


@pytest.fixture(scope="module")
def answers(service, baseline_kib, tmp_path_factory) -> dict[str, tuple[Answer, Path]]:
    """Every case of the catalogue sent once, in the catalogue's order, after the baseline was
    read; each with a folder of its own (where an unpickled upload would leave its marker)."""
    sent = {}
    for case, (send_case, _, _) in CATALOGUE.items():
        folder = tmp_path_factory.mktemp("hostile-case")
        sent[case] = (send_case(service.url, folder), folder)
    return sent


@pytest.mark.parametrize("case", list(CATALOGUE))
def test_hostile_request_gets_its_4xx_fast(answers, case):
    _, status, code = CATALOGUE[case]
    answer, folder = answers[case]
    assert answer.seconds < WALL_LIMIT_S, f"{case} took {answer.seconds:.1f} s"
    assert (answer.status, answer.code()) == (status, code), answer.body[:300]
    assert not (folder / MARKER).exists(), "the service ran code from the upload"


def test_a_client_that_gives_up_mid_body_is_dropped(service, baseline_kib):
    """Half the body, then the client shuts its side: nothing to answer to; the service closes
    the connection at once and keeps serving."""
    answer = _abandoned_body(service.url, Path())
    assert answer.seconds < WALL_LIMIT_S
    assert answer.status is None or 400 <= answer.status < 500


def test_no_answer_echoes_a_library_or_its_hints(answers):
    """Errors are in the service's words: no library's name, and none of its hints on how to
    lift a safety limit (numpy's "allow_pickle=True", Python's "sys.set_int_max_str_digits")."""
    for case, (answer, _) in answers.items():
        text = answer.body.decode("utf-8", "replace")
        assert not [hint for hint in LIBRARY_HINTS if hint in text], (case, text[:300])


def peak_of(service, request: Callable[[], httpx.Response]) -> tuple[httpx.Response, float]:
    """``request()``'s answer and how far it raised the server's peak memory, MiB (the peak
    reset to the resident memory first)."""
    reset_peak(service.pid)
    before = memory_kib(service.pid)["peak"]
    response = request()
    return response, (memory_kib(service.pid)["peak"] - before) / 1024


def test_v2_json_data_is_counted_against_its_shape_before_it_is_parsed(service):
    """A [1, 1] gray with 3.5M zeros (7 MB): refused before any value becomes a Python object
    (those took 8 to 32 bytes a value: +0.7 GiB for 15M)."""
    body = v2_json_zeros(3_500_000)
    response, growth = peak_of(
        service,
        lambda: httpx.post(
            f"{service.url}{V2_INFER}",
            content=body,
            headers={"content-type": "application/json"},
            timeout=30,
        ),
    )
    assert response.status_code == 400 and "shape [1, 1] needs 1" in response.json()["error"]
    assert growth < 2 * len(body) / 2**20, f"+{growth:.0f} MiB"


def test_the_worst_frame_stays_within_the_request_budget(service):
    """The largest frame the service takes, all foreground to the tiny model, a return every
    5 pixels along rows and columns, outlier removal and a JSON answer: its peak stays within
    the budget of one request (``sdcnet.service.budget``; before, the outlier removal alone
    took 100 MB at 1024 x 1024)."""
    gray, returns = bright_frame(1024, every=5)
    files = {"gray": ("g.png", gray), "returns": ("r.npy", returns)}
    response, growth = peak_of(
        service,
        lambda: httpx.post(
            f"{service.url}/complete", files=files, data={"outlier_removal": "true"}, timeout=120
        ),
    )
    assert response.status_code == 200, response.text
    assert response.json()["point_count"] > 1000**2
    limits = Settings(max_pixels=MAX_PIXELS, max_upload_bytes=MAX_UPLOAD_BYTES, threads=1)
    assert growth <= budget(limits).request_mib, f"+{growth:.0f} MiB"


def test_still_serving_without_a_500_and_memory_bounded(service, baseline_kib, answers):
    """After the whole catalogue (``answers``): a real frame still gets 200, no request was
    counted as an internal error, and the server's peak memory stayed bounded."""
    response = httpx.post(f"{service.url}/complete", files=good_files(), timeout=60)
    assert response.status_code == 200, response.text
    metrics = httpx.get(f"{service.url}/metrics").text
    assert 'reason="internal_error"' not in metrics
    memory = memory_kib(service.pid)
    growth_mib = (memory["peak"] - baseline_kib) / 1024
    assert growth_mib < PEAK_GROWTH_LIMIT_MIB, (memory, baseline_kib)
