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


def _dilate(x: torch.Tensor, k: tuple[int, int]) -> torch.Tensor:
    return F.max_pool2d(x, k, stride=1, padding=(k[0] // 2, k[1] // 2))


def _erode(x: torch.Tensor, k: tuple[int, int]) -> torch.Tensor:
    return -_dilate(-x, k)


def _close(x: torch.Tensor, k: tuple[int, int]) -> torch.Tensor:
    """Morphological closing: bridges gaps narrower than ``k`` without growing the outline."""
    return _erode(_dilate(x, k), k)


def near_wins_downsample(depth: torch.Tensor, factor: int) -> torch.Tensor:
    """Downsample a sparse depth map (B, 1, H, W) metres by ``factor``, keeping the nearest return
    of each block. H and W must be multiples of ``factor``."""
    inverted = torch.where(depth > 0, INVERT_M - depth, torch.zeros_like(depth))
    pooled = F.max_pool2d(inverted, factor)
    return torch.where(pooled > 0, INVERT_M - pooled, torch.zeros_like(pooled))


class MorphologicalPrefill(nn.Module):
    """Sparse depth (B, 1, h, w) metres -> coarse dense depth (B, 1, h, w) metres, 0 = unfilled.

    Kernels are (rows, columns) at the working resolution: the first dilation matches the beam
    grid (returns ~4.5 rows and ~3 columns apart), closings then bridge what dropouts and
    grazing surfaces left open, and a blur over valid pixels smooths the steps.
    """

    def __init__(self, *, dilate=(5, 3), close=(5, 5), holes=(9, 9), blur: int = 3):
        super().__init__()
        self.dilate, self.close, self.holes, self.blur = (
            tuple(dilate),
            tuple(close),
            tuple(holes),
            blur,
        )

    def forward(self, sparse: torch.Tensor) -> torch.Tensor:
        x = torch.where(sparse > 0, INVERT_M - sparse, torch.zeros_like(sparse))
        x = _dilate(x, self.dilate)
        x = _close(_close(x, self.close), self.holes)
        valid = (x > 0).to(x.dtype)
        total = F.avg_pool2d(
            x, self.blur, stride=1, padding=self.blur // 2, count_include_pad=False
        )
        count = F.avg_pool2d(
            valid, self.blur, stride=1, padding=self.blur // 2, count_include_pad=False
        )
        smooth = total / count.clamp_min(1e-6)
        return torch.where(valid > 0, INVERT_M - smooth, torch.zeros_like(x))
