"""``sdc-train``: fit SDCNet (or an ablation variant) and evaluate it on a split."""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import MISSING, Field, fields
from pathlib import Path
from typing import get_args, get_type_hints

import cv2

from sdcnet.cli import add_debug_flag, run_command
from sdcnet.dataset_format import SampleStore
from sdcnet.meshes import read_mesh_folder
from sdcnet.metrics import depth_table, markdown_table
from sdcnet.training.card import model_card
from sdcnet.training.checkpoint import load_checkpoint, save_checkpoint
from sdcnet.training.data.conditions import ROBUSTNESS
from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, generate, make_sample
from sdcnet.training.evaluate import (
    Method,
    StoredAnswers,
    classical,
    evaluate_records,
    mask_metrics_only,
    network,
    torch_model_fn,
    torch_segmentation_fn,
)
from sdcnet.training.real import evaluate_per_model, gallery
from sdcnet.training.train import PRESETS, TrainConfig, Trainer, config_from_preset
from sdcnet.visualize import montage


def flag_fields() -> list[Field]:
    """The fields of ``TrainConfig`` that are flags of ``sdc-train fit``."""
    return [f for f in fields(TrainConfig) if f.metadata.get("flag", True)]


def add_config_flags(parser: argparse.ArgumentParser) -> None:
    """One flag per field of ``TrainConfig`` (``--batch-size`` for ``batch_size``): its type
    (``int | None`` gives int), its help and choices from the field's metadata, required when
    the field has no default. A flag not given is None, so that the preset and ``--config``
    fill it."""
    hints = get_type_hints(TrainConfig)
    for f in flag_fields():
        kind = next(k for k in (*get_args(hints[f.name]), hints[f.name]) if k is not type(None))
        parser.add_argument(
            "--" + f.name.replace("_", "-"),
            dest=f.name,
            type=kind,
            required=f.default is MISSING and f.default_factory is MISSING,
            **{k: v for k, v in f.metadata.items() if k in ("help", "choices")},
        )


def cmd_fit(args: argparse.Namespace) -> int:
    overrides = json.loads(Path(args.config).read_text()) if args.config else {}
    for f in flag_fields():
        value = getattr(args, f.name)
        if value is not None:
            overrides[f.name] = value
    config = config_from_preset(args.preset, **overrides)
    best = Trainer(config).fit(resume=not args.restart)
    print(f"best checkpoint: {best}")
    return 0


def _methods(args: argparse.Namespace) -> dict[str, Method]:
    """Name -> method for --checkpoint, --onnx and --floor."""
    names = getattr(args, "names", None) or []
    if names and len(names) != len(args.checkpoint):
        raise ValueError(f"--names gives {len(names)} names for {len(args.checkpoint)} checkpoints")
    segmentation_only = getattr(args, "segmentation_only", False)
    methods = {}
    for i, path in enumerate(args.checkpoint):
        model, state = load_checkpoint(path)
        name = names[i] if names else state.get("train_config", {}).get("variant", Path(path).stem)
        if name in methods:
            raise ValueError(f"two checkpoints are both called {name!r}: give --names")
        fn = torch_segmentation_fn(model) if segmentation_only else torch_model_fn(model)
        methods[name] = network(fn, model.config.stride)
    if args.onnx:
        from sdcnet.runtime import OnnxModel

        onnx_model = OnnxModel(args.onnx)
        methods[f"onnx:{Path(args.onnx).name}"] = network(
            onnx_model.run, onnx_model.stride, onnx_model.info.work_pixels
        )
    for entry in getattr(args, "answers", None) or []:
        name, sep, folder = entry.partition("=")
        if not sep or not name or not folder:
            raise ValueError(f"--answers takes NAME=FOLDER, got {entry!r}")
        methods[name] = StoredAnswers(folder)
    if args.floor:
        methods["classical fill"] = classical
    if not methods:
        raise ValueError("nothing to evaluate: give --checkpoint, --onnx or --floor")
    return methods


