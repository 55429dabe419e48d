"""On-disk dataset format, writer and torch-free reader.

A dataset directory holds:

- ``dataset.json``: how it was made (command, seed, counts, camera, LIDAR, scene ranges),
  the model list with each model's split, and the format version;
- ``manifest.jsonl``: one JSON line per sample (id, file, model, split, view, distance,
  sun angle, pose, intrinsics, number of LIDAR returns, foreground pixels), sorted by id;
- ``samples/<id>.npz``: one zip per sample, deflate-compressed (lossless), with
  ``gray.npy`` (H x W uint8, or uint16 for a 12- or 16-bit camera), ``depth.npy`` (H x W
  float32, camera-frame Z in metres, 0 = background), ``sparse.npy`` (H x W float32, LIDAR
  returns as Z in metres, 0 = none) and ``meta.json`` (the sample's manifest line). The
  foreground mask is ``depth > 0``.

Files are byte-for-byte reproducible: fixed zip timestamps, sorted keys, no wall-clock times.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sdcnet.npyio import ZIP_EPOCH, npy_bytes

FORMAT_VERSION = 1
ARRAYS = ("gray", "depth", "sparse")


def sample_id(model_id: int, view: int) -> str:
    return f"m{model_id:04d}_v{view:03d}"


@dataclass
class Sample:
    """One frame: inputs (gray, sparse) and ground truth (depth), with its metadata."""

    gray: np.ndarray
    sparse: np.ndarray
    depth: np.ndarray
    meta: dict

    @property
    def mask(self) -> np.ndarray:
        """Ground-truth foreground (bool H x W)."""
        return self.depth > 0


def write_sample(path: Path, sample: Sample) -> None:
    """Write atomically (temporary file, then rename) so an interrupted run leaves no half file."""
    tmp = path.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for name in ARRAYS:
            data = npy_bytes(getattr(sample, name))
            zf.writestr(zipfile.ZipInfo(f"{name}.npy", ZIP_EPOCH), data, zipfile.ZIP_DEFLATED)
        meta = json.dumps(sample.meta, sort_keys=True).encode()
        zf.writestr(zipfile.ZipInfo("meta.json", ZIP_EPOCH), meta, zipfile.ZIP_DEFLATED)
    os.replace(tmp, path)


def write_manifest(root: Path, metas: list[dict]) -> None:
    """``root/manifest.jsonl``: one line per sample's metadata, in the order given (by id)."""
    lines = [json.dumps(meta, sort_keys=True) for meta in metas]
    write_atomically(Path(root) / "manifest.jsonl", "\n".join(lines) + "\n")


def write_atomically(path: Path, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path``, then rename it: shards on other
    machines that share the folder (``deploy/dataset-job.yaml``) read the old file or the new
    one, never half of one."""
    with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp", delete=False) as f:
        f.write(text)
    os.replace(f.name, path)


def read_sample(path: Path) -> Sample:
    """Read one sample file; never unpickles."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {
            name: npz[f"{name}.npy"] if f"{name}.npy" in npz.files else npz[name] for name in ARRAYS
        }
        meta = json.loads(npz["meta.json"])
    return Sample(arrays["gray"], arrays["sparse"], arrays["depth"], meta)


def evenly_spread(records: list[dict], count: int) -> list[dict]:
    """At most ``count`` of ``records``, taken at an even step from the first: a fixed,
    representative subset (the order of a split mixes models and views)."""
    return records[:: max(1, len(records) // count)][:count]


def read_meta(path: Path) -> dict:
    """A sample's metadata alone, without decompressing its arrays."""
    with zipfile.ZipFile(path) as zf:
        return json.loads(zf.read("meta.json"))


def is_complete(path: Path) -> bool:
    """Whether a sample file exists and its zip directory is readable (for resuming)."""
    try:
        with zipfile.ZipFile(path) as zf:
            return {f"{n}.npy" for n in ARRAYS} | {"meta.json"} <= set(zf.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


class SampleStore:
    """Read access to a generated dataset directory (numpy only, no torch)."""

    def __init__(self, root: str | Path):
        self.root = Path(root)
        info = self.root / "dataset.json"
        if not info.is_file():
            raise FileNotFoundError(f"{self.root} is not an sdcnet dataset: no dataset.json")
        self.info = json.loads(info.read_text())
        manifest = self.root / "manifest.jsonl"
        if not manifest.is_file():
            raise FileNotFoundError(
                f"{manifest} is missing: generation did not finish (run it again to resume, "
                "or `sdc-data close` to use the samples rendered so far)"
            )
        self.records = [json.loads(line) for line in manifest.read_text().splitlines() if line]

    def __len__(self) -> int:
        return len(self.records)

    def split(self, name: str, limit: int | None = None) -> list[dict]:
        """Manifest records of one split ('train', 'val', 'test', or any custom split name);
        at most ``limit`` of them, evenly spread (``evenly_spread``), when given."""
        records = [r for r in self.records if r["split"] == name]
        return evenly_spread(records, limit) if limit else records

    def load(self, record: dict) -> Sample:
        return read_sample(self.root / record["file"])


def merge(out: str | Path, sources: list[str | Path], command: str) -> SampleStore:
    """A dataset ``out`` holding every sample of the datasets ``sources``, to train on their
    frames together (your own spacecraft beside ours, a world drawn apart beside another).
    Nothing is copied: ``out``'s manifest refers to the sources' sample files by paths
    relative to it, so the folders must stay where they are. Each record's id is its source
    folder's name and its own id (``mine/m0001_v000``), unique across the sources.
    ``dataset.json`` records ``command`` and each source's own description (``merged_from``)."""
    out = Path(out)
    if len(sources) < 2:
        raise ValueError("merge needs at least two datasets")
    names = [Path(s).resolve().name for s in sources]
    if len(set(names)) < len(names):
        raise ValueError(f"the datasets' folder names must differ: {names}")
    if out.exists() and any(out.iterdir()):
        raise ValueError(f"{out} exists and is not empty: merge into a new folder")
    stores = [SampleStore(s) for s in sources]
    for source, store in zip(sources, stores, strict=True):
        if store.info.get("format_version") != FORMAT_VERSION:
            raise ValueError(
                f"{source}: format version {store.info.get('format_version')}, not {FORMAT_VERSION}"
            )
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for name, store in zip(names, stores, strict=True):
        prefix = os.path.relpath(store.root.resolve(), out.resolve())
        records += [
            r | {"id": f"{name}/{r['id']}", "file": f"{prefix}/{r['file']}"} for r in store.records
        ]
    info = {
        "command": command,
        "format_version": FORMAT_VERSION,
        "world": "merged",
        "merged_from": [
            {"folder": str(Path(s)), "frames": len(store)}
            | {k: store.info.get(k) for k in ("command", "seed", "world")}
            for s, store in zip(sources, stores, strict=True)
        ],
    }
    write_atomically(out / "dataset.json", json.dumps(info, indent=1, sort_keys=True) + "\n")
    write_manifest(out, records)
    return SampleStore(out)
