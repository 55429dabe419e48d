"""Sequences at the LIDAR's pace: trajectories of a spacecraft rendered at 10 Hz, with the
ground-truth pose of every frame, for pose tracking (``sdc-data sequence``).

Four trajectories, each ``frames`` long at ``rate_hz`` (time runs faster than a real
rendezvous: a 3 s approach covers 250 -> 50 m):

- ``approach``: the range falls linearly from ``approach_from_m`` to ``approach_to_m``
  while the attitude drifts slowly (``drift_deg_per_s`` about a random axis);
- ``flyaround``: the camera circles the target at a fixed range: the target turns about
  an axis across the line of sight at ``flyaround_deg_per_s``;
- ``tumble``: a tumbling target: it spins about a random body axis at
  ``tumble_deg_per_s`` while that axis precesses at a third of the rate;
- ``docking``: the last metres, ``docking_from_m`` -> ``docking_to_m`` (never inside the
  spacecraft's bounding sphere plus a metre), drifting like the approach, seen by a camera and
  LIDAR drawn once per sequence from the robustness suite's docking world (40-60 deg, a flash
  array or a scanning grid; ``sdcnet.training.data.conditions.DOCKING``): the spacecraft
  overflows the frame. Not rendered unless asked for (``--trajectories``).

The first three use the paper's camera and LIDAR; every frame's own are in its metadata.

Frames are written in the dataset format (``sdcnet.dataset_format``), one sample per frame,
with the sequence, trajectory, frame index, time and ``pose``: the target's pose in its own
frame (``{"R", "t"}``, p_camera = R p_target + t; the mesh file's frame for user meshes, the
model's centred frame for procedural ones) beside the generator's usual scene metadata.
Everything depends only on the seed.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sdcnet import __version__
from sdcnet.camera import PAPER_CAMERA, PAPER_LIDAR, Intrinsics
from sdcnet.dataset_format import FORMAT_VERSION, is_complete, read_meta, write_sample
from sdcnet.rigid import axis_angle
from sdcnet.training.data.conditions import DOCKING, PAPER, Conditions, draw_conditions
from sdcnet.training.data.generate import render_scene
from sdcnet.training.data.scene import Scene, SceneConfig, sample_scene
from sdcnet.training.data.spacecraft import SpacecraftModel

TRAJECTORIES = ("approach", "flyaround", "tumble", "docking")
#: Those rendered unless others are asked for: the paper's camera and LIDAR.
DEFAULT_TRAJECTORIES = ("approach", "flyaround", "tumble")


@dataclass(frozen=True)
class SequenceConfig:
    """What a set of sequences depends on (the models aside)."""

    frames: int = 30
    rate_hz: float = 10.0
    size: int = 1024
    seed: int = 0
    trajectories: tuple[str, ...] = DEFAULT_TRAJECTORIES
    approach_from_m: float = 250.0
    approach_to_m: float = 50.0
    drift_deg_per_s: float = 2.0
    flyaround_range_m: tuple[float, float] = (60.0, 200.0)  # drawn per sequence
    flyaround_deg_per_s: float = 15.0
    tumble_range_m: tuple[float, float] = (60.0, 200.0)
    tumble_deg_per_s: float = 10.0
    docking_from_m: float = 12.0
    docking_to_m: float = 4.0

    @property
    def intrinsics(self) -> Intrinsics:
        return PAPER_CAMERA.intrinsics().scaled(self.size, self.size)


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def trajectory(
    kind: str,
    config: SequenceConfig,
    rng: np.random.Generator,
    K: Intrinsics | None = None,
    radius_m: float = 0.0,
) -> list[Scene]:
    """The scenes of one sequence: the target's attitude and position per frame. ``K``: the
    camera (the docking trajectory places the target within its field of view), ``radius_m``:
    the spacecraft's bounding radius (the docking trajectory stays outside it)."""
    if kind not in TRAJECTORIES:
        raise ValueError(f"unknown trajectory {kind!r}; choose from {TRAJECTORIES}")
    scene_config = DOCKING.scene if kind == "docking" else SceneConfig()
    start = sample_scene(rng, scene_config, K)  # attitude, offset from the axis, sun
    direction = start.translation / np.linalg.norm(start.translation)
    times = np.arange(config.frames) / config.rate_hz
    if kind in ("approach", "docking"):
        ends = (config.approach_from_m, config.approach_to_m)
        if kind == "docking":
            near = radius_m + scene_config.clearance_m
            ends = (max(config.docking_from_m, near), max(config.docking_to_m, near))
        ranges = np.linspace(*ends, config.frames)
        axis, rate = _unit(rng), np.radians(config.drift_deg_per_s)
        turns = [axis_angle(axis, rate * t) for t in times]
    elif kind == "flyaround":
        ranges = np.full(config.frames, rng.uniform(*config.flyaround_range_m))
        across = np.cross(direction, _unit(rng))
        rate = np.radians(config.flyaround_deg_per_s)
        turns = [axis_angle(across, rate * t) for t in times]
    else:
        ranges = np.full(config.frames, rng.uniform(*config.tumble_range_m))
        spin, precession = _unit(rng), _unit(rng)
        rate = np.radians(config.tumble_deg_per_s)
        turns = [axis_angle(precession, rate * t / 3) @ axis_angle(spin, rate * t) for t in times]
    return [
        Scene(turn @ start.rotation, r * direction, start.sun, start.sun_angle_deg)
        for turn, r in zip(turns, ranges, strict=True)
    ]


