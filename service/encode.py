"""Answer bodies of ``POST /complete`` in its three formats, written into a ``Spool``.

Encoding happens in two steps so that the body can carry its own timings: ``encode`` writes
the arrays (the costly part, timed as the "encode" phase), ``finish`` adds the summary (a few
hundred bytes) and closes the body. Nothing is built whole in memory: arrays go out from their
own buffers a slice at a time, so an answer costs the memory of its arrays and of one slice
(``SLICE_BYTES``), whatever its size; the spool keeps 2 MiB in memory and the rest on disk.

- json: ``CompletionResponse``, arrays as base64 of their ``.npy`` bytes (exact round trip);
  the arrays (depth, mask, points, normals, sigma) come first, then the summary's fields;
- npz: a zip (stored, not deflated: speed over size) of ``depth.npy``, ``mask.npy``,
  ``points.npy``, ``normals.npy``, ``sigma.npy`` and ``meta.json`` (the summary), read by
  ``numpy.load``;
- ply: the point cloud alone, binary little-endian, each vertex x, y, z (metres), its unit
  normal nx, ny, nz and its sigma (metres), all float32, the summary's essentials as comments.
"""

from __future__ import annotations

import base64
import io
import json
import zipfile
from collections.abc import Iterator
from typing import TYPE_CHECKING, Protocol

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.caveats import as_text
from sdcnet.npyio import ZIP_EPOCH
from sdcnet.pointcloud import ply_header, ply_vertices
from sdcnet.service.schemas import CompletionSummary, FrameSummary, ResponseFormat
from sdcnet.service.spool import Spool

if TYPE_CHECKING:
    from sdcnet.service.inference import Completed

#: Bytes of an array encoded at a time (a multiple of 3, so that base64 slices join).
SLICE_BYTES = 3 * 2**18
MEDIA_TYPES = {
    ResponseFormat.json: "application/json",
    ResponseFormat.npz: "application/octet-stream",
    ResponseFormat.ply: "application/octet-stream",
}


