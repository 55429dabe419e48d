"""Cross-channel attention (paper sec. III-B, eqs 1-4, Figs 4-5).

Each C x H x W feature map is embedded channel by channel into a d_k-vector: the map is cut
into a fixed grid of M = g x g regions (the regions grow with the input, so the weights do not
depend on its size) and each region gives its max, its mean and a pixel-adaptive weighted mean,
d_k = 3 M. Queries come from the depth features, keys from the gray features; each of n heads
forms a C x C channel attention w_i = softmax(Q_i K_i^T / sqrt(d_k)) and fuses
f_i = F_s + w_i F_g; a 1 x 1 convolution merges the heads.
"""

from __future__ import annotations

import math

import torch
from torch import nn


class RegionEmbedding(nn.Module):
    """(B, C, H, W) -> (B, C, 3 g^2): per-region max, mean and pixel-adaptive weighted mean.

    H and W must be multiples of ``grid``.
    """

    def __init__(self, *, channels: int, grid: int = 4):
        super().__init__()
        self.grid = grid
        self.score = nn.Conv2d(channels, 1, 1)  # where, inside a region, to look

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        B, C, H, W = x.shape
        g = self.grid
        regions = x.reshape(B, C, g, H // g, g, W // g)
        peak = regions.amax(dim=(3, 5))
        mean = regions.mean(dim=(3, 5))
        score = self.score(x).reshape(B, 1, g, H // g, g, W // g)
        weight = torch.exp(score - score.amax(dim=(3, 5), keepdim=True))
        weight = weight / weight.sum(dim=(3, 5), keepdim=True)
        adaptive = (regions * weight).sum(dim=(3, 5))
        return torch.cat([peak, mean, adaptive], dim=2).reshape(B, C, 3 * g * g)


class CrossChannelAttention(nn.Module):
    """(f_s, f_g) each (B, C, H, W) -> fused depth features (B, C, H, W)."""

    def __init__(self, *, channels: int, grid: int = 4, heads: int = 4):
        super().__init__()
        d_k = 3 * grid * grid
        if d_k % heads:
            raise ValueError(f"d_k = {d_k} must split into {heads} heads")
        self.heads, self.d_k = heads, d_k
        self.embed_s = RegionEmbedding(channels=channels, grid=grid)
        self.embed_g = RegionEmbedding(channels=channels, grid=grid)
        self.norm_s = nn.LayerNorm(d_k)
        self.norm_g = nn.LayerNorm(d_k)
        self.query = nn.Linear(d_k, d_k, bias=False)  # the n matrices W_i^Q side by side
        self.key = nn.Linear(d_k, d_k, bias=False)
        self.merge = nn.Conv2d(heads * channels, channels, 1)

    def attention(self, f_s: torch.Tensor, f_g: torch.Tensor) -> torch.Tensor:
        """Channel attention maps (B, n, C, C), eq. 2."""
        B, C = f_s.shape[:2]
        n = self.heads
        q = self.query(self.norm_s(self.embed_s(f_s))).reshape(B, C, n, -1).transpose(1, 2)
        k = self.key(self.norm_g(self.embed_g(f_g))).reshape(B, C, n, -1).transpose(1, 2)
        return torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(self.d_k), dim=-1)

    def forward(self, f_s: torch.Tensor, f_g: torch.Tensor) -> torch.Tensor:
        B, C, H, W = f_s.shape
        w = self.attention(f_s, f_g)
        fused = f_s.reshape(B, 1, C, H * W) + w @ f_g.reshape(B, 1, C, H * W)  # eq. 3
        return self.merge(fused.reshape(B, self.heads * C, H, W))  # eq. 4
