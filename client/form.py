"""What ``Client.pose`` sends: ``POST /pose``'s multipart form, encoded on the standard library
(the client has no HTTP library; ``sdcnet.client.transport`` writes the body as it is).

The gray image travels as an image file (the caller's own file bytes, or a PNG of an array)
and the LIDAR returns as a list, a ``.npy`` of (N, 3) float32 (row, column, Z metres): exact,
12 bytes a return, as ``Client.complete`` sends them on the v2 route.
"""

from __future__ import annotations

import numpy as np

from sdcnet.npyio import npy_bytes


def _boundary(parts: list[bytes]) -> bytes:
    """A boundary that occurs in no part (RFC 2046 forbids it), found without randomness."""
    n = 0
    while any(b"sdcnet-form-%d" % n in part for part in parts):
        n += 1
    return b"sdcnet-form-%d" % n


def form_body(
    files: dict[str, tuple[str, bytes]], fields: dict[str, str]
) -> tuple[bytes, dict[str, str]]:
    """(body, headers) of a ``multipart/form-data`` request: ``files`` as name -> (file name,
    bytes), ``fields`` as name -> text; names and file names are this module's own ASCII."""
    parts = [(f'name="{name}"', value.encode()) for name, value in fields.items()]
    parts += [(f'name="{name}"; filename="{file}"', data) for name, (file, data) in files.items()]
    boundary = _boundary([data for _, data in parts])
    body = b"".join(
        b"--%s\r\nContent-Disposition: form-data; %s\r\n\r\n%s\r\n"
        % (boundary, disposition.encode(), data)
        for disposition, data in parts
    )
    body += b"--%s--\r\n" % boundary
    return body, {"Content-Type": f"multipart/form-data; boundary={boundary.decode()}"}


def pose_form(
    gray: bytes, returns: np.ndarray, fields: dict[str, str]
) -> tuple[bytes, dict[str, str]]:
    """(body, headers) of one ``POST /pose``: the gray image file's bytes, the returns (N, 3)
    as a float32 ``.npy``, and the form's text ``fields`` (target, init, intrinsics...)."""
    files = {"gray": ("gray", gray), "returns": ("returns.npy", npy_bytes(returns.astype("<f4")))}
    return form_body(files, fields)
