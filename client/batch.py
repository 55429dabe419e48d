"""Many frames through the service: finding the pairs, and running them concurrently.

A batch input is one of:

- a folder of pairs: each gray image ``NAME.png`` (or .tif, .tiff, .jpg, .jpeg, .bmp) with
  its LIDAR returns: ``NAME`` and the ending of one of their formats
  (``sdcnet.formats.sparse.ENDINGS``, the first found in that order: ``NAME.npy``,
  ``NAME.sparse.png`` with a depth scale, ``NAME.csv``...);
- a JSON-lines manifest, one pair per line: ``{"gray": PATH, "sparse": PATH}`` with optional
  ``"id"``, ``"depth_scale"``, ``"fx"``, ``"fy"``, ``"cx"``, ``"cy"``; paths are relative to
  the manifest's folder;
- an sdcnet dataset (``sdc-data generate``): its folder or its ``manifest.jsonl``, read with
  ``sdcnet.dataset_format.SampleStore``; ``split`` selects train / val / test.

Every pair gets its own output folder ``OUT/<id>/`` with the files of ``sdc-client infer``. A
pair that fails is reported and the others go on.
"""

from __future__ import annotations

import json
import time
import zipfile
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from sdcnet.camera import GivenIntrinsics
from sdcnet.client.api import (
    Client,
    ClientError,
    Completion,
    InputError,
    Source,
    gray_array,
    read_file,
)
from sdcnet.client.outputs import write_outputs
from sdcnet.dataset_format import SampleStore, read_sample
from sdcnet.formats.sparse import ENDINGS, FORMATS

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp")
#: Suffixes of the files of returns that hold units, for which a default depth scale is meant.
SCALED_SUFFIXES = {Path(e).suffix for f in FORMATS if f.scaled for e in f.endings}


@dataclass(frozen=True)
class Pair:
    """One frame to complete, with the depth scale (metres per unit of a 16-bit PNG map) and
    the intrinsics (pixels) of its manifest line. A dataset sample has ``gray == sparse ==``
    its ``.npz``."""

    name: str
    gray: Path
    sparse: Path
    depth_scale: float | None = None
    intrinsics: GivenIntrinsics = field(default_factory=GivenIntrinsics)

    def options(self, defaults: dict[str, Any]) -> dict[str, Any]:
        """``Client.complete``'s and ``Client.pose``'s keyword arguments for this pair: the
        ``defaults`` (the command line's ``depth_scale``, ``intrinsics``, ``max_sigma``) with
        the pair's own values in their place, value by value; a default depth scale only for
        a PNG map (the others hold metres)."""
        options = dict(defaults)
        if self.sparse.suffix.lower() not in SCALED_SUFFIXES:
            options.pop("depth_scale", None)
        if self.depth_scale is not None:
            options["depth_scale"] = self.depth_scale
        options["intrinsics"] = self.intrinsics.over(options.get("intrinsics") or GivenIntrinsics())
        return options

    def sources(self) -> tuple[Source, Source]:
        """What ``Client.complete`` takes: file bytes, or the arrays of a dataset sample."""
        if self.gray == self.sparse and self.gray.suffix == ".npz":
            try:
                sample = read_sample(self.gray)
            except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
                raise InputError(f"cannot read dataset sample {self.gray}: {exc}") from exc
            return sample.gray, sample.sparse
        return read_file(self.gray, "gray image"), read_file(self.sparse, "sparse depth")


def _folder_pairs(folder: Path) -> list[Pair]:
    pairs = []
    for path in sorted(folder.iterdir()):
        name = path.name
        if path.suffix.lower() not in IMAGE_SUFFIXES or name.endswith(ENDINGS):
            continue
        stem = path.with_suffix("")
        candidates = [Path(f"{stem}{ending}") for ending in ENDINGS]
        found = [candidate for candidate in candidates if candidate.exists()]
        pairs.append(Pair(stem.name, path, (found or candidates)[0]))
    return pairs


