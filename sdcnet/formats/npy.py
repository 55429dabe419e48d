"""``.npy`` bytes of floats read as the service and the client must read untrusted files: the
header parsed first, its shape checked by the caller before any data is read, the data read
in place and never unpickled. As a file of LIDAR returns (``FORMAT``): a dense map in metres,
or an (N, 3) list."""

from __future__ import annotations

import io
import math
from collections.abc import Callable

import numpy as np

from sdcnet.formats import NPY_MAGIC, FormatError, InputFormat


def read_floats(
    data: bytes, field: str, check_shape: Callable[[tuple[int, ...]], None] | None = None
) -> np.ndarray:
    """float32 array of ``.npy`` bytes of float32/float64 values; ``check_shape(shape)`` runs
    on the header's shape before the data is read (it raises to refuse it: a service checks
    the size an untrusted file declares). ``FormatError`` messages start with ``field``."""
    stream = io.BytesIO(data)
    try:
        major, _ = np.lib.format.read_magic(stream)
        read = (
            np.lib.format.read_array_header_1_0
            if major == 1
            else np.lib.format.read_array_header_2_0
        )
        shape, fortran, dtype = read(stream)
    except Exception:  # numpy parses the header dict with tokenize/ast: any error type
        raise FormatError(
            f"{field}: not a valid .npy header (a dict of descr, fortran_order and shape, "
            "each of a plain value)"
        ) from None
    if dtype.hasobject:
        raise FormatError(
            f"{field} .npy holds Python objects, which would need unpickling; sdcnet never "
            "unpickles: send float32 or float64 metres",
            "pickle_not_allowed",
        )
    if dtype.kind != "f" or dtype.itemsize not in (4, 8):
        raise FormatError(
            f"{field} .npy must hold float32 or float64 metres, got {dtype}", "wrong_dtype"
        )
    if any(size < 0 for size in shape):
        raise FormatError(f"{field}: the .npy header declares a negative size {shape}")
    if check_shape is not None:
        check_shape(shape)
    count = math.prod(shape)
    if len(data) - stream.tell() < count * dtype.itemsize:
        raise FormatError(
            f"{field}: the .npy data is shorter than its header's {list(shape)} {dtype} "
            "array (truncated?)"
        )
    values = np.frombuffer(data, dtype, count, stream.tell())
    return values.reshape(shape, order="F" if fortran else "C").astype(np.float32, order="C")


FORMAT = InputFormat(
    name=".npy",
    carries={
        "map": "a .npy of float32/float64 metres",
        "list": "a .npy of (N, 3) float32/float64 (exact, 12 bytes a return)",
    },
    recognise=lambda data: data.startswith(NPY_MAGIC),
    parse=lambda data, reading: read_floats(data, reading.field, reading.check_shape),
    endings=(".npy",),
)
