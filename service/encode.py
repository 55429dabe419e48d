"""Answer bodies of ``POST /complete`` in its three formats.

Encoding happens in two steps so that the body can carry its own timings: ``encode`` turns
the arrays into bytes (the costly part, timed as the "encode" phase), ``finish`` adds the
summary (a few hundred bytes of JSON) and returns the body.

- json: ``CompletionResponse``, arrays as base64 of their ``.npy`` bytes (exact round trip);
- npz: a zip (stored, not deflated: speed over size) of ``depth.npy``, ``mask.npy``,
  ``points.npy`` and ``meta.json`` (the summary), read by ``numpy.load``;
- ply: the point cloud alone, binary little-endian, the summary's essentials as comments.
"""

from __future__ import annotations

import base64
import io
import zipfile
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from sdcnet.npyio import npy_bytes
from sdcnet.pointcloud import ply_bytes
from sdcnet.service.schemas import (
    CompletionResponse,
    CompletionSummary,
    EncodedArray,
    ResponseFormat,
)

_ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)
MEDIA_TYPES = {
    ResponseFormat.json: "application/json",
    ResponseFormat.npz: "application/octet-stream",
    ResponseFormat.ply: "application/octet-stream",
}


def encoded_array(array: np.ndarray) -> EncodedArray:
    return EncodedArray(
        dtype=str(array.dtype),
        shape=list(array.shape),
        npy_base64=base64.b64encode(npy_bytes(array)).decode("ascii"),
    )


class Encoded(Protocol):
    def finish(self, summary: CompletionSummary) -> bytes: ...


@dataclass
class _Json:
    arrays: dict[str, EncodedArray]

    def finish(self, summary: CompletionSummary) -> bytes:
        return CompletionResponse(**dict(summary), **self.arrays).model_dump_json().encode()


class _Npz:
    """The zip is written as the arrays stream into it (``numpy.lib.format.write_array``
    straight into each member): no ``.npy`` copy of a 4 MiB depth map is made first."""

    def __init__(self, arrays: dict[str, np.ndarray]):
        self.buffer = io.BytesIO()
        self.zip = zipfile.ZipFile(self.buffer, "w", zipfile.ZIP_STORED)
        for name, array in arrays.items():
            member = zipfile.ZipInfo(f"{name}.npy", _ZIP_EPOCH)
            with self.zip.open(member, "w", force_zip64=array.nbytes > 2**31) as out:
                np.lib.format.write_array(out, np.ascontiguousarray(array), allow_pickle=False)

    def finish(self, summary: CompletionSummary) -> bytes:
        self.zip.writestr(zipfile.ZipInfo("meta.json", _ZIP_EPOCH), summary.model_dump_json())
        self.zip.close()
        return self.buffer.getvalue()


@dataclass
class _Ply:
    points: np.ndarray

    def finish(self, summary: CompletionSummary) -> bytes:
        return ply_bytes(self.points, ply_comments(summary))


def ply_comments(summary: CompletionSummary) -> list[str]:
    """Header comments of a PLY answer: frame, units and provenance."""
    k = summary.intrinsics
    return [
        "sdcnet point cloud: camera frame (x right, y down, z forward), metres",
        f"model_version {summary.model_version}",
        f"provider {summary.provider}",
        f"image {summary.width} x {summary.height}, fx {k.fx:.3f} fy {k.fy:.3f} "
        f"cx {k.cx:.3f} cy {k.cy:.3f}",
        f"outliers_removed {summary.outliers_removed}",
    ]


def encode(fmt: ResponseFormat, depth: np.ndarray, mask: np.ndarray, points: np.ndarray) -> Encoded:
    """Serialise the arrays for ``fmt``: depth float32 (H, W) metres, mask uint8 (H, W),
    points float32 (N, 3) metres."""
    arrays = {"depth": depth, "mask": mask, "points": points}
    if fmt is ResponseFormat.json:
        return _Json({name: encoded_array(array) for name, array in arrays.items()})
    if fmt is ResponseFormat.npz:
        return _Npz(arrays)
    return _Ply(points)
