"""``sdc-train``: fit SDCNet (or an ablation variant) and evaluate it on a split."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import fields
from pathlib import Path

from sdcnet.metrics import markdown_table
from sdcnet.training.card import model_card
from sdcnet.training.checkpoint import load_checkpoint
from sdcnet.training.data.format import SampleStore
from sdcnet.training.evaluate import ClassicalFill, evaluate_records, torch_model_fn
from sdcnet.training.model.sdcnet import VARIANTS
from sdcnet.training.train import PRESETS, TrainConfig, Trainer, config_from_preset


def cmd_fit(args: argparse.Namespace) -> int:
    overrides = json.loads(Path(args.config).read_text()) if args.config else {}
    for f in fields(TrainConfig):
        value = getattr(args, f.name, None)
        if value is not None and f.name != "command":
            overrides[f.name] = value
    config = config_from_preset(args.preset, **overrides)
    best = Trainer(config).fit(resume=not args.restart)
    print(f"best checkpoint: {best}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    store = SampleStore(args.data)
    records = store.split(args.split)
    if not records:
        raise ValueError(f"split {args.split!r} is empty in {args.data}")
    if args.limit:
        records = records[:: max(1, len(records) // args.limit)][: args.limit]
    methods = {}
    for path in args.checkpoint:
        model, state = load_checkpoint(path)
        name = state.get("train_config", {}).get("variant", Path(path).stem)
        methods[name] = (torch_model_fn(model), model.config.stride)
    if args.onnx:
        from sdcnet.export.runtime import OnnxModel

        onnx_model = OnnxModel(args.onnx)
        methods[f"onnx:{Path(args.onnx).name}"] = (onnx_model.run, onnx_model.stride)
    if args.floor:
        methods["classical fill"] = (torch_model_fn(ClassicalFill()), 64)
    results, counts, undefined = {}, {}, {}
    for name, (fn, stride) in methods.items():
        table = evaluate_records(fn, store, records, stride=stride, desc=name)
        results[name], counts[name], undefined[name] = table.mean(), len(table), table.undefined()
    text = markdown_table(results, counts)
    print(f"{args.split} split of {args.data}: {len(records)} images, mean over images\n")
    print(text)
    for name, u in undefined.items():
        if any(u.values()):
            print(f"{name}: images left out for empty sets: {u}")
    if args.out:
        Path(args.out).write_text(
            json.dumps(
                {
                    "title": args.title or f"{args.split} split of {args.data}",
                    "split": args.split,
                    "images": len(records),
                    "results": results,
                    "undefined": undefined,
                },
                indent=1,
            )
        )
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdc-train", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit", help="two-stage training; resumes from OUT/last.pt")
    f.add_argument("--data", required=True, help="dataset directory (sdc-data generate)")
    f.add_argument("--out", required=True, help="run directory: checkpoints, log.csv, plots")
    f.add_argument("--preset", default="cpu", choices=sorted(PRESETS), help="recipe (default: cpu)")
    f.add_argument("--config", help="JSON file of TrainConfig fields (flags override it)")
    f.add_argument("--variant", choices=sorted(VARIANTS))
    f.add_argument("--fsnet-inputs", dest="fsnet_inputs", choices=["both", "gray", "sparse"])
    for name, kind in (
        ("fsnet_epochs", int),
        ("epochs", int),
        ("batch_size", int),
        ("tile", int),
        ("lr", float),
        ("weight_decay", float),
        ("samples_per_epoch", int),
        ("val_samples", int),
        ("workers", int),
        ("seed", int),
    ):
        f.add_argument("--" + name.replace("_", "-"), dest=name, type=kind)
    f.add_argument(
        "--init-segmentation",
        dest="init_segmentation",
        help="checkpoint whose trained FSNet to reuse: skips stage 1",
    )
    f.add_argument("--restart", action="store_true", help="ignore OUT/last.pt")
    f.set_defaults(func=cmd_fit)

    e = sub.add_parser("evaluate", help="Table-3-style metrics on a split")
    e.add_argument("--checkpoint", nargs="*", default=[], help="one or more checkpoints")
    e.add_argument("--onnx", help="also evaluate an exported ONNX model (onnxruntime)")
    e.add_argument("--data", required=True)
    e.add_argument("--split", default="test")
    e.add_argument("--floor", action="store_true", help="also the classical morphological fill")
    e.add_argument("--limit", type=int, help="evaluate on this many images (evenly spread)")
    e.add_argument("--out", help="write the results as JSON")
    e.add_argument("--title", help="heading of these results in the model card")
    e.set_defaults(func=cmd_evaluate)

    c = sub.add_parser("card", help="write the model card from a checkpoint and evaluation reports")
    c.add_argument("--checkpoint", required=True)
    c.add_argument("--report", nargs="*", default=[], help="JSON files of `evaluate --out`")
    c.add_argument("--onnx", help="the exported model the card describes (names its version)")
    c.add_argument("--notes", help="markdown appended as is (limitations, observations)")
    c.add_argument("--out", required=True)
    c.set_defaults(func=cmd_card)
    return p


def cmd_card(args: argparse.Namespace) -> int:
    model, state = load_checkpoint(args.checkpoint)
    reports = [json.loads(Path(r).read_text()) for r in args.report]
    version = Path(args.checkpoint).stem
    if args.onnx:
        import onnx

        meta = {p.key: p.value for p in onnx.load(args.onnx).metadata_props}
        version = meta.get("model_version", version)
    notes = Path(args.notes).read_text() if args.notes else ""
    Path(args.out).write_text(model_card(state, model, reports, version, notes))
    print(f"wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        return args.func(args)
    except (FileNotFoundError, ValueError) as exc:
        print(f"sdc-train: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