def cmd_robustness(args: argparse.Namespace) -> int:
    """Every condition of the robustness suite: the methods against the classical fill."""
    from sdcnet.training.robustness import run_suite

    table = run_suite(
        _methods(args),
        args.conditions,
        Path(args.data),
        read_mesh_folder(args.meshes) if args.meshes else (),
        Path(args.out),
        args.views,
        args.seed,
        args.workers,
        args.gallery,
        args.models,
    )
    print(table)
    return 0


def cmd_real(args: argparse.Namespace) -> int:
    """Render the real meshes (once), evaluate every method per spacecraft, draw the gallery."""
    data = Path(args.data)
    if not (data / "manifest.jsonl").exists():
        config = GenerateConfig(
            models=0,
            views=args.views,
            seed=args.seed,
            meshes=read_mesh_folder(args.meshes),
            split=(0, 0, 0),
        )
        generate(config, data, workers=args.workers)
    store = SampleStore(data)
    records = store.split("real")
    methods = _methods(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    per_method = {
        name: evaluate_per_model(method, store, records) for name, method in methods.items()
    }
    overall = {name: tables["all"].mean() for name, tables in per_method.items()}
    lines = [
        f"Real spacecraft (never trained on): {len(records)} frames of "
        f"{len({r['model_name'] for r in records})} NASA models, rendered by `sdc-data` "
        f"({store.info['command']} --meshes ...), mean over images.",
        "",
        "### All spacecraft",
        "",
        markdown_table(overall),
        "",
        depth_table(overall),
        "",
    ]
    first = next(iter(per_method))
    for name in sorted(k for k in per_method[first] if k != "all"):
        rows = {method: tables[name].mean() for method, tables in per_method.items()}
        lines += [f"### {name}", "", markdown_table(rows), "", depth_table(rows), ""]
    (out / "real_spacecraft.md").write_text("\n".join(lines))
    (out / "real_spacecraft.json").write_text(
        json.dumps(
            {
                "title": "Real spacecraft (never trained on)",
                "split": "real",
                "images": len(records),
                "results": overall,
                "undefined": {n: t["all"].undefined() for n, t in per_method.items()},
            },
            indent=1,
        )
    )
    others = {
        name: method
        for name, method in methods.items()
        if name != first and not name.startswith("onnx:")  # the same model as the first
    }
    print(gallery(methods[first], store, records, out / "gallery.png", others))
    print("\n".join(lines))
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    store = SampleStore(args.data)
    records = store.split(args.split, args.limit)
    if not records:
        raise ValueError(f"split {args.split!r} is empty in {args.data}")
    methods = _methods(args)
    results, counts, undefined = {}, {}, {}
    for name, method in methods.items():
        table = evaluate_records(
            method, store, records, desc=name, mask_only=args.segmentation_only
        )
        results[name], counts[name], undefined[name] = table.mean(), len(table), table.undefined()
        if args.segmentation_only:
            results[name] = mask_metrics_only(results[name])
    text = markdown_table(results, counts) + "\n\n" + depth_table(results)
    print(f"{args.split} split of {args.data}: {len(records)} images, mean over images\n")
    print(text)
    for name, u in undefined.items():
        if any(u.values()):
            print(f"{name}: images left out for empty sets: {u}")
    if args.out:
        report = {
            "title": args.title or f"{args.split} split of {args.data}",
            "split": args.split,
            "images": len(records),
            "frames_sha256": frames_digest(records),
            "results": results,
            "undefined": undefined,
        }
        if args.append:
            report = appended(Path(args.out), report)
        Path(args.out).write_text(json.dumps(report, indent=1))
    return 0


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


#: What a user's mistake raises (a missing or bad file, a bad value): one line, exit 2.
USER_ERRORS = {OSError: 2, ValueError: 2}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdc-train", description=__doc__)
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)
    f = sub.add_parser("fit", help="two-stage training; resumes from OUT/last.pt")
    f.add_argument("--preset", default="cpu", choices=sorted(PRESETS), help="recipe (default: cpu)")
    f.add_argument("--config", help="JSON file of TrainConfig fields (flags override it)")
    add_config_flags(f)
    f.add_argument("--restart", action="store_true", help="ignore OUT/last.pt")
    f.set_defaults(func=cmd_fit)

    e = sub.add_parser("evaluate", help="Table-3-style metrics on a split")
    e.add_argument("--checkpoint", nargs="*", default=[], help="one or more checkpoints")
    e.add_argument("--names", nargs="*", help="table labels of the checkpoints, in order")
    e.add_argument(
        "--segmentation-only",
        action="store_true",
        help="run only the foreground path of the checkpoints: IOU and IOI (stage-1-only runs)",
    )
    e.add_argument("--onnx", help="also evaluate an exported ONNX model (onnxruntime)")
    e.add_argument(
        "--answers",
        nargs="*",
        default=[],
        metavar="NAME=FOLDER",
        help="answers made elsewhere, e.g. the previous model (benchmarks/previous_model.py)",
    )
    e.add_argument("--data", required=True)
    e.add_argument("--split", default="test")
    e.add_argument("--floor", action="store_true", help="also the classical morphological fill")
    e.add_argument("--limit", type=int, help="evaluate on this many images (evenly spread)")
    e.add_argument("--out", help="write the results as JSON")
    e.add_argument(
        "--append",
        action="store_true",
        help="add the rows to the --out report (made on the same frames); rows sorted by name",
    )
    e.add_argument("--title", help="heading of these results in the model card")
    e.set_defaults(func=cmd_evaluate)

    r = sub.add_parser("real", help="real spacecraft meshes: per-spacecraft table and gallery")
    r.add_argument("--checkpoint", nargs="*", default=[], help="first one draws the gallery")
    r.add_argument("--names", nargs="*", help="table labels of the checkpoints, in order")
    r.add_argument("--onnx", help="also the exported ONNX model")
    r.add_argument(
        "--answers",
        nargs="*",
        default=[],
        metavar="NAME=FOLDER",
        help="answers made elsewhere, e.g. the previous model (benchmarks/previous_model.py)",
    )
    r.add_argument("--floor", action="store_true", help="also the classical morphological fill")
    r.add_argument(
        "--meshes", default="../shared/real-meshes", help="mesh folder with manifest.json"
    )
    r.add_argument("--data", default="data/real", help="where the rendered frames go (made once)")
    r.add_argument("--views", type=int, default=8)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--workers", type=int, default=2)
    r.add_argument("--out", default="docs/real", help="markdown table, JSON and gallery.png")
    r.set_defaults(func=cmd_real)

    o = sub.add_parser(
        "robustness",
        help="model vs classical fill per condition (cameras, LIDARs, ranges, skies) on "
        "spacecraft never trained on: table, latency and galleries",
    )
    o.add_argument("--checkpoint", nargs="*", default=[], help="first one draws the galleries")
    o.add_argument("--names", nargs="*", help="table labels of the checkpoints, in order")
    o.add_argument("--onnx", help="also the exported ONNX model (onnxruntime, as served)")
    o.add_argument(
        "--answers",
        nargs="*",
        default=[],
        metavar="NAME=FOLDER",
        help="answers made elsewhere, e.g. the previous model (benchmarks/previous_model.py)",
    )
    o.add_argument("--conditions", nargs="*", default=list(ROBUSTNESS), choices=list(ROBUSTNESS))
    o.add_argument(
        "--meshes", default="../shared/real-meshes", help="real meshes (manifest.json); '' none"
    )
    o.add_argument("--data", default="data/robustness", help="where the frames go (made once)")
    o.add_argument("--views", type=int, default=3, help="frames per spacecraft and condition")
    o.add_argument("--seed", type=int, default=0, help="the reference dataset's (its test split)")
    o.add_argument("--models", type=int, default=126, help="the reference dataset's model count")
    o.add_argument("--workers", type=int, default=2)
    o.add_argument("--gallery", type=int, default=4, help="frames per condition's picture")
    o.add_argument("--out", default="docs/robustness", help="robustness.md, .json, galleries")
    o.set_defaults(func=cmd_robustness, floor=False)

    q = sub.add_parser(
        "pose",
        help="pose of known targets: single frames from scratch and tracked sequences, from "
        "the completed cloud, the classical fill's and the raw returns",
    )
    q.add_argument("--onnx", default="models/sdcnet.onnx", help="the model that completes")
    q.add_argument("--threads", type=int, default=2, help="onnxruntime threads")
    q.add_argument("--meshes", default="../shared/real-meshes", help="real meshes (manifest)")
    q.add_argument("--dataset", default="data/paper", help="whose split's models to use")
    q.add_argument("--split", default="test")
    q.add_argument("--limit", type=int, default=18, help="models of the split, evenly spread")
    q.add_argument("--views", type=int, default=4, help="single frames per model")
    q.add_argument("--seed", type=int, default=0, help="of the real meshes' frames and inits")
    q.add_argument(
        "--clouds",
        nargs="*",
        choices=["completed", "classical fill"],
        default=["completed", "classical fill"],
        help="the clouds registered beside the raw returns",
    )
    q.add_argument(
        "--no-perturbed",
        dest="perturbed",
        action="store_false",
        help="leave out the single frames tracked from perturbed true poses",
    )
    q.add_argument("--sequences", nargs="*", default=[], help="folders made by `sdc-data sequence`")
    q.add_argument(
        "--gallery",
        type=int,
        default=5,
        help="worst real frames in failures*.png, per cloud (0: no pictures)",
    )
    q.add_argument(
        "--redraw", action="store_true", help="only the pictures, from --out's pose_eval.json"
    )
    q.add_argument(
        "--out", default="docs/pose", help="pose_eval.md, pose_eval.json and failures.png"
    )
    q.set_defaults(func=cmd_pose)

    s = sub.add_parser("ship", help="copy a checkpoint without the optimiser state (to commit)")
    s.add_argument("--checkpoint", required=True)
    s.add_argument("--out", required=True)
    s.add_argument(
        "--zero",
        nargs="*",
        default=[],
        metavar="PREFIX",
        help="ablation copies: set the weights under these prefixes to 0, e.g. fdcnet.head "
        "(depth = the plane fit alone) or refiner.correction (FSNet without its refiner)",
    )
    s.set_defaults(func=cmd_ship)

    k = sub.add_parser(
        "calibrate", help="scale the depth's sigma to cover 68 %% of the errors on a split"
    )
    k.add_argument("--checkpoint", required=True)
    k.add_argument("--data", required=True, help="a dataset whose split was not trained on")
    k.add_argument("--split", default="val")
    k.add_argument("--limit", type=int, default=90, help="frames, evenly spread")
    k.add_argument(
        "--edge-weight",
        type=float,
        default=0.5,
        help="sigma's depth-edge term per metre of local depth spread, before the scaling "
        "(0: the scale head alone)",
    )
    k.add_argument("--out", required=True, help="the calibrated checkpoint")
    k.set_defaults(func=cmd_calibrate)

    c = sub.add_parser("card", help="write the model card from a checkpoint and evaluation reports")
    c.add_argument("--checkpoint", required=True)
    c.add_argument("--report", nargs="*", default=[], help="JSON files of `evaluate --out`")
    c.add_argument("--onnx", help="the exported model the card describes (names its version)")
    c.add_argument("--notes", help="markdown appended as is (limitations, observations)")
    c.add_argument("--robustness", help="robustness.json of `sdc-train robustness`")
    c.add_argument("--out", required=True)
    c.set_defaults(func=cmd_card)
    return p


