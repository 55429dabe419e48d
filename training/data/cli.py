"""``sdc-data``: generate the synthetic dataset, preview it, render pose-tracking sequences,
benchmark the generator."""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from sdcnet.cli import FILE_AND_VALUE_ERRORS, add_debug_flag, run_command
from sdcnet.dataset_format import SampleStore, merge
from sdcnet.meshes import read_mesh_folder
from sdcnet.returns import returns_from_dense, write_returns_csv
from sdcnet.training.data.conditions import WORLDS
from sdcnet.training.data.generate import (
    GenerateConfig,
    build_spacecraft,
    close,
    generate,
    make_sample,
)
from sdcnet.training.data.preview import preview
from sdcnet.training.data.scene import SceneConfig
from sdcnet.training.data.sequence import (
    DEFAULT_TRAJECTORIES,
    TRAJECTORIES,
    SequenceConfig,
    write_sequences,
)
from sdcnet.training.data.spacecraft import SpacecraftModel, load_mesh_file
from sdcnet.training.data.styles import STYLE_KINDS

#: Model ids of ``sdc-data sequence --meshes`` files: after any procedural dataset's.
MESH_IDS = 1000


def _shard(text: str) -> tuple[int, int]:
    try:
        index, count = (int(x) for x in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--shard takes INDEX/COUNT, e.g. 0/4, got {text!r}"
        ) from None
    if not 0 <= index < count:
        raise argparse.ArgumentTypeError(f"--shard index must be in [0, {count}), got {index}")
    return index, count


def _split(text: str) -> tuple[int, int, int]:
    try:
        train, val, test = (int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--split takes TRAIN,VAL,TEST model counts, got {text!r}"
        ) from None
    return train, val, test


def _config(args: argparse.Namespace) -> GenerateConfig:
    meshes = read_mesh_folder(args.meshes, args.mesh_scale) if args.meshes else ()
    return GenerateConfig(
        models=args.models,
        views=args.views,
        size=args.size,
        seed=args.seed,
        split=args.split,
        meshes=meshes,
        mesh_split=args.mesh_split,
        world=args.world,
        styles=tuple(args.styles),
        only_splits=tuple(args.only_splits),
    )


def cmd_generate(args: argparse.Namespace) -> int:
    config = _config(args)
    started = time.perf_counter()
    store = generate(
        config, args.out, workers=args.workers, shard=args.shard, progress=not args.quiet
    )
    elapsed = time.perf_counter() - started
    if store is None:
        print(
            f"shard {args.shard[0]}/{args.shard[1]} done in {elapsed:.0f} s; "
            "the manifest is written once every shard has finished"
        )
    else:
        print(f"{_describe(store, args.out)} after {elapsed:.0f} s")
    return 0


def _describe(store: SampleStore, root: Path) -> str:
    """How many samples a dataset holds, per split."""
    counts = {s: len(store.split(s)) for s in sorted({r["split"] for r in store.records})}
    return f"{len(store)} samples in {root} ({counts})"


def cmd_close(args: argparse.Namespace) -> int:
    print(f"{_describe(close(args.dataset), args.dataset)}: manifest written")
    return 0


def cmd_merge(args: argparse.Namespace) -> int:
    sources = [str(d) for d in args.datasets]
    command = shlex.join(["sdc-data", "merge", "--out", str(args.out), *sources])
    store = merge(args.out, sources, command)
    print(f"{_describe(store, args.out)}: the sources' files, left where they are")
    return 0


