"""Model card: how a checkpoint was made and what it scored, written from the records.

Everything factual comes from the checkpoint (training config, dataset command and seed,
history, hardware) and from ``sdc-eval evaluate --out`` reports; free text comes from a notes
file, so the card can be regenerated whenever the model is.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sdcnet.evaluation.robustness import table_of
from sdcnet.metrics import depth_table, markdown_table, uncertainty_table
from sdcnet.training.checkpoint import load_checkpoint, provenance_key
from sdcnet.training.model.sdcnet import SDCNet


def _parent(run: dict) -> dict | None:
    """The checkpoint a run started from (``--init-weights``, ``--init-segmentation`` or
    ``--warm-start``), or None."""
    return run.get("parent") or run.get("segmentation_parent") or run.get("warm_start_parent")


def lineage(state: dict) -> list[dict]:
    """The runs that made a checkpoint, oldest first: its ``parent`` chain (fine-tuning with
    ``--init-weights``, ``--init-segmentation`` or ``--warm-start``), then itself; for an
    average (``sdc-train average``) each member's runs, those they share once."""
    if "averaged" in state:
        runs: dict[str, dict] = {}
        for member in state["averaged"]:
            for run in lineage(member):
                runs.setdefault(provenance_key(run), run)
        return list(runs.values())
    parent = _parent(state)
    return [*(lineage(parent) if parent is not None else []), state]


def _run_line(run: dict, number: dict[str, int]) -> str:
    """One training run: command, hardware, the run it started from, epochs per stage and wall
    time. ``number``: each run's number in the card by ``provenance_key``."""
    history = run.get("history", [])
    minutes = sum(r.get("seconds", 0) for r in history) / 60
    epochs = [sum(1 for r in history if r["stage"] == s) for s in (1, 2)]
    parent = _parent(run)
    start = f", from {_weights_of(parent, number)}'s weights" if parent is not None else ""
    return (
        f"`{run.get('train_config', {}).get('command', '?')}` on {run.get('hardware', '?')}"
        f"{start}: {epochs[0]} FSNet and {epochs[1]} FDCNet epochs up to the kept checkpoint, "
        f"{minutes:.0f} min of training and validation"
    )


def _weights_of(state: dict, number: dict[str, int]) -> str:
    """Whose weights a checkpoint holds, by the card's run numbers (``number``, by
    ``provenance_key``): ``run 3``, for an average ``the mean of runs 3, 4, 5``, and for an
    average of averages ``the mean of (the mean of runs 3, 4, 5) and run 6``."""
    if "averaged" not in state:
        return f"run {number[provenance_key(state)]}"
    members = state["averaged"]
    if not any("averaged" in m for m in members):
        return "the mean of runs " + ", ".join(str(number[provenance_key(m)]) for m in members)
    named = [
        f"({_weights_of(m, number)})" if "averaged" in m else _weights_of(m, number)
        for m in members
    ]
    return "the mean of " + ", ".join(named[:-1]) + " and " + named[-1]


def _average_line(state: dict, number: dict[str, int]) -> list[str]:
    """The line that says which runs' weights an average's are the mean of (none otherwise)."""
    if "averaged" not in state:
        return []
    return [
        f"- The weights are {_weights_of(state, number)}'s (`sdc-train average`, a model soup: "
        "checkpoints fine-tuned from one model, averaged)."
    ]


def _recipe(configs: list[dict]) -> str:
    keys = (
        "variant",
        "fsnet_inputs",
        "fsnet_growth",
        "fsnet_context",
        "fsnet_epochs",
        "epochs",
        "batch_size",
        "tile",
        "lr",
        "weight_decay",
        "gradient_loss",
        "iou_loss",
        "iou_over",
        "sigma_loss",
        "samples_per_epoch",
        "train_samples",
        "val_samples",
        "seed",
        "warm_start",
    )
    header = "| recipe | " + " | ".join(f"run {i + 1}" for i in range(len(configs))) + " |"
    rule = "|---|" + "---|" * len(configs)
    rows = [f"| {k} | " + " | ".join(str(c.get(k)) for c in configs) + " |" for k in keys]
    return "\n".join([header, rule, *rows])


def _data_lines(runs: list[dict]) -> list[str]:
    """The datasets the runs trained on, each once, in the order first used."""
    seen: dict[str, dict] = {}
    for run in runs:
        data = run.get("dataset", {})
        seen.setdefault(data.get("command", "?"), data)
    return [
        f"- Data: `{command}` ({_made_of(data)}"
        + (f"; frames used {data['frames']}" if "frames" in data else "")
        + "). Test models are never seen in training."
        for command, data in seen.items()
    ]


def _made_of(data: dict) -> str:
    """What a dataset was rendered with, or for one of several (``sdc-data merge``) each
    source's command and frames."""
    if data.get("merged_from"):
        return "of " + ", ".join(
            f"`{source['command']}` ({source['frames']} frames)" for source in data["merged_from"]
        )
    return (
        f"seed {data.get('seed')}; {data.get('models')} models x {data.get('views')} views; "
        f"models per split {data.get('split_models')}"
    )


