"""Two-stage training of SDCNet (paper sec. V-A), on one CPU, one GPU or many (torchrun).

Stage 1 trains FSNet with BCE; stage 2 freezes it and trains the
rest with L1 on the predicted foreground. Adam, lr 1e-3, weight decay 1e-3, cosine decay per
stage. Every epoch: validation on the val split with all six metrics, a CSV log line, a
learning-curve plot, ``last.pt`` (to resume) and ``best.pt`` (best val MATE; stage 1: IOU).
"""

from __future__ import annotations

import csv
import json
import os
import platform
import time
from dataclasses import asdict, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import torch
from torch import distributed as dist
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import DataLoader, DistributedSampler, Subset
from tqdm import tqdm

from sdcnet.dataset_format import SampleStore, evenly_spread
from sdcnet.evaluation.scoring import (
    evaluate_records,
    mask_metrics_only,
    network,
    torch_model_fn,
    torch_segmentation_fn,
)
from sdcnet.metrics import NAMES
from sdcnet.training.checkpoint import (
    PROVENANCE,
    load_weights,
    read_checkpoint,
    save_checkpoint,
    transplant_weights,
)
from sdcnet.training.dataset import TileDataset
from sdcnet.training.losses import (
    dense_depth_loss,
    depth_gradient_loss,
    foreground_depth_loss,
    laplace_nll,
    segmentation_loss,
    soft_iou_loss,
)
from sdcnet.training.model.sdcnet import ModelConfig, SDCNet, build_model
from sdcnet.training.train_config import TrainConfig


class Segmenter(torch.nn.Module):
    """SDCNet's segmentation path as a module of its own, so DistributedDataParallel
    synchronises stage 1's gradients through its forward."""

    def __init__(self, model: SDCNet):
        super().__init__()
        self.model = model

    def forward(
        self, gray: torch.Tensor, sparse: torch.Tensor, focal_px: torch.Tensor
    ) -> torch.Tensor:
        return self.model.segment(gray, sparse, focal_px)


PRESETS: dict[str, dict] = {
    # The paper's recipe (sec. V-A), for a GPU.
    "paper": {"fsnet_epochs": 30, "epochs": 50, "batch_size": 8, "tile": 512},
    # About an hour on two CPU cores: fewer, smaller tiles centred on the spacecraft.
    "cpu": {
        "fsnet_epochs": 8,
        "epochs": 16,
        "batch_size": 8,
        "tile": 320,
        "samples_per_epoch": 1600,
        "val_samples": 90,
        "workers": 1,
    },
    # Seconds: for tests and smoke runs.
    "smoke": {
        "fsnet_epochs": 1,
        "epochs": 1,
        "batch_size": 2,
        "tile": 128,
        "samples_per_epoch": 4,
        "val_samples": 2,
        "workers": 0,
    },
}


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo (or the platform's description)."""
    cpuinfo = Path("/proc/cpuinfo")
    lines = cpuinfo.read_text().splitlines() if cpuinfo.exists() else []
    names = [line.split(":", 1)[1].strip() for line in lines if line.startswith("model name")]
    return names[0] if names else platform.processor() or "unknown CPU"


def hardware_description(device: torch.device, world: int) -> str:
    """What trained the model, for the model card."""
    if device.type == "cuda":
        what = torch.cuda.get_device_name(device)
    else:
        what = f"{cpu_name()}, {torch.get_num_threads()} threads"
    return f"{world} x {what}, torch {torch.__version__}"


def config_from_preset(preset: str, **overrides) -> TrainConfig:
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(PRESETS)}")
    return TrainConfig(
        **{**PRESETS[preset], **{k: v for k, v in overrides.items() if v is not None}}
    )