def cmd_example(args: argparse.Namespace) -> int:
    """One frame of one mesh at a set distance, as a user would send it: the gray image
    (``NAME.png``) and the LIDAR returns (``NAME.returns.csv``, ``sdcnet.returns``)."""
    meshes = {entry.path.stem: entry for entry in read_mesh_folder(args.meshes)}
    if args.name not in meshes:
        raise ValueError(f"no mesh called {args.name!r} in {args.meshes}: {sorted(meshes)}")
    scene = SceneConfig(min_distance_m=args.distance, max_distance_m=args.distance)
    config = GenerateConfig(
        models=0, views=1, seed=args.seed, split=(0, 0, 0), scene=scene, meshes=(meshes[args.name],)
    )
    sample = make_sample(config, build_spacecraft(config, 0), 0, 0, "example")
    args.out.mkdir(parents=True, exist_ok=True)
    gray, returns = args.out / f"{args.name}.png", args.out / f"{args.name}.returns.csv"
    if not cv2.imwrite(str(gray), sample.gray, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise OSError(f"cannot write {gray}")
    write_returns_csv(returns, returns_from_dense(sample.sparse))
    meta = sample.meta
    print(
        f"{gray} ({gray.stat().st_size / 1e3:.0f} kB) and {returns} "
        f"({returns.stat().st_size / 1e3:.1f} kB): {args.name} at {meta['distance_m']:.0f} m, "
        f"{meta['returns']} LIDAR returns, {meta['foreground_px']} spacecraft px"
    )
    return 0


def cmd_preview(args: argparse.Namespace) -> int:
    out = args.out or Path(args.dataset) / "preview.png"
    print(preview(args.dataset, out, count=args.count, zoom=not args.full_frame))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    """Seconds per sample on one core and the LIDAR density, over a few samples."""
    config = GenerateConfig(
        models=args.models, views=args.views, size=args.size, seed=args.seed, world=args.world
    )
    times, density, returns = [], [], []
    for m in range(config.models):
        model = build_spacecraft(config, m)
        for v in range(config.views):
            t0 = time.perf_counter()
            s = make_sample(config, model, m, v, "bench")
            times.append(time.perf_counter() - t0)
            returns.append(s.meta["returns"])
            density.append(s.meta["returns"] / max(s.meta["foreground_px"], 1))
    per = float(np.median(times))
    total = 8064 * per / max(args.workers, 1)
    print(
        f"{len(times)} samples at {args.size} x {args.size}: "
        f"median {per:.3f} s/sample on one process "
        f"(mean {np.mean(times):.3f}, max {np.max(times):.3f})"
    )
    print(
        f"LIDAR returns per sample: median {np.median(returns):.0f}; "
        f"per foreground pixel: median {np.median(density):.5f} ({100 * np.median(density):.2f} %)"
    )
    print(f"projected 8064-sample paper set with {args.workers} workers: {total / 60:.1f} min")
    return 0


def sequence_models(args: argparse.Namespace) -> dict[int, tuple[SpacecraftModel, str]]:
    """The models of ``sdc-data sequence``: a dataset split's procedural models (rebuilt from
    the dataset's seed, same ids) and the folder's meshes (ids 1000, 1001, ...)."""
    models: dict[int, tuple[SpacecraftModel, str]] = {}
    if args.dataset:
        info_path = Path(args.dataset) / "dataset.json"
        if not info_path.is_file():
            raise FileNotFoundError(f"{args.dataset} is not an sdcnet dataset: no dataset.json")
        info = json.loads(info_path.read_text())
        config = GenerateConfig(models=info["models"], seed=info["seed"])
        ids = [int(m) for m, split in info["model_split"].items() if split == args.split]
        ids = [m for m in ids if m < info["models"]]
        if not ids:
            raise ValueError(f"{args.dataset} has no procedural model in split {args.split!r}")
        step = max(1, len(ids) // args.limit) if args.limit else 1
        for m in ids[::step][: args.limit or None]:
            models[m] = (build_spacecraft(config, m), args.split)
    if args.meshes:
        for k, entry in enumerate(read_mesh_folder(args.meshes)):
            mesh = load_mesh_file(entry.path, entry.longest_m, entry.scale, seed=args.seed)
            models[MESH_IDS + k] = (mesh, args.mesh_split)
    if not models:
        raise ValueError("give --dataset (with --split) and/or --meshes: no model to render")
    return models


def cmd_sequence(args: argparse.Namespace) -> int:
    config = SequenceConfig(
        frames=args.frames, size=args.size, seed=args.seed, trajectories=tuple(args.trajectories)
    )
    models = sequence_models(args)
    command = (
        f"sdc-data sequence --frames {args.frames} --size {args.size} --seed {args.seed} "
        f"--trajectories {' '.join(args.trajectories)}"
        + (
            f" --dataset {args.dataset} --split {args.split} --limit {args.limit}"
            if args.dataset
            else ""
        )
        + (f" --meshes {args.meshes}" if args.meshes else "")
    )
    started = time.perf_counter()
    manifest = write_sequences(models, config, args.out, command, progress=not args.quiet)
    count = len(models) * len(config.trajectories) * config.frames
    print(
        f"{count} frames ({len(models)} models x {len(config.trajectories)} trajectories x "
        f"{config.frames} frames at {config.rate_hz:g} Hz) in {args.out} after "
        f"{time.perf_counter() - started:.0f} s; {manifest}"
    )
    return 0


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sdc-data", description=__doc__)
    add_debug_flag(p)
    sub = p.add_subparsers(dest="command", required=True)

    g = sub.add_parser("generate", help="render a dataset (resumable; shardable across machines)")
    g.add_argument("--out", type=Path, required=True, help="dataset directory")
    g.add_argument("--models", type=int, default=126, help="procedural spacecraft models")
    g.add_argument("--views", type=int, default=64, help="views per model")
    g.add_argument("--size", type=int, default=1024, help="image side in pixels (same optics)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument(
        "--split", type=_split, default=None, help="TRAIN,VAL,TEST models (default 99:9:18)"
    )
    g.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    g.add_argument(
        "--shard", type=_shard, default=(0, 1), help="INDEX/COUNT of the work to do here"
    )
    g.add_argument(
        "--meshes",
        type=Path,
        default=None,
        help="folder of your own mesh files (optional manifest.json with longest_m)",
    )
    g.add_argument(
        "--mesh-scale", type=float, default=1.0, help="metres per mesh unit (no manifest)"
    )
    g.add_argument("--mesh-split", default="real", help="split name of the folder's meshes")
    g.add_argument(
        "--world",
        default="paper",
        choices=WORLDS,
        help="how each frame's camera, sensor, LIDAR, range and sky are drawn: paper (Tables "
        "1-2, 50-250 m, stars), any (every factor), mixed (a quarter paper, the rest any) or "
        "one robustness condition (default paper)",
    )
    g.add_argument(
        "--styles",
        nargs="*",
        default=[],
        choices=STYLE_KINDS,
        metavar="STYLE",
        help="render styles drawn per frame instead of the world's: ours (one ray a pixel, "
        "Blinn-Phong, hard shadows), pbr (anti-aliased, GGX, a fill light, stains); e.g. ours "
        "pbr (default: the world's, ours but for the other-renderer condition)",
    )
    g.add_argument(
        "--only-splits",
        nargs="*",
        default=[],
        metavar="SPLIT",
        help="render only the models of these splits, e.g. test real (default: all)",
    )
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=cmd_generate)

    c = sub.add_parser(
        "close",
        help="write the manifest over the samples rendered so far: train on a generation "
        "stopped before its end (generate again to resume it later)",
    )
    c.add_argument("dataset", type=Path, help="dataset directory")
    c.set_defaults(func=cmd_close)

    m = sub.add_parser(
        "merge",
        help="one dataset of several, to train on their frames together (your own spacecraft "
        "beside ours): a manifest over the sources' files, nothing copied",
    )
    m.add_argument("datasets", type=Path, nargs="+", help="dataset directories (at least two)")
    m.add_argument("--out", type=Path, required=True, help="the new dataset directory")
    m.set_defaults(func=cmd_merge)

    e = sub.add_parser(
        "example", help="one frame of a mesh as a user sends it: NAME.png and NAME.returns.csv"
    )
    e.add_argument("--meshes", type=Path, required=True, help="mesh folder (manifest.json)")
    e.add_argument("--name", required=True, help="the mesh's file name without its suffix")
    e.add_argument("--distance", type=float, default=120.0, help="metres (default 120)")
    e.add_argument("--seed", type=int, default=0, help="attitude, sun and noise")
    e.add_argument("--out", type=Path, default=Path("examples"))
    e.set_defaults(func=cmd_example)

    v = sub.add_parser("preview", help="montage PNG of a few samples")
    v.add_argument("dataset", type=Path)
    v.add_argument("--out", type=Path, default=None, help="PNG path (default DATASET/preview.png)")
    v.add_argument("--count", type=int, default=4)
    v.add_argument("--full-frame", action="store_true", help="show whole frames, not object crops")
    v.set_defaults(func=cmd_preview)

    q = sub.add_parser(
        "sequence",
        help="trajectories at 10 Hz (approach, fly-around, tumble) with every frame's pose",
    )
    q.add_argument("--out", type=Path, required=True, help="output directory")
    q.add_argument("--dataset", type=Path, help="a dataset whose split's models to render")
    q.add_argument("--split", default="test", help="that split (default test)")
    q.add_argument("--limit", type=int, default=0, help="at most this many of its models")
    q.add_argument("--meshes", type=Path, help="folder of your meshes (manifest.json)")
    q.add_argument("--mesh-split", default="real", help="split name of the folder's meshes")
    q.add_argument("--frames", type=int, default=30, help="frames per trajectory (10 Hz)")
    q.add_argument(
        "--trajectories",
        nargs="+",
        choices=TRAJECTORIES,
        default=list(DEFAULT_TRAJECTORIES),
        help="default: the paper camera's three; docking: 12 -> 4 m, a docking camera and LIDAR",
    )
    q.add_argument("--size", type=int, default=1024, help="image side in pixels (same optics)")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--quiet", action="store_true", help="no progress bar")
    q.set_defaults(func=cmd_sequence)

    b = sub.add_parser("bench", help="seconds per sample and LIDAR density")
    b.add_argument("--models", type=int, default=4)
    b.add_argument("--views", type=int, default=4)
    b.add_argument("--size", type=int, default=1024)
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--world", default="paper", choices=WORLDS, help="as for generate")
    b.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="for the projection")
    b.set_defaults(func=cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_command("sdc-data", lambda: args.func(args), FILE_AND_VALUE_ERRORS, args.debug)


if __name__ == "__main__":
    sys.exit(main())
