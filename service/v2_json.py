"""The JSON header of an Open Inference Protocol request, read without Python lists of its
tensors' values.

An input's ``data`` of a 2048 x 2048 image holds 4M values; as the Python objects that
``json.loads`` or pydantic build they take 8 to 32 bytes each (about 8 times their text),
before anything could compare their count with the declared shape (a [1, 1] gray with 15M
zeros cost 0.7 GiB to refuse). Here the header is split first, at C speed (``bytes`` and
``re`` methods; Python loops only over strings and brackets, both bounded):

1. ``split_data`` finds every ``"data": [...]`` array in the raw bytes, keeps its bytes aside
   and puts a placeholder in its place; what is left (names, shapes, datatypes, parameters: a
   few hundred bytes) must be under ``MAX_SKELETON_BYTES`` and is validated by the pydantic
   models as before;
2. ``data_values`` counts an array's values in its bytes (its commas), compares the count
   with the declared shape, and only then has numpy parse the text into an array (8 bytes a
   value), checked for the datatype.
"""

from __future__ import annotations

import json
import math
import re
import warnings
from dataclasses import dataclass

import numpy as np

#: Bytes of the JSON header besides its inputs' data: a request with three inputs, three
#: outputs, parameters and an id takes under 2 kB.
MAX_SKELETON_BYTES = 64 * 2**10
#: Strings in a JSON header: keys, names, datatypes, an id (a request has under 100).
MAX_STRINGS = 1024
#: Arrays ("[") in a JSON header: an input's data nested by rows has one per row, plus the
#: shapes; data of more rows goes flat (row-major), as tritonclient sends it.
MAX_ARRAYS = 65536
_STRING = re.compile(rb'"(?:[^"\\]++|\\.)*+"', re.DOTALL)
_KEY_END = re.compile(rb"\s*:\s*")
_ROW = re.compile(rb"\[([^\[\]]*)\]")
#: Bytes a JSON array of numbers is made of.
_NUMBER_TEXT = b"0123456789+-.eE, \t\r\n[]"
_FRACTION_TEXT = b".eE"


class JsonDataError(ValueError):
    """A header or data array that cannot be read; ``code`` names the problem for the
    service's error answers (``invalid_request``, ``wrong_dtype``)."""

    def __init__(self, message: str, code: str = "invalid_request"):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class DataArray:
    """Where an input's ``data`` array lies in its header: bytes ``start`` (its "[") to
    ``end`` (its "]", included)."""

    header: bytes | bytearray
    start: int
    end: int


@dataclass(frozen=True)
class SplitHeader:
    """A JSON header with each ``data`` array replaced by ``[k]`` (k: its index in
    ``arrays``), and where the arrays lie."""

    skeleton: bytes
    arrays: list[DataArray]


def split_data(header: bytes | bytearray) -> SplitHeader:
    """Take every ``"data": [...]`` array out of a JSON header (see the module doc); raises
    ``JsonDataError`` for a header of too many strings or arrays, or too large without its
    data."""
    if header.count(b'"') > 2 * MAX_STRINGS:
        raise JsonDataError(
            f"the inference header holds more than {MAX_STRINGS} strings: tensor data are numbers"
        )
    if header.count(b"[") > MAX_ARRAYS:
        raise JsonDataError(
            f"the inference header holds more than {MAX_ARRAYS} arrays: send each input's data "
            "flat (row-major), or as binary data"
        )
    strings = [m.span() for m in _STRING.finditer(header)]
    view = memoryview(header)
    pieces, arrays, at = [], [], 0
    for k, (start, end) in enumerate(strings):
        if start < at or not _is_data_key(header[start:end]):
            continue
        colon = _KEY_END.match(header, end)
        if colon is None or header[colon.end() : colon.end() + 1] != b"[":
            continue  # "data": null and the like: the models refuse them
        opening = colon.end()
        closing = _closing_bracket(header, opening)
        if any(opening < s < closing for s, _ in strings[k + 1 :]):
            raise JsonDataError("an input's data must hold numbers, got strings", "wrong_dtype")
        pieces += [view[at:opening], b"[%d]" % len(arrays)]
        arrays.append(DataArray(header, opening, closing))
        at = closing + 1
    skeleton = b"".join([*pieces, view[at:]])
    if len(skeleton) > MAX_SKELETON_BYTES:
        raise JsonDataError(
            f"the inference header holds {len(skeleton)} bytes besides its inputs' data, above "
            f"the {MAX_SKELETON_BYTES} a request needs"
        )
    return SplitHeader(skeleton, arrays)