def model_card(
    state: dict,
    model: SDCNet,
    reports: list[dict],
    version: str,
    notes: str = "",
    robustness: dict | None = None,
) -> str:
    """Markdown model card of a trained checkpoint and its evaluation reports."""
    runs = lineage(state)
    number = {provenance_key(run): i + 1 for i, run in enumerate(runs)}
    data = runs[-1].get("dataset", {})
    minutes = sum(r.get("seconds", 0) for run in runs for r in run.get("history", [])) / 60
    params = sum(p.numel() for p in model.parameters())
    fs = sum(p.numel() for p in model.fsnet.parameters()) if model.fsnet is not None else 0
    lines = [
        f"# Model card: {version}",
        "",
        "SDCNet (pre-fills + FSNet + FDCNet) for spacecraft depth completion from a gray image",
        "and the LIDAR returns of any camera and LIDAR at any range, trained on the world",
        f"`{data.get('world', 'paper')}` (`docs/dataset.md`).",
        "",
        "- Inputs: `gray` float32 (B, 1, H, W) in [0, 1]; `sparse` float32 (B, 1, H, W), LIDAR",
        "  camera-frame Z in metres, 0 = no return; `focal_px` float32 (B, 1, 1, 1), the focal",
        "  length in the inputs' pixels. Outputs: `depth` (metres), `foreground` (probability),",
        "  `sigma` (the depth's uncertainty, metres). The pipeline (`sdcnet.pipeline`) crops to",
        "  the LIDAR-bounded region and resamples it to the model's fixed working-pixel budget.",
        f"- Architecture: {json.dumps(model.config.to_dict())}; {params:,} parameters "
        f"({fs:,} in FSNet).",
        "",
        "## Training",
        "",
        *_data_lines(runs),
        f"- Training: {len(runs)} run(s), a fine-tuning run starting from another's kept "
        f"weights (`--init-weights`, its FSNet with `--init-segmentation`, or every weight "
        f"that fits a new design with `--warm-start`), {minutes:.0f} min in all:",
        *(f"  {i + 1}. {_run_line(run, number)}." for i, run in enumerate(runs)),
        *_average_line(state, number),
        "- Optimiser: Adam, cosine decay per stage; stage 1 BCE on the foreground (eq. 6), stage 2",
        "  L1 on predicted ∩ true foreground (eq. 7) with FSNet frozen. Kept: the best epoch by",
        "  val IOU (stage 1) or val MATE (stage 2).",
        "",
        _recipe([run.get("train_config", {}) for run in runs]),
        "",
    ]
    for report in reports:
        lines += [
            f"## {report.get('title', 'Results')}",
            "",
            f"{report['split']} split, {report['images']} images, mean over images "
            "(IOU, IOI in %; errors in metres; α = 10 m).",
            "",
            markdown_table(report["results"]),
            "",
        ]
        if any("MAE" in m for m in report["results"].values()):
            lines += [
                "Depth on the pixels each method shares with the classical fill (the fill's own "
                "error in brackets), by distance to the nearest LIDAR return; normals on the "
                "interior of true ∩ predicted foreground (of a model run through the pipeline, "
                "the normals it answers, `sdcnet.normals`; of stored answers and the fill, "
                "their depth maps'); false specks per image:",
                "",
                depth_table(report["results"]),
                "",
            ]
        if any(not np.isnan(m.get("sigma_within_1", np.nan)) for m in report["results"].values()):
            lines += [
                "The depth's uncertainty on predicted ∩ true foreground (`sigma`):",
                "",
                uncertainty_table(report["results"]),
                "",
            ]
        undefined = {
            k: {name: n for name, n in v.items() if n and not name.startswith("sigma_")}
            for k, v in report.get("undefined", {}).items()
        }
        undefined = {k: v for k, v in undefined.items() if v}
        if undefined:
            lines += [f"Images left out of a mean for an empty set: {json.dumps(undefined)}", ""]
    if robustness:
        lines += [
            "## Robustness suite: every condition, model against the classical fill",
            "",
            "`sdc-eval robustness`: frames of spacecraft never trained on (the test split's "
            "models and the real meshes) per condition (`docs/dataset.md`); IOU with the "
            "fill's in brackets, depth MAE on the pixels shared with the fill (the fill's in "
            "brackets) overall and by distance to the nearest return, mean normal error (of a "
            "model run through the pipeline, the normals it answers; of stored answers and the "
            "fill, their depth maps'), false specks per frame, in-process milliseconds per "
            "frame on 2 threads.",
            "",
            table_of(robustness),
            "",
        ]
    if notes:
        lines += [notes.strip(), ""]
    return "\n".join(lines)


def write_card(
    checkpoint: str,
    out: str,
    reports: Sequence[str] = (),
    onnx: str | None = None,
    notes: str | None = None,
    robustness: str | None = None,
) -> None:
    """``model_card`` of ``checkpoint`` written to ``out``, from the JSON ``reports`` of
    ``sdc-eval evaluate --out`` (and ``real``), the ``robustness.json`` of ``sdc-eval
    robustness`` and a markdown ``notes`` file. The version is the exported ``onnx`` model's,
    else the checkpoint's file name."""
    model, state = load_checkpoint(checkpoint)
    loaded = [json.loads(Path(r).read_text()) for r in reports]
    version = Path(checkpoint).stem
    if onnx:
        import onnx as onnx_format

        meta = {p.key: p.value for p in onnx_format.load(onnx).metadata_props}
        version = meta.get("model_version", version)
    text = Path(notes).read_text() if notes else ""
    suite = json.loads(Path(robustness).read_text()) if robustness else None
    Path(out).write_text(model_card(state, model, loaded, version, text, suite))