def npy_header(array: np.ndarray) -> bytes:
    """The ``.npy`` header (format 1.0) of a C-contiguous ``array``: its file is this, then
    the array's bytes."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, np.lib.format.header_data_from_array_1_0(array))
    return header.getvalue()


def array_slices(array: np.ndarray, size: int = SLICE_BYTES) -> Iterator[memoryview]:
    """The bytes of a C-contiguous ``array``, ``size`` at a time, without a copy."""
    flat = memoryview(array).cast("B") if array.size else memoryview(b"")
    for start in range(0, len(flat), size):
        yield flat[start : start + size]


def write_base64(spool: Spool, pieces: Iterator[bytes | memoryview]) -> None:
    """Base64 of the concatenated ``pieces`` into ``spool``, a slice at a time."""
    carry = b""
    for piece in pieces:
        if carry:
            need = 3 - len(carry)
            carry += bytes(piece[:need])
            piece = piece[need:]
            if len(carry) < 3:
                continue
            spool.write(base64.b64encode(carry))
        whole = len(piece) - len(piece) % 3
        for start in range(0, whole, SLICE_BYTES):
            spool.write(base64.b64encode(piece[start : min(start + SLICE_BYTES, whole)]))
        carry = bytes(piece[whole:])
    spool.write(base64.b64encode(carry))


class Encoded(Protocol):
    def finish(self, summary: CompletionSummary) -> None: ...


class _Json:
    def __init__(self, arrays: dict[str, np.ndarray], spool: Spool):
        self.spool = spool
        for k, (name, array) in enumerate(arrays.items()):
            array = np.ascontiguousarray(array)
            head = {"dtype": str(array.dtype), "shape": list(array.shape)}
            opening = "{" if k == 0 else ", "
            spool.write(f'{opening}"{name}": {json.dumps(head)[:-1]}, "npy_base64": "'.encode())
            write_base64(spool, iter([npy_header(array), *array_slices(array)]))
            spool.write(b'"}')

    def finish(self, summary: CompletionSummary) -> None:
        self.spool.write(b", " + summary.model_dump_json().encode()[1:])


class _Npz:
    """The zip is written as the arrays stream into it (``numpy.lib.format.write_array``
    straight into each member, 16 MiB at a time)."""

    def __init__(self, arrays: dict[str, np.ndarray], spool: Spool):
        self.zip = zipfile.ZipFile(spool.file, "w", zipfile.ZIP_STORED)
        for name, array in arrays.items():
            member = zipfile.ZipInfo(f"{name}.npy", ZIP_EPOCH)
            with self.zip.open(member, "w", force_zip64=array.nbytes > 2**31) as out:
                np.lib.format.write_array(out, np.ascontiguousarray(array), allow_pickle=False)

    def finish(self, summary: CompletionSummary) -> None:
        self.zip.writestr(zipfile.ZipInfo("meta.json", ZIP_EPOCH), summary.model_dump_json())
        self.zip.close()


#: The per-vertex properties of a PLY answer after x, y, z (float32): the unit normal (the
#: names Open3D, PCL and MeshLab read as normals) and the depth's sigma (metres).
PLY_PROPERTIES = ("nx", "ny", "nz", "sigma")


class _Ply:
    """The vertices are interleaved (x, y, z, nx, ny, nz, sigma) a slice of ``SLICE_BYTES`` at
    a time."""

    def __init__(
        self,
        points: np.ndarray,
        normals: np.ndarray,
        sigma: np.ndarray,
        comments: list[str],
        spool: Spool,
    ):
        spool.write(ply_header(len(points), comments, PLY_PROPERTIES))
        step = max(1, SLICE_BYTES // (4 * (3 + len(PLY_PROPERTIES))))
        for start in range(0, len(points), step):
            part = slice(start, start + step)
            rows = ply_vertices(points[part], (*normals[part].T, sigma[part]))
            spool.write(memoryview(rows).cast("B"))

    def finish(self, summary: CompletionSummary) -> None:
        pass  # the header said all there is to say


def ply_comments(frame: FrameSummary, K: Intrinsics) -> list[str]:
    """Header comments of a PLY answer: frame, units and provenance (``K``: the intrinsics
    the points were back-projected with)."""
    return [
        "sdcnet point cloud: camera frame (x right, y down, z forward), metres",
        "nx, ny, nz: the unit surface normal, facing the camera",
        "sigma: the depth's 1-sigma uncertainty, metres",
        f"model_version {frame.model_version}",
        f"provider {frame.provider}",
        f"image {K.width} x {K.height}, {K.describe()}",
        f"outliers_removed {frame.outliers_removed}",
        f"uncertain_removed {frame.uncertain_removed}",
        f"cloud_stride {frame.cloud_stride}",
        f"mask_iou_estimate {frame.mask_iou_estimate:.4f}",
        f"caveats {as_text(frame.caveats) or 'none'}",
    ]


def encode(fmt: ResponseFormat, done: Completed, frame: FrameSummary, spool: Spool) -> Encoded:
    """Write the arrays of a completed frame for ``fmt`` into ``spool``: depth float32 (H, W)
    metres, mask uint8 (H, W), points float32 (N, 3) metres, their unit normals float32 (N, 3),
    sigma float32 (H, W) metres (PLY: each point's); ``frame``: the summary without timings
    (the PLY header's)."""
    if fmt is ResponseFormat.ply:
        comments = ply_comments(frame, done.intrinsics)
        return _Ply(done.points, done.normals, done.point_sigma, comments, spool)
    arrays = {
        "depth": done.depth,
        "mask": done.mask.view(np.uint8),
        "points": done.points,
        "normals": done.normals,
        "sigma": done.sigma,
    }
    if fmt is ResponseFormat.json:
        return _Json(arrays, spool)
    return _Npz(arrays, spool)
