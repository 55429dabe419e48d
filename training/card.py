"""Model card: how a checkpoint was made and what it scored, written from the records.

Everything factual comes from the checkpoint (training config, dataset command and seed,
history, hardware) and from ``sdc-train evaluate --out`` reports; free text comes from a notes
file, so the card can be regenerated whenever the model is.
"""

from __future__ import annotations

import json

from sdcnet.metrics import markdown_table
from sdcnet.training.model.sdcnet import SDCNet


def _recipe(config: dict) -> str:
    keys = (
        "variant",
        "fsnet_inputs",
        "fsnet_epochs",
        "epochs",
        "batch_size",
        "tile",
        "lr",
        "weight_decay",
        "samples_per_epoch",
        "val_samples",
        "seed",
    )
    return "\n".join(f"| {k} | {config.get(k)} |" for k in keys)


def model_card(
    state: dict, model: SDCNet, reports: list[dict], version: str, notes: str = ""
) -> str:
    """Markdown model card of a trained checkpoint and its evaluation reports."""
    config, data, history = (
        state.get("train_config", {}),
        state.get("dataset", {}),
        state.get("history", []),
    )
    seconds = sum(r.get("seconds", 0) for r in history)
    stage_epochs = {s: sum(1 for r in history if r["stage"] == s) for s in (1, 2)}
    params = sum(p.numel() for p in model.parameters())
    fs = sum(p.numel() for p in model.fsnet.parameters()) if model.fsnet is not None else 0
    lines = [
        f"# Model card: {version}",
        "",
        "SDCNet (pre-fill + FSNet + FDCNet) for spacecraft depth completion from a",
        "1024 x 1024 gray image (f = 50 mm, 6.449 mm sensor) and a co-located LIDAR",
        "(0.09 x 0.13 deg beams) at 50-250 m.",
        "",
        "- Inputs: `gray` float32 (B, 1, H, W) in [0, 1]; `sparse` float32 (B, 1, H, W), LIDAR",
        "  camera-frame Z in metres, 0 = no return. Outputs: `depth` (metres), `foreground`",
        "  (probability). The service crops to the LIDAR-bounded region first (`sdcnet.pipeline`).",
        f"- Architecture: {json.dumps(model.config.to_dict())}; {params:,} parameters "
        f"({fs:,} in FSNet).",
        "",
        "## Training",
        "",
        f"- Data: `{data.get('command', '?')}` (seed {data.get('seed')}; "
        f"{data.get('models')} models x {data.get('views')} views; models per split "
        f"{data.get('split_models')}). Test models are never seen in training.",
        f"- Command: `{config.get('command', '?')}`",
        f"- Hardware: {state.get('hardware', '?')}; {seconds / 60:.0f} min of training and "
        f"validation up to this checkpoint ({stage_epochs[1]} FSNet epochs, then the best of "
        f"{config.get('epochs', '?')} FDCNet epochs: epoch {stage_epochs[2]}).",
        "- Optimiser: Adam, cosine decay per stage; stage 1 BCE on the foreground (eq. 6), stage 2",
        "  L1 on predicted ∩ true foreground (eq. 7) with FSNet frozen. Best epoch by val MATE.",
        "",
        "| recipe | value |",
        "|---|---|",
        _recipe(config),
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
        undefined = {k: v for k, v in report.get("undefined", {}).items() if any(v.values())}
        if undefined:
            lines += [f"Images left out of a mean for an empty set: {json.dumps(undefined)}", ""]
    if notes:
        lines += [notes.strip(), ""]
    return "\n".join(lines)
