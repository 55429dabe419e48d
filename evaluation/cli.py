"""``sdc-eval``: score trained models, the exported one and the classical fill on a dataset
split, the real spacecraft and the robustness suite; pose of known targets; the model card."""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path

from sdcnet.allocator import configure_malloc
from sdcnet.cli import FILE_AND_VALUE_ERRORS, add_debug_flag, run_command
from sdcnet.evaluation.card import write_card
from sdcnet.evaluation.evaluate import evaluate_split
from sdcnet.evaluation.methods import methods_from
from sdcnet.evaluation.pose import CLOUDS, PoseRun, run_pose
from sdcnet.evaluation.real import evaluate_real, render_real
from sdcnet.evaluation.scoring import Method
from sdcnet.meshes import read_mesh_folder
from sdcnet.training.data.conditions import ROBUSTNESS

#: What a user's mistake raises (a missing or bad file, a bad value): one line, exit 2.
REAL_MESHES = "../shared/real-meshes"


def methods_of(args: argparse.Namespace) -> dict[str, Method]:
    """The methods named by the flags of ``add_method_flags``."""
    return methods_from(
        args.checkpoint,
        args.names,
        args.onnx,
        args.answers,
        args.floor,
        getattr(args, "segmentation_only", False),
    )


def cmd_evaluate(args: argparse.Namespace) -> int:
    evaluate_split(
        methods_of(args),
        args.data,
        args.split,
        args.limit,
        args.segmentation_only,
        args.out,
        args.append,
        args.title,
    )
    return 0


def cmd_real(args: argparse.Namespace) -> int:
    store = render_real(args.meshes, Path(args.data), args.views, args.seed, args.workers)
    print(evaluate_real(methods_of(args), store, Path(args.out)))
    return 0


def cmd_robustness(args: argparse.Namespace) -> int:
    from sdcnet.evaluation.robustness import run_suite

    configure_malloc()  # its milliseconds are the pipeline's as sdc-serve runs it
    table = run_suite(
        methods_of(args),
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


def cmd_factors(args: argparse.Namespace) -> int:
    from sdcnet.evaluation.factors import run_factors

    print(run_factors(methods_of(args), args.data, args.split, args.limit, Path(args.out)))
    return 0


def cmd_pose(args: argparse.Namespace) -> int:
    settings = {f.name: getattr(args, f.name) for f in fields(PoseRun)}
    run_pose(
        PoseRun(
            **{
                **settings,
                "clouds": tuple(args.clouds),
                "sequences": tuple(args.sequences),
                "suite": tuple(args.suite),
            }
        )
    )
    return 0


def cmd_card(args: argparse.Namespace) -> int:
    write_card(args.checkpoint, args.out, args.report, args.onnx, args.notes, args.robustness)
    print(f"wrote {args.out}")
    return 0


def add_method_flags(p: argparse.ArgumentParser, checkpoint_help: str, onnx_help: str) -> None:
    """The methods to compare: checkpoints, the ONNX model, stored answers, the fill."""
    p.add_argument("--checkpoint", nargs="*", default=[], help=checkpoint_help)
    p.add_argument("--names", nargs="*", help="table labels of the checkpoints, in order")
    p.add_argument("--onnx", nargs="*", default=[], help=onnx_help)
    p.add_argument(
        "--answers",
        nargs="*",
        default=[],
        metavar="NAME=FOLDER",
        help="answers made elsewhere, e.g. the previous model (benchmarks/previous_model.py)",
    )


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdc-eval", description=__doc__)
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)
    fill_help = "also the classical morphological fill"

    e = sub.add_parser("evaluate", help="Table-3-style metrics on a split")
    add_method_flags(
        e, "one or more checkpoints", "also evaluate exported ONNX models (onnxruntime)"
    )
    e.add_argument(
        "--segmentation-only",
        action="store_true",
        help="run only the foreground path of the checkpoints: IOU and IOI (stage-1-only runs)",
    )
    e.add_argument("--data", required=True)
    e.add_argument("--split", default="test")
    e.add_argument("--floor", action="store_true", help=fill_help)
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
    add_method_flags(r, "first one draws the gallery", "also exported ONNX models")
    r.add_argument("--floor", action="store_true", help=fill_help)
    r.add_argument("--meshes", default=REAL_MESHES, help="mesh folder with manifest.json")
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
    add_method_flags(
        o, "first one draws the galleries", "also exported ONNX models (onnxruntime, as served)"
    )
    o.add_argument("--conditions", nargs="*", default=list(ROBUSTNESS), choices=list(ROBUSTNESS))
    o.add_argument("--meshes", default=REAL_MESHES, help="real meshes (manifest.json); '' none")
    o.add_argument("--data", default="data/robustness", help="where the frames go (made once)")
    o.add_argument("--views", type=int, default=3, help="frames per spacecraft and condition")
    o.add_argument("--seed", type=int, default=0, help="the reference dataset's (its test split)")
    o.add_argument("--models", type=int, default=126, help="the reference dataset's model count")
    o.add_argument("--workers", type=int, default=2)
    o.add_argument("--gallery", type=int, default=4, help="frames per condition's picture")
    o.add_argument("--out", default="docs/robustness", help="robustness.md, .json, galleries")
    o.set_defaults(func=cmd_robustness, floor=False)

    f = sub.add_parser(
        "factors",
        help="IOU by each factor a frame records (background, LIDAR, range, camera, sensor) "
        "on frames drawing every factor at once (a dataset of the `any` world)",
    )
    add_method_flags(f, "checkpoints (the first one's deficit is shared out)", "ONNX models")
    f.add_argument("--data", required=True, help="e.g. `sdc-data generate --world any` frames")
    f.add_argument("--split", default="test")
    f.add_argument("--floor", action="store_true", help=fill_help)
    f.add_argument("--limit", type=int, help="this many frames (evenly spread)")
    f.add_argument("--out", default="docs/factors", help="factors.md and factors.json")
    f.set_defaults(func=cmd_factors)

    add_pose_parser(sub)

    c = sub.add_parser("card", help="write the model card from a checkpoint and evaluation reports")
    c.add_argument("--checkpoint", required=True)
    c.add_argument("--report", nargs="*", default=[], help="JSON files of `evaluate --out`")
    c.add_argument("--onnx", help="the exported model the card describes (names its version)")
    c.add_argument("--notes", help="markdown appended as is (limitations, observations)")
    c.add_argument("--robustness", help="robustness.json of `sdc-eval robustness`")
    c.add_argument("--out", required=True)
    c.set_defaults(func=cmd_card)
    return p


