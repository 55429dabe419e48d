"""``.npy`` bytes in memory: the one writer the dataset, the service, the client and the tests
share. Never pickles (object arrays raise ``ValueError``) unless a test asks for it to build
hostile input."""

from __future__ import annotations

import io

import numpy as np

#: The time stamp of every member of the npz archives sdcnet writes (the zip format's earliest),
#: so that the same arrays always give the same bytes.
ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)


def npy_bytes(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    """The ``.npy`` file of ``array``, C-contiguous."""
    buffer = io.BytesIO()
    np.lib.format.write_array(buffer, np.ascontiguousarray(array), allow_pickle=allow_pickle)
    return buffer.getvalue()
