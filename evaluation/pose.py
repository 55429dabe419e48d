"""``sdc-eval pose``: pose of known targets from scratch on single frames and tracked over
sequences, from the completed cloud, the classical fill's and the raw returns
(``pose_eval``); the report (``pose_report``) and the worst real frames from scratch in
pictures."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from sdcnet.camera import Intrinsics
from sdcnet.dataset_format import Sample, SampleStore
from sdcnet.evaluation import pose_eval, pose_report
from sdcnet.evaluation.pose_eval import RAW, FrameResult, truth_of
from sdcnet.evaluation.scoring import FILL, Method, classical, network
from sdcnet.meshes import read_mesh_folder
from sdcnet.pointcloud import back_project
from sdcnet.registration import estimate_pose
from sdcnet.rigid import pose_errors
from sdcnet.targets import Target, load_target
from sdcnet.training.data.generate import GenerateConfig, build_spacecraft, make_sample
from sdcnet.training.data.spacecraft import SpacecraftModel
from sdcnet.visualize import (
    colorize_depth,
    dilated_returns,
    draw_points,
    gray_bgr,
    labelled,
    montage,
    object_crop,
)

#: The clouds registered beside the raw returns.
CLOUDS = ("completed", FILL)


@dataclass(frozen=True)
class PoseRun:
    """What ``sdc-eval pose`` evaluates (its flags, same names)."""

    onnx: str = "models/sdcnet.onnx"  # the model that completes
    threads: int = 2  # onnxruntime's
    meshes: str = "../shared/real-meshes"  # the real meshes (manifest.json)
    dataset: str = "data/paper"  # whose split's procedural models to use
    split: str = "test"
    limit: int = 18  # models of the split, evenly spread
    views: int = 4  # single frames per model
    seed: int = 0  # of the real meshes' frames and the perturbed inits
    clouds: tuple[str, ...] = CLOUDS
    perturbed: bool = True  # also single frames tracked from perturbed true poses
    sequences: tuple[str, ...] = field(default=())  # folders made by `sdc-data sequence`
    suite: tuple[str, ...] = field(default=())  # conditions of the robustness suite (folders)
    gallery: int = 5  # worst real frames per cloud in failures*.png (0: no pictures)
    redraw: bool = False  # only the pictures, from out/pose_eval.json
    out: str = "docs/pose"


RealModels = dict[int, tuple[SpacecraftModel, Target]]


def run_pose(run: PoseRun) -> None:
    """Pose from scratch on single frames and tracked over sequences; writes
    ``out/pose_eval.md`` and ``.json`` (unless ``redraw``), then the worst real frames from
    scratch in ``failures.png`` (the first cloud) and ``failures_raw.png``."""
    methods: dict[str, Method] = {}
    if "completed" in run.clouds:
        from sdcnet.runtime.onnx import OnnxModel

        onnx = OnnxModel(run.onnx, threads=run.threads)
        methods["completed"] = network(onnx.run, onnx.stride, onnx.info.work_pixels)
    if FILL in run.clouds:
        methods[FILL] = classical
    entries = read_mesh_folder(run.meshes)
    real_config = GenerateConfig(models=0, views=run.views, seed=run.seed, meshes=entries)
    real = {
        k: (build_spacecraft(real_config, k), load_target(entry)) for k, entry in enumerate(entries)
    }
    stores = {Path(path).name: SampleStore(path) for path in run.sequences}
    out = Path(run.out)
    if run.redraw:
        results = pose_report.read_report(out / "pose_eval.json")
    else:
        results = pose_results(run, methods, real_config, real, stores)
        text, data = pose_report.report(results, [*methods, RAW])
        out.mkdir(parents=True, exist_ok=True)
        (out / "pose_eval.md").write_text(text + "\n")
        (out / "pose_eval.json").write_text(json.dumps(data, indent=1))
        print(text)
    if run.gallery and methods:
        failure_pictures(results, methods, real_config, real, stores, run.gallery, out)


def pose_results(
    run: PoseRun,
    methods: dict[str, Method],
    real_config: GenerateConfig,
    real: RealModels,
    stores: dict[str, SampleStore],
) -> dict[str, list[FrameResult]]:
    """Name of each evaluation -> its frame results."""
    ids = set(pose_eval.split_ids(run.dataset, run.split, run.limit))
    ids |= {r["model"] for store in stores.values() for r in store.records if r["model"] < 1000}
    test_config, procedural = pose_eval.procedural_models(run.dataset, sorted(ids))
    single_ids = pose_eval.split_ids(run.dataset, run.split, run.limit)
    targets = {t.name: t for _, t in [*real.values(), *procedural.values()]}
    real_frames = list(pose_eval.single_frames(real_config, real, run.views, "real"))
    test_frames = list(
        pose_eval.single_frames(
            test_config, {m: procedural[m] for m in single_ids}, run.views, run.split
        )
    )
    results = {
        f"Real spacecraft, single frames from scratch ({run.views} views each)": (
            pose_eval.evaluate_frames(real_frames, methods)
        ),
        f"Test split ({len(single_ids)} models), single frames from scratch "
        f"({run.views} views each)": pose_eval.evaluate_frames(test_frames, methods),
    }
    if run.perturbed:
        results[f"Real spacecraft, tracked from perturbed true poses ({run.views} views each)"] = (
            pose_eval.evaluate_perturbed(real_frames, methods, run.seed)
        )
        results[
            f"Test split ({len(single_ids)} models), tracked from perturbed true poses "
            f"({run.views} views each)"
        ] = pose_eval.evaluate_perturbed(test_frames, methods, run.seed)
    for name, store in stores.items():
        count = len({r["model_name"] for r in store.records})
        results[f"Sequences {name} ({count} spacecraft), tracked at 10 Hz"] = (
            pose_eval.evaluate_sequences(store, targets, methods)
        )
    for folder in run.suite:
        condition = Path(folder).name
        frames = tqdm(pose_eval.suite_frames(folder, real), desc=condition, unit="frame")
        results[f"Robustness suite, {condition}: single frames from scratch"] = [
            replace(r, condition=condition) for r in pose_eval.evaluate_frames(frames, methods)
        ]
    return results


def failure_pictures(
    results: dict[str, list[FrameResult]],
    methods: dict[str, Method],
    real_config: GenerateConfig,
    real: RealModels,
    stores: dict[str, SampleStore],
    count: int,
    out: Path,
) -> None:
    """The ``count`` worst real frames from scratch (single frames and the sequences' first
    frames), re-rendered or reloaded: of the first method's cloud (whose depth is drawn beside
    the returns) in ``failures.png``, of the raw returns in ``failures_raw.png``."""
    real_names = {target.name for _, target in real.values()}
    scratch = [
        r
        for frames in results.values()
        for r in frames
        if r.mode == "scratch" and r.spacecraft in real_names and not r.condition
    ]

    def load(result: FrameResult) -> tuple[Target, Sample]:
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

    first = next(iter(methods))
    for cloud, name in ((first, "failures.png"), (RAW, "failures_raw.png")):
        picks = [(r, *load(r)) for r in pick_failures(scratch, cloud, count)]
        rows = gallery_rows(picks, methods[first], cloud)
        cv2.imwrite(str(out / name), montage(rows, tile=256))
        print(out / name)


def gallery_rows(
    picks: list[tuple[FrameResult, Target, Sample]], method: Method, cloud: str
) -> list[list[np.ndarray]]:
    """One row per pick: gray | LIDAR returns | completed depth | the target drawn at the
    pose estimated from ``cloud`` ("completed" by ``method``, or the raw returns) | ... at the
    true pose; zoomed on the spacecraft."""
    rows = []
    for result, target, sample in picks:
        K = Intrinsics(**sample.meta["intrinsics"])
        depth, mask = method(sample)[:2]
        returns = back_project(sample.sparse, sample.sparse > 0, K)
        points = back_project(depth, mask, K) if cloud != RAW else returns
        estimate = estimate_pose(target.model, points, returns, view=K)
        window = object_crop(sample.mask | mask)
        scale = max(1, round((window[0].stop - window[0].start) / 256 / 2))
        base = gray_bgr(sample.gray)
        drawn = target.model.render_points
        rotation_deg, translation_m = pose_errors(estimate.pose, truth_of(sample))
        flag = ", ambiguous" if estimate.ambiguous else ""
        rows.append(
            [
                labelled(base[window], f"{target.name} {result.range_m:.0f} m"),
                labelled(
                    dilated_returns(sample.sparse, 4)[window], f"{sample.meta['returns']} returns"
                ),
                labelled(colorize_depth(depth)[window], "completed depth"),
                labelled(
                    draw_points(base, estimate.pose.apply(drawn), K, radius=scale)[window],
                    f"{cloud}: {rotation_deg:.1f} deg, {translation_m:.2f} m{flag}",
                ),
                labelled(
                    draw_points(base, truth_of(sample).apply(drawn), K, radius=scale)[window],
                    "truth",
                ),
            ]
        )
    return rows


def pick_failures(results: list[FrameResult], cloud: str, count: int) -> list[FrameResult]:
    """The ``count`` worst frames of ``cloud`` by rotation error, then its best frame at the
    longest range for contrast."""
    own = [r for r in results if r.cloud == cloud and np.isfinite(r.rotation_deg)]
    worst = sorted(own, key=lambda r: -r.rotation_deg)[:count]
    good = [r for r in own if r.success and r not in worst]
    return worst + sorted(good, key=lambda r: -r.range_m)[:1]