def cmd_pose(args: argparse.Namespace) -> int:
    """Pose from scratch on single frames and tracked over sequences, three clouds; then the
    worst real frames from scratch in pictures (``--redraw``: only those, from the report)."""
    from sdcnet.runtime import OnnxModel
    from sdcnet.targets import load_target
    from sdcnet.training import pose_eval

    methods = {}
    if "completed" in args.clouds:
        onnx = OnnxModel(args.onnx, threads=args.threads)
        methods["completed"] = network(onnx.run, onnx.stride, onnx.info.work_pixels)
    if "classical fill" in args.clouds:
        methods["classical fill"] = classical
    entries = read_mesh_folder(args.meshes)
    real_config = GenerateConfig(models=0, views=args.views, seed=args.seed, meshes=entries)
    real = {
        k: (build_spacecraft(real_config, k), load_target(entry)) for k, entry in enumerate(entries)
    }
    stores = {Path(path).name: SampleStore(path) for path in args.sequences}
    out = Path(args.out)
    if args.redraw:
        results = pose_eval.read_report(out / "pose_eval.json")
    else:
        results = _pose_results(args, methods, real_config, real, stores)
        text, data = pose_eval.report(results, [*methods, pose_eval.RAW])
        out.mkdir(parents=True, exist_ok=True)
        (out / "pose_eval.md").write_text(text + "\n")
        (out / "pose_eval.json").write_text(json.dumps(data, indent=1))
        print(text)
    # From scratch on the real spacecraft: single frames and the sequences' first frames.
    real_names = {target.name for _, target in real.values()}
    scratch = [
        r
        for frames in results.values()
        for r in frames
        if r.mode == "scratch" and r.spacecraft in real_names
    ]

    def load(result: pose_eval.FrameResult):
        if result.trajectory:
            store = next(
                s for s in stores.values() if any(r["id"] == result.frame for r in s.records)
            )
            sample = store.load(next(r for r in store.records if r["id"] == result.frame))
            return next(t for _, t in real.values() if t.name == result.spacecraft), sample
        model_id, view = (int(part[1:]) for part in result.frame.split("_"))
        model, target = real[model_id]
        sample = make_sample(real_config, model, model_id, view, "real")
        return target, pose_eval.with_pose(sample, model)

    if not args.gallery or not methods:
        return 0
    first = next(iter(methods))  # its depth is drawn beside the returns
    for cloud, name in ((first, "failures.png"), (pose_eval.RAW, "failures_raw.png")):
        picks = [(r, *load(r)) for r in pose_eval.pick_failures(scratch, cloud, args.gallery)]
        rows = pose_eval.gallery_rows(picks, methods[first], cloud)
        cv2.imwrite(str(out / name), montage(rows, tile=256))
        print(out / name)
    return 0


