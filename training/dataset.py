"""PyTorch view of a generated dataset: tiles around the spacecraft, with augmentation.

Training tiles are ``tile`` x ``tile`` windows at full resolution placed on the spacecraft's
region (the same LIDAR-bounded region the service crops to): inside it when the region is
larger, around it when smaller (paper: random crop to 512 x 512). Augmentation: horizontal and
vertical flips, brightness, contrast and gamma jitter of the gray image.
"""

from __future__ import annotations

import numpy as np
import torch
from torch.utils.data import Dataset

from sdcnet.dataset_format import SampleStore
from sdcnet.pipeline import Region, normalise_gray, region_of_interest


def training_window(
    region: Region, height: int, width: int, tile: int, rng: np.random.Generator
) -> Region:
    """A tile x tile window on ``region``, inside a height x width frame (tile <= frame)."""

    def start(lo: int, hi: int, size: int) -> int:
        a, b = (lo, hi - tile) if hi - lo >= tile else (hi - tile, lo)
        return int(np.clip(rng.integers(a, b + 1), 0, size - tile))

    y0, x0 = start(region.y0, region.y1, height), start(region.x0, region.x1, width)
    return Region(y0, y0 + tile, x0, x0 + tile)


def jitter_gray(gray: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Brightness, contrast and gamma jitter of a [0, 1] image (the sky stays near black)."""
    gamma = rng.uniform(0.8, 1.25)
    contrast = rng.uniform(0.7, 1.3)
    brightness = rng.uniform(-0.02, 0.02)
    return np.clip(contrast * gray**gamma + brightness, 0, 1).astype(np.float32)


class TileDataset(Dataset):
    """Items: dict of float32 tensors gray (1, T, T) in [0, 1], sparse and depth (1, T, T) in m.

    With ``tile=None`` an item is the whole spacecraft region (variable size, batch 1).
    """

    def __init__(
        self,
        store: SampleStore,
        records: list[dict],
        *,
        stride: int,
        tile: int | None = 512,
        augment: bool = False,
        seed: int = 0,
    ):
        self.store, self.records = store, records
        self.tile, self.augment, self.seed, self.stride = tile, augment, seed, stride
        self.epoch = 0  # set by the trainer: new windows and jitter every epoch, reproducibly

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        sample = self.store.load(self.records[index])
        rng = np.random.default_rng([self.seed, self.epoch, index])
        region = region_of_interest(sample.sparse, self.stride)
        if self.tile is not None:
            H, W = sample.gray.shape
            region = training_window(region, H, W, min(self.tile, H, W), rng)
        rows, cols = region.slices
        gray = normalise_gray(sample.gray[rows, cols])
        sparse, depth = sample.sparse[rows, cols], sample.depth[rows, cols]
        if self.augment:
            gray = jitter_gray(gray, rng)
            if rng.random() < 0.5:
                gray, sparse, depth = gray[:, ::-1], sparse[:, ::-1], depth[:, ::-1]
            if rng.random() < 0.5:
                gray, sparse, depth = gray[::-1], sparse[::-1], depth[::-1]
        return {
            name: torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))[None]
            for name, a in (("gray", gray), ("sparse", sparse), ("depth", depth))
        }
