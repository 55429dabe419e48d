"""Morphological pre-fill of the sparse LIDAR map (paper sec. III-B), inside the network.

Depth is inverted so that near surfaces win every max, then each empty pixel takes the nearest
return within a growing square: dilations by 3, 5, 9, 17 and 33 working pixels, each filling
only what the ones before left empty. A fixed set of kernels matched to one beam grid (as
IP-Basic does) fails on other LIDARs: a flash array needs none of it, a 16-beam sensor's rows
lie tens of pixels apart. The growing squares reach any spacing up to 16 cells and say how far
each pixel is from its return (``level``), which the networks use as a cue of their own. Built
from max pooling, so training and the exported ONNX graph share one implementation.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from sdcnet.evaluation.classical_fill import INVERT_M  # the classical fill's inversion, shared


def _dilate(x: torch.Tensor, k: int) -> torch.Tensor:
    """Grey dilation by a k x k square as two 1-D max pools (a square's max is separable)."""
    x = F.max_pool2d(x, (1, k), stride=1, padding=(0, k // 2))
    return F.max_pool2d(x, (k, 1), stride=1, padding=(k // 2, 0))


def near_wins_downsample(depth: torch.Tensor, factor: int) -> torch.Tensor:
    """Downsample a sparse depth map (B, 1, H, W) metres by ``factor``, keeping the nearest return
    of each block. H and W must be multiples of ``factor``."""
    inverted = torch.where(depth > 0, INVERT_M - depth, torch.zeros_like(depth))
    pooled = F.max_pool2d(inverted, factor)
    return torch.where(pooled > 0, INVERT_M - pooled, torch.zeros_like(pooled))


class NearestReturnFill(nn.Module):
    """Sparse depth (B, 1, h, w) metres -> filled depth (B, 1, h, w) metres (0 = no return
    within reach) and level (B, 1, h, w): 0 on a return, k / n where the k-th of the n squares
    filled the pixel, 1 where none reached it."""

    def __init__(self, *, kernels: tuple[int, ...] = (3, 5, 9, 17, 33)):
        super().__init__()
        self.kernels = tuple(kernels)

    def forward(self, sparse: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.where(sparse > 0, INVERT_M - sparse, torch.zeros_like(sparse))
        level = torch.where(x > 0, torch.zeros_like(x), torch.ones_like(x))
        count = len(self.kernels)
        for k, kernel in enumerate(self.kernels, start=1):
            grown = _dilate(x, kernel)
            new = (x <= 0) & (grown > 0)
            level = torch.where(new, torch.full_like(level, k / count), level)
            x = torch.where(x > 0, x, grown)
        return torch.where(x > 0, INVERT_M - x, torch.zeros_like(x)), level
