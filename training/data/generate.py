"""Dataset generation: deterministic per (seed, model, view), parallel, sharded, resumable."""

from __future__ import annotations

import json
import multiprocessing as mp
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sdcnet import __version__
from sdcnet.camera import PAPER_CAMERA, PAPER_LIDAR, Intrinsics
from sdcnet.dataset_format import (
    FORMAT_VERSION,
    Sample,
    SampleStore,
    is_complete,
    read_meta,
    sample_id,
    write_atomically,
    write_manifest,
    write_sample,
)
from sdcnet.meshes import MeshEntry
from sdcnet.training.data.background import (
    render_background,
    sample_background,
    sample_sun_near_view,
)
from sdcnet.training.data.conditions import Conditions, draw_conditions, world_for_frame
from sdcnet.training.data.lidar import Lidar, scan_lidar
from sdcnet.training.data.render import PosedModel, render_camera
from sdcnet.training.data.scene import Scene, SceneConfig, sample_scene
from sdcnet.training.data.spacecraft import SpacecraftModel, load_mesh_file, procedural_spacecraft

PAPER_SPLIT = (99, 9, 18)  # train / val / test models of 126 (paper sec. IV)
SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class GenerateConfig:
    """Everything a dataset depends on. Workers and shards change speed, never content."""

    models: int = 126
    views: int = 64
    size: int = 1024
    seed: int = 0
    split: tuple[int, int, int] | None = None  # models per split; default: paper ratios
    scene: SceneConfig | None = None  # None: the world's ranges
    meshes: tuple[MeshEntry, ...] = ()  # users' meshes, appended after the procedural models
    mesh_split: str = "real"
    world: str = "paper"  # how cameras, LIDARs, ranges and skies are drawn (conditions.WORLDS)
    styles: tuple[str, ...] = ()  # render styles drawn per frame (styles.STYLE_KINDS); () = world's
    only_splits: tuple[str, ...] = ()  # render only the models of these splits (empty: all)

    @property
    def intrinsics(self) -> Intrinsics:
        """The paper camera at ``size``: every frame's camera in the paper's world."""
        return PAPER_CAMERA.intrinsics().scaled(self.size, self.size)

    def split_counts(self) -> tuple[int, int, int]:
        if self.split is not None:
            if sum(self.split) != self.models:
                raise ValueError(f"split {self.split} does not add up to {self.models} models")
            return self.split
        return paper_split_counts(self.models)

    def command(self) -> str:
        """The command that regenerates this dataset (output directory aside)."""
        parts = [
            f"sdc-data generate --models {self.models} --views {self.views}",
            f"--size {self.size} --seed {self.seed}",
        ]
        if self.world != "paper":
            parts.append(f"--world {self.world}")
        if self.styles:
            parts.append("--styles " + " ".join(self.styles))
        if self.only_splits:
            parts.append("--only-splits " + " ".join(self.only_splits))
        if self.split is not None:
            parts.append("--split " + ",".join(map(str, self.split)))
        return " ".join(parts)


def paper_split_counts(models: int) -> tuple[int, int, int]:
    """Models per split in the paper's 99:9:18 ratio, every split non-empty from 3 models."""
    if models < 3:
        return (models, 0, 0)
    val = max(1, round(models * PAPER_SPLIT[1] / sum(PAPER_SPLIT)))
    test = max(1, round(models * PAPER_SPLIT[2] / sum(PAPER_SPLIT)))
    return (models - val - test, val, test)


def model_splits(config: GenerateConfig) -> dict[int, str]:
    """Split name of every model id; procedural models are shuffled by the seed."""
    order = np.random.default_rng([config.seed, 0x5EED]).permutation(config.models)
    counts = config.split_counts()
    names = np.repeat(SPLITS, counts)
    splits = {int(m): str(name) for m, name in zip(order, names, strict=True)}
    for k in range(len(config.meshes)):
        splits[config.models + k] = config.mesh_split
    return splits


