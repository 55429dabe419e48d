"""Spatial attention (paper sec. III-B, eq. 5), after CBAM.

Channel-wise max and mean of the fused features and of the gray features, a convolution and a
sigmoid give a per-pixel weight W; out = W * f_cca + (1 - W) * f_g, W broadcast over channels.
"""

from __future__ import annotations

import torch
from torch import nn


class SpatialAttention(nn.Module):
    """(f_cca, f_g) each (B, C, H, W) -> (B, C, H, W)."""

    def __init__(self, *, kernel: int = 7):
        super().__init__()
        self.conv = nn.Conv2d(4, 1, kernel, padding=kernel // 2)

    def weight(self, f_cca: torch.Tensor, f_g: torch.Tensor) -> torch.Tensor:
        """The spatial attention map W (B, 1, H, W) in (0, 1)."""
        descriptor = torch.cat(
            [
                f_cca.amax(1, keepdim=True),
                f_cca.mean(1, keepdim=True),
                f_g.amax(1, keepdim=True),
                f_g.mean(1, keepdim=True),
            ],
            dim=1,
        )
        return torch.sigmoid(self.conv(descriptor))

    def forward(self, f_cca: torch.Tensor, f_g: torch.Tensor) -> torch.Tensor:
        w = self.weight(f_cca, f_g)
        return w * f_cca + (1 - w) * f_g
