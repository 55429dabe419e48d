"""Morphological pre-fill of the sparse LIDAR map (paper sec. III-B), inside the network.

IP-Basic-like: depth is inverted so that near surfaces win every max, then dilated, closed,
holes filled by a larger dilation and smoothed over valid pixels. Built from max/avg pooling so
training, the exported ONNX graph and the classical baseline share one implementation.
Kernel sizes are in pixels of the working resolution, where returns are ~3 x 4.5 px apart.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

INVERT_M = 1000.0  # depths are inverted as INVERT_M - d: valid depths stay positive


def _dilate(x: torch.Tensor, k: int) -> torch.Tensor:
    return F.max_pool2d(x, k, stride=1, padding=k // 2)


def _erode(x: torch.Tensor, k: int) -> torch.Tensor:
    return -F.max_pool2d(-x, k, stride=1, padding=k // 2)


def near_wins_downsample(depth: torch.Tensor, factor: int) -> torch.Tensor:
    """Downsample a sparse depth map (B, 1, H, W) metres by ``factor``, keeping the nearest return
    of each block. H and W must be multiples of ``factor``."""
    inverted = torch.where(depth > 0, INVERT_M - depth, torch.zeros_like(depth))
    pooled = F.max_pool2d(inverted, factor)
    return torch.where(pooled > 0, INVERT_M - pooled, torch.zeros_like(pooled))


class MorphologicalPrefill(nn.Module):
    """Sparse depth (B, 1, h, w) metres -> coarse dense depth (B, 1, h, w) metres, 0 = unfilled."""

    def __init__(self, dilate: int = 5, close: int = 5, fill: int = 9, blur: int = 3):
        super().__init__()
        self.dilate, self.close, self.fill, self.blur = dilate, close, fill, blur

    def forward(self, sparse: torch.Tensor) -> torch.Tensor:
        x = torch.where(sparse > 0, INVERT_M - sparse, torch.zeros_like(sparse))
        x = _dilate(x, self.dilate)
        x = _erode(_dilate(x, self.close), self.close)
        x = torch.where(x > 0, x, _dilate(x, self.fill))
        valid = (x > 0).to(x.dtype)
        total = F.avg_pool2d(
            x, self.blur, stride=1, padding=self.blur // 2, count_include_pad=False
        )
        count = F.avg_pool2d(
            valid, self.blur, stride=1, padding=self.blur // 2, count_include_pad=False
        )
        smooth = total / count.clamp_min(1e-6)
        return torch.where(valid > 0, INVERT_M - smooth, torch.zeros_like(x))