def build_spacecraft(config: GenerateConfig, model_id: int) -> SpacecraftModel:
    """Spacecraft ``model_id`` of the dataset ``config`` describes: procedural below
    ``config.models``, else ``config.meshes``' file of that index (metres)."""
    if model_id < config.models:
        return procedural_spacecraft(config.seed, model_id)
    entry = config.meshes[model_id - config.models]
    return load_mesh_file(
        entry.path, longest_m=entry.longest_m, scale=entry.scale, seed=config.seed
    )


def render_scene(
    model: SpacecraftModel, scene: Scene, conditions: Conditions, seeds: tuple[int, ...]
) -> Sample:
    """Camera frame and LIDAR scan of ``model`` placed as ``scene`` under ``conditions``; the
    noise is drawn from ``seeds`` (+ 2 for the camera, + 3 for the LIDAR, + 5 and + 6 for the
    background). Meta: what the frame shows and every factor it was drawn with."""
    K = conditions.intrinsics
    posed = PosedModel.place(model, scene)
    sky = sample_background(np.random.default_rng([*seeds, 5]), K, scene.sun, conditions.background)
    background = render_background(sky, K, scene.sun, np.random.default_rng([*seeds, 6]))
    frame = render_camera(
        posed,
        K,
        np.random.default_rng([*seeds, 2]),
        background,
        conditions.sensor,
        conditions.style,
    )
    lidar = within_range(conditions.lidar, scene, model)
    sparse = scan_lidar(posed, lidar, K, np.random.default_rng([*seeds, 3]))
    meta = {
        "model_name": model.name,
        "intrinsics": K.as_dict(),
        "returns": int(np.count_nonzero(sparse)),
        "foreground_px": int(np.count_nonzero(frame.depth)),
        "exposure": round(frame.exposure, 5),
        **scene.metadata(),
        **replace(conditions, lidar=lidar).metadata(),
        "background": sky.metadata(),
    }
    return Sample(frame.gray, sparse, frame.depth, meta)


def within_range(lidar: Lidar, scene: Scene, model: SpacecraftModel) -> Lidar:
    """``lidar`` with a maximum range that reaches the whole spacecraft: a frame without
    returns teaches nothing (the paper's LIDAR, 280 m, already covers its 250 m scenes)."""
    reach = scene.distance_m + model.radius_m
    return lidar if lidar.max_range_m >= reach else replace(lidar, max_range_m=round(reach + 1))


def frame_conditions(config: GenerateConfig, model_id: int, view: int) -> Conditions:
    """The conditions of one frame: drawn from the dataset's world, seeded by the frame."""
    rng = np.random.default_rng([config.seed, model_id, view, 4])
    world = world_for_frame(config.world, rng)
    if config.styles:  # drawn last: the frames are the world's but for their style
        world = replace(world, styles=config.styles)
    conditions = draw_conditions(world, rng, config.size)
    return conditions if config.scene is None else replace(conditions, scene=config.scene)


def make_sample(
    config: GenerateConfig, model: SpacecraftModel, model_id: int, view: int, split: str
) -> Sample:
    """Render one frame; depends only on (config, model, view)."""
    conditions = frame_conditions(config, model_id, view)
    rng = np.random.default_rng([config.seed, model_id, view, 1])
    scene = sample_scene(rng, conditions.scene, conditions.intrinsics, model.radius_m)
    if conditions.background == "sun":  # the Sun in or near the frame, behind the target
        scene = scene.with_sun(sample_sun_near_view(rng, conditions.intrinsics))
    sample = render_scene(model, scene, conditions, (config.seed, model_id, view))
    sid = sample_id(model_id, view)
    head = {"id": sid, "file": f"samples/{sid}.npz", "model": model_id}
    sample.meta = {**head, **sample.meta, "split": split, "view": view}
    return sample


_worker_cache: dict[int, SpacecraftModel] = {}


