"""Model card: how a checkpoint was made and what it scored, written from the records.

Everything factual comes from the checkpoint (training config, dataset command and seed,
history, hardware) and from ``sdc-train evaluate --out`` reports; free text comes from a notes
file, so the card can be regenerated whenever the model is.
"""

from __future__ import annotations

import json

from sdcnet.metrics import depth_table, markdown_table
from sdcnet.training.model.sdcnet import SDCNet


def lineage(state: dict) -> list[dict]:
    """The runs that made a checkpoint, oldest first: its ``parent`` chain (fine-tuning with
    ``--init-weights``), then itself; a run that started stage 2 from another checkpoint's
    FSNet (``--init-segmentation``) comes after that checkpoint's own runs."""
    runs = [state]
    while True:
        first = runs[0]
        parent = first.get("parent") or first.get("segmentation_parent")
        if parent is None:
            return runs
        runs.insert(0, parent)


def _run_line(run: dict) -> str:
    """One training run: command, hardware, epochs per stage and wall time."""
    history = run.get("history", [])
    minutes = sum(r.get("seconds", 0) for r in history) / 60
    epochs = [sum(1 for r in history if r["stage"] == s) for s in (1, 2)]
    return (
        f"`{run.get('train_config', {}).get('command', '?')}` on {run.get('hardware', '?')}: "
        f"{epochs[0]} FSNet and {epochs[1]} FDCNet epochs up to the kept checkpoint, "
        f"{minutes:.0f} min of training and validation"
    )


def _recipe(configs: list[dict]) -> str:
    keys = (
        "variant",
        "fsnet_inputs",
        "fsnet_epochs",
        "epochs",
        "batch_size",
        "tile",
        "lr",
        "weight_decay",
        "gradient_loss",
        "iou_loss",
        "samples_per_epoch",
        "train_samples",
        "val_samples",
        "seed",
    )
    header = "| recipe | " + " | ".join(f"run {i + 1}" for i in range(len(configs))) + " |"
    rule = "|---|" + "---|" * len(configs)
    rows = [f"| {k} | " + " | ".join(str(c.get(k)) for c in configs) + " |" for k in keys]
    return "\n".join([header, rule, *rows])


def model_card(
    state: dict, model: SDCNet, reports: list[dict], version: str, notes: str = ""
) -> str:
    """Markdown model card of a trained checkpoint and its evaluation reports."""
    data, runs = state.get("dataset", {}), lineage(state)
    minutes = sum(r.get("seconds", 0) for run in runs for r in run.get("history", [])) / 60
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
        f"- Training: {len(runs)} run(s), each starting from the weights the one before kept "
        f"(`--init-weights`, or its FSNet with `--init-segmentation`), {minutes:.0f} min in all:",
        *(f"  {i + 1}. {_run_line(run)}." for i, run in enumerate(runs)),
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
                "interior of true ∩ predicted foreground; false specks per image:",
                "",
                depth_table(report["results"]),
                "",
            ]
        undefined = {k: v for k, v in report.get("undefined", {}).items() if any(v.values())}
        if undefined:
            lines += [f"Images left out of a mean for an empty set: {json.dumps(undefined)}", ""]
    if notes:
        lines += [notes.strip(), ""]
    return "\n".join(lines)