def _distributed() -> tuple[int, int, torch.device]:
    """(rank, world size, device); initialises torch.distributed under torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    cuda = torch.cuda.is_available()
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    rank = dist.get_rank() if world > 1 else 0
    local = int(os.environ.get("LOCAL_RANK", "0"))
    device = torch.device(f"cuda:{local}") if cuda else torch.device("cpu")
    if cuda:
        torch.cuda.set_device(device)
    return rank, world, device


#: What a checkpoint records of the dataset it was trained on: ``dataset.json``'s keys
#: (``merged_from``: the sources of an ``sdc-data merge``).
DATASET_KEYS = (
    "command",
    "seed",
    "models",
    "views",
    "size",
    "split_models",
    "world",
    "merged_from",
)


class Trainer:
    def __init__(self, config: TrainConfig):
        self.config = config
        self.rank, self.world, self.device = _distributed()
        self.out = Path(config.out)
        self.out.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(config.seed)
        self.store = SampleStore(config.data)
        train = self.store.split("train")
        if not train:
            raise ValueError(f"{config.data} has no 'train' samples")
        if config.train_samples:
            train = evenly_spread(train, config.train_samples)
        self.val_records = self.store.split("val") or train[:2]
        if config.val_samples:
            self.val_records = evenly_spread(self.val_records, config.val_samples)
        # the frames this run used: fewer than models x views where the dataset was closed
        # before its end (`sdc-data close`) or subsampled (--train-samples, --val-samples)
        self.frames = {"train": len(train), "val": len(self.val_records)}
        self.model = build_model(
            config.variant,
            fsnet_inputs=config.fsnet_inputs,
            fsnet_growth=config.fsnet_growth,
            fsnet_context=config.fsnet_context,
        ).to(self.device)
        self.train_set = TileDataset(
            self.store,
            train,
            tile=config.tile,
            augment=True,
            whole_target_share=config.whole_target_share,
            field_cut_share=config.field_cut_share,
            seed=config.seed,
            stride=self.model.config.stride,
        )
        self.state = {"stage": 1 if self.model.fsnet is not None else 2, "epoch": 0, "best": None}
        self.history: list[dict] = []

    # --- bookkeeping ---------------------------------------------------------------------

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def _provenance(self) -> dict:
        """What made this checkpoint; for a fine-tuned one also what made the model it started
        from (``parent``, recursively), so the model card can tell the whole training."""
        provenance = {
            "hardware": hardware_description(self.device, self.world),
            "train_config": asdict(self.config),
            "dataset": {
                k: self.store.info.get(k, "paper" if k == "world" else None) for k in DATASET_KEYS
            }
            | {"frames": self.frames},
        }
        if self.config.init_weights:
            state = self._init_checkpoint
            provenance["parent"] = {k: state[k] for k in PROVENANCE if k in state}
        if self.config.init_segmentation and self.model.fsnet is not None:
            state = self._segmentation_checkpoint
            provenance["segmentation_parent"] = {k: state[k] for k in PROVENANCE if k in state}
        if self.config.warm_start:
            state = self._warm_checkpoint
            provenance["warm_start_parent"] = {k: state[k] for k in PROVENANCE if k in state}
        return provenance

    def _save(self, name: str, optimizer, scheduler) -> None:
        if self.is_main:
            save_checkpoint(
                self.out / name,
                self.model,
                state=self.state,
                history=self.history,
                optimizer=optimizer.state_dict(),
                scheduler=scheduler.state_dict(),
                **self._provenance(),
            )

    def _log(self, row: dict) -> None:
        self.history.append(row)
        if not self.is_main:
            return
        path = self.out / "log.csv"
        new = not path.exists()
        with path.open("a", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(row))
            if new:
                writer.writeheader()
            writer.writerow(row)
        from sdcnet.training.plots import learning_curves

        learning_curves(self.history, self.out / "learning_curves.png")

    # --- the two stages ------------------------------------------------------------------

    def _stage_setup(self, stage: int):
        seg = set(map(id, self.model.segmentation_parameters()))
        for p in self.model.parameters():
            p.requires_grad = (id(p) in seg) == (stage == 1)
        params = [p for p in self.model.parameters() if p.requires_grad]
        epochs = self.config.fsnet_epochs if stage == 1 else self.config.epochs
        optimizer = torch.optim.Adam(
            params, lr=self.config.lr, weight_decay=self.config.weight_decay
        )
        scheduler = torch.optim.lr_scheduler.CosineAnnealingLR(
            optimizer, max(epochs, 1), eta_min=self.config.lr / 100
        )
        return optimizer, scheduler, epochs

    def _loader(self, epoch: int) -> DataLoader:
        self.train_set.epoch = epoch
        n = len(self.train_set)
        dataset = self.train_set
        if self.config.samples_per_epoch and self.config.samples_per_epoch < n:
            rng = np.random.default_rng([self.config.seed, epoch])
            dataset = Subset(
                self.train_set, rng.choice(n, self.config.samples_per_epoch, replace=False).tolist()
            )
        sampler = DistributedSampler(dataset, seed=self.config.seed) if self.world > 1 else None
        if sampler is not None:
            sampler.set_epoch(epoch)
        generator = torch.Generator().manual_seed(self.config.seed * 1000 + epoch)
        return DataLoader(
            dataset,
            self.config.batch_size,
            shuffle=sampler is None,
            sampler=sampler,
            num_workers=self.config.workers,
            drop_last=len(dataset) > self.config.batch_size,
            generator=generator,
            persistent_workers=False,
        )

    def _loss(self, stage: int, batch: dict[str, torch.Tensor], net) -> torch.Tensor:
        inputs = (batch["gray"], batch["sparse"], batch["focal_px"])
        if stage == 1:  # net is a Segmenter
            prob = net(*inputs)
            loss = segmentation_loss(prob, batch["depth"])
            if self.config.iou_loss:
                per_tile = self.config.iou_over == "tile"
                loss = loss + self.config.iou_loss * soft_iou_loss(prob, batch["depth"], per_tile)
            return loss
        depth, prob, sigma = net(*inputs)
        if self.model.fsnet is None:
            return dense_depth_loss(depth, batch["depth"])
        unit = self.model.residual_unit(batch["sparse"], batch["focal_px"])
        loss = foreground_depth_loss(depth, prob, batch["depth"], unit)
        if self.config.gradient_loss:
            loss = loss + self.config.gradient_loss * depth_gradient_loss(
                depth, prob, batch["depth"], unit
            )
        if self.config.sigma_loss:
            scale = sigma / self.model.config.sigma_per_scale
            nll = laplace_nll(depth.detach(), scale, prob, batch["depth"], unit)
            loss = loss + self.config.sigma_loss * nll
        return loss

    def _train_epoch(self, stage: int, epoch: int, optimizer, net) -> float:
        self.model.train()
        if stage == 2 and self.model.fsnet is not None:  # frozen: keep its batch-norm statistics
            self.model.fsnet.eval()
        losses = []
        bar = tqdm(
            self._loader(epoch),
            desc=f"stage {stage} epoch {epoch + 1}",
            unit="batch",
            disable=not self.is_main,
            leave=False,
        )
        for batch in bar:
            batch = {k: v.to(self.device, non_blocking=True) for k, v in batch.items()}
            loss = self._loss(stage, batch, net)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
            bar.set_postfix(loss=f"{np.mean(losses[-20:]):.4f}")
        return float(np.mean(losses)) if losses else float("nan")

    def validate(self, stage: int) -> dict[str, float]:
        """The metrics on the val records. Stage 1 trains the mask alone and keeps its best
        epoch by IOU, so it validates the mask alone (IOU, IOI, specks; the rest NaN), at
        FSNet's cost and without the depth reports."""
        mask_only = stage == 1
        fn = torch_segmentation_fn if mask_only else torch_model_fn
        table = evaluate_records(
            network(fn(self.model, self.device), self.model.config.stride),
            self.store,
            self.val_records,
            progress=self.is_main,
            desc="validate",
            mask_only=mask_only,
        )
        return mask_metrics_only(table.mean()) if mask_only else table.mean()

    def _resume(self) -> tuple[dict | None, dict | None]:
        path = self.out / "last.pt"
        if not path.exists():
            return None, None
        state = read_checkpoint(path, self.device)
        if not {"state", "history", "optimizer", "scheduler"} <= set(state):
            raise ValueError(f"{path} is not a run's last.pt (no trainer state): use --restart")
        load_weights(self.model, state["model"], path)
        self.state, self.history = state["state"], state["history"]
        return state["optimizer"], state["scheduler"]

    @cached_property
    def _segmentation_checkpoint(self) -> dict:
        """The checkpoint whose FSNet stage 2 starts from (any depth design), read once for its
        weights and its provenance."""
        return read_checkpoint(self.config.init_segmentation, self.device)

    def _init_segmentation(self) -> None:
        path = self.config.init_segmentation
        theirs = self._segmentation_checkpoint["model"]
        own = self.model.state_dict()
        seg = {k: v for k, v in theirs.items() if k.startswith(("fsnet.", "refiner.")) and k in own}
        if not seg:
            raise ValueError(f"{path} holds no FSNet weights to reuse (--init-segmentation)")
        load_weights(self.model, {**own, **seg}, path)
        self.state["stage"] = 2

    @cached_property
    def _init_checkpoint(self) -> dict:
        """The checkpoint fine-tuning starts from (same variant, else a clear error), read once
        for its weights and its provenance."""
        state = read_checkpoint(self.config.init_weights, self.device)
        differences = self.model.config.architecture_differences(
            ModelConfig.from_dict(state["model_config"])
        )
        if differences:
            listed = ", ".join(
                f"{k} {theirs} (this run: {ours})" for k, (ours, theirs) in differences.items()
            )
            raise ValueError(
                f"{self.config.init_weights} holds another architecture ({listed}); "
                "--init-weights needs the same variant and flags (e.g. --fsnet-growth)"
            )
        return state

    @cached_property
    def _warm_checkpoint(self) -> dict:
        """The checkpoint of another design the run starts from (``--warm-start``)."""
        return read_checkpoint(self.config.warm_start, self.device, check_config=False)

    def _warm_start(self) -> None:
        """Start from every weight of another design that fits (``transplant_weights``)."""
        report = transplant_weights(self.model, self._warm_checkpoint["model"])
        if not report["copied"]:
            raise ValueError(f"{self.config.warm_start}: no weight fits this architecture")
        depth_weights = [n for n in self.model.state_dict() if n.startswith("fdcnet.")]
        if set(depth_weights) <= set(report["copied"]):
            # the depth networks are the source's whole, so is their sigma's calibration
            theirs, ours = self._warm_checkpoint["model_config"], self.model.config
            self.model.config = replace(
                ours,
                sigma_per_scale=theirs.get("sigma_per_scale", ours.sigma_per_scale),
                sigma_edge_weight=theirs.get("sigma_edge_weight", ours.sigma_edge_weight),
            )
        if self.is_main:
            print(
                f"warm start from {self.config.warm_start}: {len(report['copied'])} tensors "
                f"copied, {len(report['partial'])} in part ({', '.join(report['partial'])}), "
                f"{len(report['left'])} left as initialised"
            )

    def _init_weights(self) -> None:
        """Start from a whole trained model of the same variant (fine-tuning), its sigma's
        calibration included (the scale the sigma head was trained in)."""
        load_weights(self.model, self._init_checkpoint["model"], self.config.init_weights)
        # the same architecture (``_init_checkpoint`` checked it) with the checkpoint's calibration
        self.model.config = ModelConfig.from_dict(self._init_checkpoint["model_config"])

    def _check_segmentation_is_trained(self) -> None:
        """Stage 2 trains on FSNet's mask: a fresh run must train FSNet or be given one."""
        if self.state["stage"] == 1 and self.config.fsnet_epochs == 0:
            raise ValueError(
                "--fsnet-epochs 0 on a fresh run would leave FSNet untrained for stage 2: "
                "train it (--fsnet-epochs N) or start from trained weights (--init-weights, "
                "--init-segmentation)"
            )

    def fit(self, resume: bool = True) -> Path:
        """Run (or resume) both stages; the best checkpoint: best.pt, or best_stage1.pt when
        stage 2 has no epochs (segmentation-only runs)."""
        optimizer_state, scheduler_state = self._resume() if resume else (None, None)
        if optimizer_state is None and self.config.warm_start:
            self._warm_start()
        if optimizer_state is None and self.config.init_weights:
            self._init_weights()
        if (
            optimizer_state is None
            and self.config.init_segmentation
            and self.model.fsnet is not None
        ):
            self._init_segmentation()
        if optimizer_state is None and not self.config.init_weights:
            self._check_segmentation_is_trained()
        while self.state["stage"] <= 2:
            stage = self.state["stage"]
            optimizer, scheduler, epochs = self._stage_setup(stage)
            if optimizer_state is not None:
                optimizer.load_state_dict(optimizer_state)
                scheduler.load_state_dict(scheduler_state)
                optimizer_state = scheduler_state = None
            net = Segmenter(self.model) if stage == 1 else self.model
            if self.world > 1:
                net = DistributedDataParallel(
                    net, device_ids=[self.device] if self.device.type == "cuda" else None
                )
            while self.state["epoch"] < epochs:
                epoch = self.state["epoch"]
                started = time.perf_counter()
                train_loss = self._train_epoch(stage, epoch, optimizer, net)
                lr = optimizer.param_groups[0]["lr"]
                scheduler.step()
                metrics = self.validate(stage) if self.is_main else {}
                self.state["epoch"] += 1
                row = {
                    "stage": stage,
                    "epoch": epoch + 1,
                    "train_loss": round(train_loss, 5),
                    **{k: round(metrics.get(k, float("nan")), 5) for k in NAMES},
                    "lr": lr,
                    "seconds": round(time.perf_counter() - started, 1),
                }
                self._log(row)
                score = (
                    -metrics.get("IOU", 0.0) if stage == 1 else metrics.get("MATE", float("inf"))
                )
                if self.is_main and (self.state["best"] is None or score < self.state["best"]):
                    self.state["best"] = score
                    self._save("best_stage1.pt" if stage == 1 else "best.pt", optimizer, scheduler)
                self._save("last.pt", optimizer, scheduler)
                if self.world > 1:
                    dist.barrier()
            if stage == 1 and epochs > 0:  # stage 2 starts from the best segmentation
                best = self.out / "best_stage1.pt"
                load_weights(self.model, read_checkpoint(best, self.device)["model"], best)
            self.state = {"stage": stage + 1, "epoch": 0, "best": None}
        if self.is_main:
            (self.out / "train_config.json").write_text(
                json.dumps(asdict(self.config), indent=1) + "\n"
            )
        best = self.out / "best.pt"
        return best if best.exists() else self.out / "best_stage1.pt"