def _pose_results(args, methods, real_config, real, stores) -> dict:
    """Name of each evaluation -> its frame results (``cmd_pose``)."""
    from sdcnet.training import pose_eval

    ids = set(pose_eval.split_ids(args.dataset, args.split, args.limit))
    ids |= {r["model"] for store in stores.values() for r in store.records if r["model"] < 1000}
    test_config, procedural = pose_eval.procedural_models(args.dataset, sorted(ids))
    single_ids = pose_eval.split_ids(args.dataset, args.split, args.limit)
    targets = {t.name: t for _, t in [*real.values(), *procedural.values()]}
    real_frames = list(pose_eval.single_frames(real_config, real, args.views, "real"))
    test_frames = list(
        pose_eval.single_frames(
            test_config, {m: procedural[m] for m in single_ids}, args.views, args.split
        )
    )
    results = {
        f"Real spacecraft, single frames from scratch ({args.views} views each)": (
            pose_eval.evaluate_frames(real_frames, methods)
        ),
        f"Test split ({len(single_ids)} models), single frames from scratch "
        f"({args.views} views each)": pose_eval.evaluate_frames(test_frames, methods),
    }
    if args.perturbed:
        results[f"Real spacecraft, tracked from perturbed true poses ({args.views} views each)"] = (
            pose_eval.evaluate_perturbed(real_frames, methods, args.seed)
        )
        results[
            f"Test split ({len(single_ids)} models), tracked from perturbed true poses "
            f"({args.views} views each)"
        ] = pose_eval.evaluate_perturbed(test_frames, methods, args.seed)
    for name, store in stores.items():
        count = len({r["model_name"] for r in store.records})
        results[f"Sequences {name} ({count} spacecraft), tracked at 10 Hz"] = (
            pose_eval.evaluate_sequences(store, targets, methods)
        )
    return results


