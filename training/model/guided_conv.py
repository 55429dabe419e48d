"""Guided convolution fusion, the paper's GuideNet baseline (Tang et al., TIP 2020).

The gray features generate a spatially-variant 3 x 3 depthwise kernel for every pixel and
channel of the depth features, then a channel-mixing matrix from their global average;
the filtered depth features are added back to the depth features. Built from convolutions,
slicing and matmul only, so it exports to ONNX and runs on a CPU.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class GuidedConvFusion(nn.Module):
    """(f_s, f_g) each (B, C, H, W) -> (B, C, H, W)."""

    def __init__(self, *, channels: int):
        super().__init__()
        self.kernels = nn.Conv2d(channels, 9 * channels, 3, padding=1)
        self.mixing = nn.Linear(channels, channels * channels)
        self.norm = nn.BatchNorm2d(channels)

    def forward(self, f_s: torch.Tensor, f_g: torch.Tensor) -> torch.Tensor:
        B, C, H, W = f_s.shape
        kernels = self.kernels(f_g)
        padded = F.pad(f_s, (1, 1, 1, 1))
        filtered = torch.zeros_like(f_s)
        for k in range(9):
            dy, dx = divmod(k, 3)
            filtered = (
                filtered + padded[:, :, dy : dy + H, dx : dx + W] * kernels[:, k * C : (k + 1) * C]
            )
        mixing = self.mixing(f_g.mean(dim=(2, 3))).reshape(B, C, C) / C
        mixed = (mixing @ filtered.reshape(B, C, H * W)).reshape(B, C, H, W)
        return f_s + torch.relu(self.norm(mixed))