def _generate_one(args: tuple[GenerateConfig, Path, int, int, str]) -> str:
    config, out, model_id, view, split = args
    if model_id not in _worker_cache:
        _worker_cache.clear()  # tasks come grouped by model: keep one
        _worker_cache[model_id] = build_spacecraft(config, model_id)
    sample = make_sample(config, _worker_cache[model_id], model_id, view, split)
    write_sample(out / sample.meta["file"], sample)
    return sample.meta["id"]


def dataset_info(config: GenerateConfig) -> dict:
    splits = model_splits(config)
    counts = config.split_counts()
    info = {
        "format_version": FORMAT_VERSION,
        "generator": f"sdcnet {__version__}",
        "command": config.command(),
        "seed": config.seed,
        "models": config.models,
        "views": config.views,
        "size": config.size,
        "split_models": dict(zip(SPLITS, counts, strict=True)),
        "world": config.world,
        "only_splits": list(config.only_splits),
        "camera": asdict(PAPER_CAMERA),
        "intrinsics": config.intrinsics.as_dict(),
        "lidar": asdict(PAPER_LIDAR),
        "scene": asdict(config.scene) if config.scene is not None else None,
        "user_meshes": [entry.describe() for entry in config.meshes],
        "model_split": {str(k): v for k, v in sorted(splits.items())},
    }
    if config.styles:  # only when given: the datasets made before it keep their record
        info["styles"] = list(config.styles)
    return info


def generate(
    config: GenerateConfig,
    out: Path,
    workers: int = 1,
    shard: tuple[int, int] = (0, 1),
    progress: bool = True,
) -> SampleStore | None:
    """Write the samples of ``shard`` (index, count) that are missing; then, once every
    sample of the dataset exists, the manifest. Returns the store when complete."""
    out = Path(out)
    (out / "samples").mkdir(parents=True, exist_ok=True)
    info = dataset_info(config)
    info_path = out / "dataset.json"
    text = json.dumps(info, indent=1, sort_keys=True) + "\n"
    if info_path.exists() and info_path.read_text() != text:
        raise ValueError(f"{out} holds a dataset made with other settings; use another --out")
    write_atomically(info_path, text)
    splits = model_splits(config)
    chosen = [
        m for m in sorted(splits) if not config.only_splits or splits[m] in config.only_splits
    ]
    tasks = [(config, out, m, v, splits[m]) for m in chosen for v in range(config.views)]
    index, count = shard
    todo = [
        t
        for k, t in enumerate(tasks)
        if k % count == index and not is_complete(out / "samples" / f"{sample_id(t[2], t[3])}.npz")
    ]
    bar = tqdm(total=len(todo), desc="samples", unit="smp", disable=not progress)
    if workers > 1 and len(todo) > 1:
        with mp.get_context("spawn").Pool(workers) as pool:
            for _ in pool.imap_unordered(_generate_one, todo, chunksize=2):
                bar.update()
    else:
        for task in todo:
            _generate_one(task)
            bar.update()
    bar.close()
    files = [out / "samples" / f"{sample_id(t[2], t[3])}.npz" for t in tasks]
    if not all(is_complete(f) for f in files):
        return None
    return _with_manifest(out, files)


def _with_manifest(out: Path, files: list[Path]) -> SampleStore:
    """The dataset ``out`` with its manifest written over ``files`` (its samples, by id)."""
    write_manifest(out, [read_meta(f) for f in files])
    return SampleStore(out)


def close(out: Path) -> SampleStore:
    """Write the manifest over the samples of ``out`` rendered so far, so that a generation
    stopped before its end (a time limit, a killed job) can be trained on as it stands. A
    sample cut off mid-write is left out; running ``generate`` again later still resumes and
    rewrites the manifest over every sample once all exist."""
    out = Path(out)
    if not (out / "dataset.json").is_file():
        raise FileNotFoundError(f"{out} is not a dataset (no dataset.json): sdc-data generate")
    files = sorted(f for f in (out / "samples").glob("*.npz") if is_complete(f))
    if not files:
        raise ValueError(f"{out} holds no complete sample yet")
    return _with_manifest(out, files)