def cmd_ship(args: argparse.Namespace) -> int:
    model, state = load_checkpoint(args.checkpoint)
    weights = model.state_dict()
    for prefix in args.zero:
        chosen = [k for k in weights if k.startswith(prefix + ".") or k == prefix]
        if not chosen:
            raise ValueError(f"--zero {prefix}: no weights under that prefix in {args.checkpoint}")
        for key in chosen:
            weights[key].zero_()
    keep = {
        k: v
        for k, v in state.items()
        if k not in ("model", "model_config", "optimizer", "scheduler")
    }
    if args.zero:
        keep["zeroed"] = list(args.zero)  # an ablation copy says so
    save_checkpoint(Path(args.out), model, **keep)
    print(f"wrote {args.out} ({Path(args.out).stat().st_size / 1e6:.2f} MB)")
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Set the model's sigma so that it covers 68 % of the errors on frames not trained on."""
    from sdcnet.training.uncertainty import calibrated, error_ratios, with_sigma

    model, state = load_checkpoint(args.checkpoint)
    model = with_sigma(model, model.config.sigma_per_scale, args.edge_weight)
    store = SampleStore(args.data)
    records = store.split(args.split, args.limit)
    if not records:
        raise ValueError(f"split {args.split!r} is empty in {args.data}")
    fixed, report = calibrated(model, error_ratios(model, store, records))
    keep = {k: v for k, v in state.items() if k not in ("model", "model_config")}
    keep["sigma_calibration"] = {
        **report,
        "data": args.data,
        "split": args.split,
        "frames": len(records),
    }
    save_checkpoint(Path(args.out), fixed, **keep)
    print(
        f"sigma x {report['factor']:.3f} (sigma_per_scale {report['sigma_per_scale']:.3f}, "
        f"sigma_edge_weight {report['sigma_edge_weight']:.3f}): "
        f"within 1 / 2 sigma {100 * report['within_1_before']:.1f} / "
        f"{100 * report['within_2_before']:.1f} % -> {100 * report['within_1_after']:.1f} / "
        f"{100 * report['within_2_after']:.1f} % on {report['pixels']} px of {len(records)} "
        f"{args.split} frames; wrote {args.out}"
    )
    return 0


def cmd_card(args: argparse.Namespace) -> int:
    model, state = load_checkpoint(args.checkpoint)
    reports = [json.loads(Path(r).read_text()) for r in args.report]
    version = Path(args.checkpoint).stem
    if args.onnx:
        import onnx

        meta = {p.key: p.value for p in onnx.load(args.onnx).metadata_props}
        version = meta.get("model_version", version)
    notes = Path(args.notes).read_text() if args.notes else ""
    robustness = json.loads(Path(args.robustness).read_text()) if args.robustness else None
    Path(args.out).write_text(model_card(state, model, reports, version, notes, robustness))
    print(f"wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_command("sdc-train", lambda: args.func(args), USER_ERRORS, args.debug)


if __name__ == "__main__":
    sys.exit(main())
