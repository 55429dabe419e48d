"""``sdc-eval evaluate``: methods on one split of a dataset, mean over images; the tables are
printed and, with ``out``, written as the JSON report the model card and ``sdc-export
--metrics`` read."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.scoring import Method, evaluate_records, mask_metrics_only
from sdcnet.metrics import depth_table, markdown_table


def evaluate_split(
    methods: dict[str, Method],
    data: str,
    split: str = "test",
    limit: int | None = None,
    segmentation_only: bool = False,
    out: str | None = None,
    append: bool = False,
    title: str | None = None,
) -> None:
    """Score ``methods`` on ``limit`` frames (evenly spread; None: all) of ``split`` of the
    dataset at ``data``, print the tables and write the report to ``out``; ``append`` adds
    the rows to the report already there (same frames, else a ``ValueError``).
    ``segmentation_only``: only the mask metrics mean anything."""
    store = SampleStore(data)
    records = store.split(split, limit)
    if not records:
        raise ValueError(f"split {split!r} is empty in {data}")
    results, counts, undefined = {}, {}, {}
    for name, method in methods.items():
        table = evaluate_records(method, store, records, desc=name, mask_only=segmentation_only)
        results[name], counts[name], undefined[name] = table.mean(), len(table), table.undefined()
        if segmentation_only:
            results[name] = mask_metrics_only(results[name])
    text = markdown_table(results, counts) + "\n\n" + depth_table(results)
    print(f"{split} split of {data}: {len(records)} images, mean over images\n")
    print(text)
    for name, u in undefined.items():
        if any(u.values()):
            print(f"{name}: images left out for empty sets: {u}")
    if out:
        report = {
            "title": title or f"{split} split of {data}",
            "split": split,
            "images": len(records),
            "frames_sha256": frames_digest(records),
            "results": results,
            "undefined": undefined,
        }
        if append:
            report = appended(Path(out), report)
        Path(out).write_text(json.dumps(report, indent=1))


def frames_digest(records: list[dict]) -> str:
    """Names the exact frames a report was made on, so that rows are only ever merged with rows
    of the same frames."""
    return hashlib.sha256("\n".join(r["id"] for r in records).encode()).hexdigest()[:16]


def appended(path: Path, report: dict) -> dict:
    """``report``'s rows added to those of the report at ``path`` (same frames, else an error),
    all rows sorted by name: label them "(a) ...", "(b) ..." to fix their order."""
    if not path.exists():
        return report
    old = json.loads(path.read_text())
    if old.get("frames_sha256") != report["frames_sha256"]:
        raise ValueError(f"{path} was made on other frames: cannot append rows to it")
    merged = {**report}
    for key in ("results", "undefined"):
        rows = {**old[key], **report[key]}
        merged[key] = {name: rows[name] for name in sorted(rows)}
    return merged