def _is_data_key(token: bytes) -> bool:
    """Whether a JSON string token says ``data``, escapes included (``"d\\u0061ta"``)."""
    if token == b'"data"':
        return True
    if b"\\" not in token or len(token) > 32:  # "data" escaped in full is 26 bytes
        return False
    try:
        return json.loads(token) == "data"
    except ValueError:
        return False


def _closing_bracket(header: bytes | bytearray, opening: int) -> int:
    """Index of the bracket that closes the array opened at ``opening`` (``bytes.find``:
    one pass over the array, a Python step per bracket)."""
    depth = 1
    next_open, next_close = header.find(b"[", opening + 1), header.find(b"]", opening + 1)
    while next_close != -1:
        if -1 < next_open < next_close:
            depth += 1
            next_open = header.find(b"[", next_open + 1)
            continue
        depth -= 1
        if depth == 0:
            return next_close
        next_close = header.find(b"]", next_close + 1)
    raise JsonDataError("the inference header is not valid JSON: an array is not closed")


_NOT_SPACE = re.compile(rb"[^ \t\r\n]")


def data_values(
    name: str, array: DataArray, dtype: np.dtype, datatype: str, shape: tuple[int, ...]
) -> np.ndarray:
    """The values of one input's JSON ``data`` (flat, or nested by rows for a 2-D shape) as
    an array of ``dtype`` and ``shape``; counted in place (no copy) against the shape before
    they are read. Raises ``JsonDataError``."""
    header, first, last = array.header, array.start + 1, array.end
    expected = math.prod(shape)
    empty = _NOT_SPACE.search(header, first, last) is None
    count = 0 if empty else header.count(b",", first, last) + 1
    if count != expected:
        raise JsonDataError(
            f"input {name}: data holds {count} values, shape {list(shape)} needs {expected}"
        )
    body = bytes(header[first:last]).strip()
    if body.translate(None, _NUMBER_TEXT):
        raise JsonDataError(f"input {name}: data must hold {datatype} numbers", "wrong_dtype")
    if dtype.kind == "u" and any(c in body for c in _FRACTION_TEXT):
        raise JsonDataError(
            f"input {name}: data must hold {datatype} numbers, got fractions", "wrong_dtype"
        )
    if b"[" in body:
        _check_rows(name, body, shape)
    values = _parse(name, body.translate(None, b"[]"), count)
    if dtype.kind == "u" and values.size:
        low, high = values.min(), values.max()
        if low < 0 or high > np.iinfo(dtype).max:
            raise JsonDataError(
                f"input {name}: {datatype} values lie in 0..{np.iinfo(dtype).max}, got "
                f"{low:g}..{high:g}",
                "wrong_dtype",
            )
    return values.astype(dtype).reshape(shape)


def _check_rows(name: str, body: bytes, shape: tuple[int, ...]) -> None:
    """Data nested by rows: as many rows as the shape's first dimension, each as long as
    the second."""
    rows = _ROW.findall(body)
    rest = _ROW.sub(b"", body).translate(None, b", \t\r\n")
    regular = len(shape) == 2 and len(rows) == shape[0] and not rest
    if not regular or any(row.count(b",") + 1 != shape[1] for row in rows):
        raise JsonDataError(
            f"input {name}: data must be flat (row-major) or nested by rows, a regular "
            f"{list(shape)} array"
        )


def _parse(name: str, text: bytes, count: int) -> np.ndarray:
    """``count`` comma-separated numbers as float64."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            values = np.fromstring(text, dtype=np.float64, sep=",")
        except (ValueError, DeprecationWarning):
            values = np.empty(0)
    if values.size != count or not np.isfinite(values).all():
        raise JsonDataError(f"input {name}: data is not a list of numbers")
    return values
