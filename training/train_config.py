"""The settings of one training run (``TrainConfig``): each field is a flag of ``sdc-train
fit``, made from its metadata; ``sdcnet.training.train`` fills them from a preset."""

from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass, field
from typing import Any

from sdcnet.training.model.sdcnet import VARIANTS


def setting(default: Any, help: str, **flag: Any) -> Any:
    """A ``TrainConfig`` field with its ``sdc-train fit`` flag's ``help`` (and any other
    argparse keyword, such as ``choices``) in its metadata: the flags are made from them."""
    return field(default=default, metadata={"help": help, **flag})


@dataclass
class TrainConfig:
    """One training run. ``preset`` fills the recipe; any field can be overridden (each is a
    flag of ``sdc-train fit``: ``--batch-size`` for ``batch_size``)."""

    data: str = field(metadata={"help": "dataset directory (sdc-data generate)"})
    out: str = field(metadata={"help": "run directory: checkpoints, log.csv, plots"})
    variant: str = setting("sdcnet", "the network (an ablation variant)", choices=sorted(VARIANTS))
    fsnet_inputs: str = setting(
        "both", "what FSNet sees: gray, sparse or both", choices=("both", "gray", "sparse")
    )
    fsnet_growth: int = setting(
        1, "FSNet's widths x this (1: the paper's ~5k parameters; 2: four times as many)"
    )
    fsnet_context: bool = setting(
        False,
        "FSNet's coarse branch: three convolutions at a sixteenth of the working grid that see "
        "most of the crop at once (parts of the spacecraft far from any return)",
    )
    fsnet_epochs: int = setting(
        30, "epochs of stage 1 (FSNet alone); 0 skips it, from --init-weights"
    )
    epochs: int = setting(50, "epochs of stage 2 (depth; FSNet frozen); 0 skips it")
    batch_size: int = setting(8, "tiles per step")
    tile: int = setting(512, "side of a training tile, pixels")
    lr: float = setting(1e-3, "Adam's learning rate at the start of each stage (cosine decay)")
    weight_decay: float = setting(1e-3, "Adam's weight decay")
    gradient_loss: float = setting(
        1.0, "weight of the depth-gradient L1 beside eq. 7's L1 (stage 2)"
    )
    iou_loss: float = setting(0.0, "weight of a soft-IOU term beside eq. 6's BCE (stage 1)")
    iou_over: str = setting(
        "batch",
        "the soft-IOU term over the whole batch, or per tile and averaged (each spacecraft "
        "weighs alike, as in the IOU metric, a mean over frames)",
        choices=("batch", "tile"),
    )
    sigma_loss: float = setting(
        1.0, "weight of the uncertainty's Laplace NLL (stage 2; depth detached)"
    )
    whole_target_share: float = setting(
        0.0,
        "share of training items cropped to hold the whole spacecraft, not only its returns' "
        "region: shows the network the parts no return reached (a LIDAR narrower than the camera)",
    )
    field_cut_share: float = setting(
        0.0,
        "share of training items whose returns are cut off past a random straight line across "
        "them, the truth kept: a LIDAR field that ends across the spacecraft, where the mask "
        "must go on without returns",
    )
    samples_per_epoch: int | None = setting(
        None,
        "training frames drawn per epoch (unset, or more than the train split holds: the whole "
        "train split)",
    )
    train_samples: int | None = setting(None, "train frames used, evenly spread (unset: every one)")
    val_samples: int | None = setting(
        None, "val frames, evenly spread (unset: the whole val split)"
    )
    workers: int = setting(2, "data-loading processes")
    seed: int = setting(0, "random seed")
    init_segmentation: str | None = setting(
        None, "checkpoint whose trained FSNet to reuse: skips stage 1"
    )
    init_weights: str | None = setting(
        None,
        "fine-tune: start from this checkpoint's weights (same variant), e.g. the shipped "
        "model on your own spacecraft; --epochs 0 trains the segmentation alone",
    )
    warm_start: str | None = setting(
        None,
        "start from a checkpoint of an earlier design: every weight whose name and shape "
        "fit, and the shared input channels of layers that gained some",
    )
    command: str = field(
        default_factory=lambda: shlex.join(["sdc-train", *sys.argv[1:]]),
        metadata={"flag": False},  # recorded, not given
    )