def add_pose_parser(sub: argparse._SubParsersAction) -> None:
    """``pose``: its flags are ``PoseRun``'s fields, with its defaults."""
    d = PoseRun()
    q = sub.add_parser(
        "pose",
        help="pose of known targets: single frames from scratch and tracked sequences, from "
        "the completed cloud, the classical fill's and the raw returns",
    )
    q.add_argument("--onnx", default=d.onnx, help="the model that completes")
    q.add_argument("--threads", type=int, default=d.threads, help="onnxruntime threads")
    q.add_argument("--meshes", default=d.meshes, help="real meshes (manifest)")
    q.add_argument("--dataset", default=d.dataset, help="whose split's models to use")
    q.add_argument("--split", default=d.split)
    q.add_argument("--limit", type=int, default=d.limit, help="models of the split, evenly spread")
    q.add_argument("--views", type=int, default=d.views, help="single frames per model")
    q.add_argument("--seed", type=int, default=d.seed, help="of the real meshes' frames and inits")
    q.add_argument(
        "--clouds",
        nargs="*",
        choices=CLOUDS,
        default=list(CLOUDS),
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
        "--suite",
        nargs="*",
        default=[],
        help="conditions of the robustness suite (its folders, rendered by `sdc-eval "
        "robustness` with the same --meshes): their frames from scratch",
    )
    q.add_argument(
        "--gallery",
        type=int,
        default=d.gallery,
        help="worst real frames in failures*.png, per cloud (0: no pictures)",
    )
    q.add_argument(
        "--redraw", action="store_true", help="only the pictures, from --out's pose_eval.json"
    )
    q.add_argument("--out", default=d.out, help="pose_eval.md, pose_eval.json and failures.png")
    q.set_defaults(func=cmd_pose)


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_command("sdc-eval", lambda: args.func(args), FILE_AND_VALUE_ERRORS, args.debug)


if __name__ == "__main__":
    sys.exit(main())