def sequence_id(model_id: int, kind: str, frame: int) -> str:
    return f"m{model_id:04d}_{kind}_f{frame:03d}"


def sequence_conditions(kind: str, config: SequenceConfig, model_id: int) -> Conditions:
    """One camera, sensor and LIDAR for a whole sequence: the paper's, or at docking range
    one drawn from the docking world."""
    world = DOCKING if kind == "docking" else PAPER
    rng = np.random.default_rng([config.seed, model_id, TRAJECTORIES.index(kind), 4])
    return draw_conditions(world, rng, config.size)


def render_sequence(
    model: SpacecraftModel, model_id: int, kind: str, config: SequenceConfig, split: str
):
    """The samples (``Sample``) of one sequence, in order."""
    index = TRAJECTORIES.index(kind)
    conditions = sequence_conditions(kind, config, model_id)
    scenes = trajectory(
        kind,
        config,
        np.random.default_rng([config.seed, model_id, index, 0]),
        conditions.intrinsics,
        model.radius_m,
    )
    for frame, scene in enumerate(scenes):
        sample = render_scene(
            model, scene, conditions, (config.seed, model_id, 1000 + index, frame)
        )
        R, t = model.file_frame_pose(scene.rotation, scene.translation)
        sid = sequence_id(model_id, kind, frame)
        sample.meta = {
            "id": sid,
            "file": f"samples/{sid}.npz",
            "model": model_id,
            **sample.meta,
            "split": split,
            "sequence": f"m{model_id:04d}_{kind}",
            "trajectory": kind,
            "frame": frame,
            "time_s": round(frame / config.rate_hz, 6),
            "pose": {"R": np.round(R, 9).tolist(), "t": np.round(t, 6).tolist()},
        }
        yield sample


def write_sequences(
    models: dict[int, tuple[SpacecraftModel, str]],
    config: SequenceConfig,
    out: Path,
    command: str,
    progress: bool = True,
) -> Path:
    """Render every trajectory of every model (id -> (model, split)) into ``out``; frames
    already there are kept (an interrupted run resumes). Returns the manifest's path."""
    out = Path(out)
    (out / "samples").mkdir(parents=True, exist_ok=True)
    info = {
        "format_version": FORMAT_VERSION,
        "generator": f"sdcnet {__version__}",
        "command": command,
        "kind": "sequences",
        "sequence": asdict(config),
        "camera": asdict(PAPER_CAMERA),
        "intrinsics": config.intrinsics.as_dict(),
        "lidar": asdict(PAPER_LIDAR),
        "models": {
            str(m): {"name": model.name, "split": split} for m, (model, split) in models.items()
        },
    }
    text = json.dumps(info, indent=1, sort_keys=True) + "\n"
    info_path = out / "dataset.json"
    if info_path.exists() and info_path.read_text() != text:
        raise ValueError(f"{out} holds sequences made with other settings; use another --out")
    info_path.write_text(text)
    files = []
    total = len(models) * len(config.trajectories) * config.frames
    bar = tqdm(total=total, desc="frames", unit="frame", disable=not progress)
    for model_id, (model, split) in models.items():
        for kind in config.trajectories:
            ids = [sequence_id(model_id, kind, f) for f in range(config.frames)]
            paths = [out / "samples" / f"{sid}.npz" for sid in ids]
            files += paths
            if all(is_complete(p) for p in paths):
                bar.update(len(paths))
                continue
            for sample, path in zip(
                render_sequence(model, model_id, kind, config, split), paths, strict=True
            ):
                write_sample(path, sample)
                bar.update()
    bar.close()
    manifest = out / "manifest.jsonl"
    lines = [json.dumps(read_meta(f), sort_keys=True) for f in files]
    manifest.write_text("\n".join(lines) + "\n")
    return manifest
