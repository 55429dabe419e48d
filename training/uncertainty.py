"""Calibrating the depth's uncertainty on frames not trained on (``sdc-train calibrate``).

The scale head is trained to the Laplace negative log-likelihood; whether |error| <= sigma for
68 % of pixels on frames of spacecraft it never saw is a measurement, not a given. This module
measures the ratio |error| / sigma on the true-positive pixels of a split and scales the
model's sigma (``sigma_per_scale`` and the depth-edge term's ``sigma_edge_weight`` alike) so that
its 68th percentile is 1.

The pipeline then anchors the depth to the returns and rescales sigma frame by frame by the
network's error there (``sdcnet.anchoring.anchored_sigma``), which cancels a factor common to
both parts: what the scaling changes in the answers is the ratio of the two (and sigma on frames
without a return on the mask). So the command measures the scaled model again through the
pipeline and reports that too (``within_1_served``, ``within_2_served``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.scoring import network, torch_model_fn
from sdcnet.training.checkpoint import load_checkpoint, save_checkpoint
from sdcnet.training.model.sdcnet import SDCNet

#: Share of pixels a calibrated sigma covers (one sigma of a Gaussian).
TARGET_COVERAGE = 0.68
#: Pixels drawn per frame, so that large frames do not outweigh small ones.
PIXELS_PER_FRAME = 20_000


def error_ratios(
    model: SDCNet, store: SampleStore, records: list[dict], seed: int = 0
) -> np.ndarray:
    """|error| / sigma on up to ``PIXELS_PER_FRAME`` true-positive pixels of each frame."""
    method = network(torch_model_fn(model), model.config.stride)
    rng = np.random.default_rng(seed)
    ratios = []
    for record in tqdm(records, desc="calibrate", unit="img", leave=False):
        sample = store.load(record)
        depth, mask, sigma = method(sample)[:3]
        region = np.flatnonzero(mask & (sample.depth > 0))
        if region.size > PIXELS_PER_FRAME:
            region = rng.choice(region, PIXELS_PER_FRAME, replace=False)
        error = np.abs(depth.ravel()[region] - sample.depth.ravel()[region])
        ratios.append(error / np.maximum(sigma.ravel()[region], 1e-9))
    return np.concatenate(ratios) if ratios else np.empty(0)


def with_sigma(model: SDCNet, per_scale: float, edge_weight: float) -> SDCNet:
    """A copy of ``model`` (eval mode) whose sigma has these two coefficients."""
    config = replace(model.config, sigma_per_scale=per_scale, sigma_edge_weight=edge_weight)
    copy = SDCNet(config)
    copy.load_state_dict(model.state_dict())
    return copy.eval()


def calibrated(model: SDCNet, ratios: np.ndarray) -> tuple[SDCNet, dict[str, float]]:
    """``model`` with its sigma scaled so that |error| <= sigma on ``TARGET_COVERAGE`` of the
    measured pixels; and the coverage at 1 and 2 sigma before and after."""
    if ratios.size == 0:
        raise ValueError("no true-positive pixel to calibrate on")
    factor = float(np.quantile(ratios, TARGET_COVERAGE))
    config = model.config
    fixed = with_sigma(model, config.sigma_per_scale * factor, config.sigma_edge_weight * factor)
    report = {
        "factor": factor,
        "sigma_per_scale": fixed.config.sigma_per_scale,
        "sigma_edge_weight": fixed.config.sigma_edge_weight,
        "within_1_before": float(np.mean(ratios <= 1)),
        "within_2_before": float(np.mean(ratios <= 2)),
        "within_1_after": float(np.mean(ratios <= factor)),
        "within_2_after": float(np.mean(ratios <= 2 * factor)),
        "pixels": int(ratios.size),
    }
    return fixed, report


def calibrate_checkpoint(
    checkpoint: str,
    data: str,
    out: str,
    split: str = "val",
    limit: int | None = 90,
    edge_weight: float = 0.5,
) -> str:
    """Write to ``out`` the checkpoint with its sigma calibrated on ``limit`` frames (evenly
    spread) of ``split`` of the dataset at ``data``, after setting the depth-edge term to
    ``edge_weight`` (per metre of local depth spread; 0: the scale head alone). The report
    goes into the checkpoint; returns it in one line."""
    model, state = load_checkpoint(checkpoint)
    model = with_sigma(model, model.config.sigma_per_scale, edge_weight)
    store = SampleStore(data)
    records = store.split(split, limit)
    if not records:
        raise ValueError(f"split {split!r} is empty in {data}")
    fixed, report = calibrated(model, error_ratios(model, store, records))
    # What is served: the pipeline's anchoring rescales sigma frame by frame by the returns'
    # residuals, which cancels much of a common factor (docs/development.md, "Measurements").
    served = error_ratios(fixed, store, records)
    report |= {
        "within_1_served": float(np.mean(served <= 1)),
        "within_2_served": float(np.mean(served <= 2)),
    }
    keep = {k: v for k, v in state.items() if k not in ("model", "model_config")}
    keep["sigma_calibration"] = {**report, "data": data, "split": split, "frames": len(records)}
    save_checkpoint(Path(out), fixed, **keep)
    return (
        f"sigma x {report['factor']:.3f} (sigma_per_scale {report['sigma_per_scale']:.3f}, "
        f"sigma_edge_weight {report['sigma_edge_weight']:.3f}): "
        f"within 1 / 2 sigma {100 * report['within_1_before']:.1f} / "
        f"{100 * report['within_2_before']:.1f} % -> {100 * report['within_1_after']:.1f} / "
        f"{100 * report['within_2_after']:.1f} % on {report['pixels']} px of {len(records)} "
        f"{split} frames; measured again through the pipeline, whose anchoring rescales sigma "
        f"per frame: {100 * report['within_1_served']:.1f} / "
        f"{100 * report['within_2_served']:.1f} %; wrote {out}"
    )
