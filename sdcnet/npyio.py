"""``.npy`` bytes in memory: the one writer the dataset, the service, the client and the tests
share. Never pickles (object arrays raise ``ValueError``) unless a test asks for it to build
hostile input."""

from __future__ import annotations

import io

import numpy as np


def npy_bytes(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    """The ``.npy`` file of ``array``, C-contiguous."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(array), allow_pickle=allow_pickle)
    return buffer.getvalue()