def _manifest_pairs(manifest: Path, split: str | None) -> list[Pair]:
    root = manifest.parent
    pairs = []
    for number, line in enumerate(read_file(manifest, "manifest").decode().splitlines(), 1):
        if not line.strip():
            continue
        try:
            record: dict[str, Any] = json.loads(line)
            if split is not None and record.get("split") != split:
                continue
            gray, sparse = root / record["gray"], root / record["sparse"]
            scale = None if record.get("depth_scale") is None else float(record["depth_scale"])
            intrinsics = GivenIntrinsics.from_dict(record)
        except (ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{manifest} line {number}: not a pair ({exc})") from exc
        name = str(record.get("id") or Path(gray).stem).replace("/", "_")
        pairs.append(Pair(name, gray, sparse, scale, intrinsics))
    return pairs


def _dataset_pairs(root: Path, split: str | None) -> list[Pair]:
    try:
        store = SampleStore(root)
    except (OSError, ValueError) as exc:
        raise InputError(f"cannot read the dataset {root}: {exc}") from exc
    records = store.records if split is None else store.split(split)
    return [Pair(r["id"], root / r["file"], root / r["file"]) for r in records]


def find_pairs(source: Path, split: str | None = None) -> list[Pair]:
    """The pairs of a folder, a JSON-lines manifest or a dataset (see the module doc)."""
    dataset = source if source.is_dir() else source.parent
    if (dataset / "dataset.json").is_file() and source in (dataset, dataset / "manifest.jsonl"):
        return _dataset_pairs(dataset, split)
    if source.is_dir():
        manifest = source / "manifest.jsonl"
        return _manifest_pairs(manifest, split) if manifest.is_file() else _folder_pairs(source)
    if source.is_file():
        return _manifest_pairs(source, split)
    raise InputError(f"batch input not found: {source}")


@dataclass
class BatchReport:
    done: list[tuple[Pair, Completion]] = field(default_factory=list)
    failed: list[tuple[Pair, str]] = field(default_factory=list)
    seconds: float = 0.0

    def summary(self) -> str:
        total = len(self.done) + len(self.failed)
        lines = [
            f"{len(self.done)} of {total} pairs completed, {len(self.failed)} failed, "
            f"in {self.seconds:.1f} s ({len(self.done) / max(self.seconds, 1e-9):.2f} frames/s)"
        ]
        if self.done:
            latency = np.array([c.latency_s for _, c in self.done]) * 1e3
            inference = [c.timings_ms.get("inference_ms", 0.0) for _, c in self.done]
            lines.append(
                f"latency median {np.median(latency):.1f} ms, max {latency.max():.1f} ms; "
                f"server inference median {np.median(inference):.1f} ms"
            )
        lines += [f"FAILED {pair.name}: {message}" for pair, message in self.failed]
        return "\n".join(lines)


def run_batch(
    client: Client,
    pairs: list[Pair],
    out: Path,
    concurrency: int = 2,
    outlier_removal: bool = False,
    defaults: dict[str, Any] | None = None,
    progress: bool = True,
    float16_depth: bool = False,
) -> BatchReport:
    """Complete every pair, at most ``concurrency`` requests at once, writing ``out/<name>/``.
    ``defaults`` (depth_scale, intrinsics, max_sigma) apply where a pair does not set its own
    (``Pair.options``)."""
    report = BatchReport()

    def one(pair: Pair) -> Completion:
        gray, sparse = pair.sources()
        options = pair.options(defaults or {})
        image = gray_array(gray)
        result = client.complete(
            image, sparse, outlier_removal=outlier_removal, float16_depth=float16_depth, **options
        )
        write_outputs(out / pair.name, image, result)
        return result

    start = time.perf_counter()
    with ThreadPoolExecutor(max_workers=max(concurrency, 1)) as pool:
        futures = {pool.submit(one, pair): pair for pair in pairs}
        bar = tqdm(as_completed(futures), total=len(futures), unit="frame", disable=not progress)
        for future in bar:
            pair = futures[future]
            try:
                report.done.append((pair, future.result()))
            except ClientError as exc:
                report.failed.append((pair, str(exc)))
            except Exception as exc:  # a bad pair must not stop the batch, whatever went wrong
                report.failed.append((pair, f"{type(exc).__name__}: {exc}"))
            if report.failed:
                bar.set_postfix(failed=len(report.failed))
    report.seconds = time.perf_counter() - start
    return report
