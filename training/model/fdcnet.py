"""FDCNet: the foreground depth completion subnet (paper sec. III-B, Fig. 2).

A gray branch and a depth branch, both U-shaped encoder-decoders of the same widths. At every
decoder scale the depth features are fused with the gray features by the fusion module
(cross-channel attention then spatial attention in SDCNet; guided convolution in the
GuideNet baseline; either attention alone in the ablations). A 1 x 1 head regresses depth.
"""

from __future__ import annotations

from itertools import pairwise

import torch
from torch import nn

from sdcnet.training.model.blocks import ConvBNReLU, upsample_to
from sdcnet.training.model.cca import CrossChannelAttention
from sdcnet.training.model.guided_conv import GuidedConvFusion
from sdcnet.training.model.spatial_attention import SpatialAttention

FUSIONS = ("cca+sa", "cca", "sa", "guided")


class Fusion(nn.Module):
    """Depth features fused with gray features: (f_s, f_g) (B, C, H, W) -> (B, C, H, W)."""

    def __init__(self, *, kind: str, channels: int, grid: int, heads: int):
        super().__init__()
        if kind not in FUSIONS:
            raise ValueError(f"unknown fusion {kind!r}; choose one of {FUSIONS}")
        self.cca = (
            CrossChannelAttention(channels=channels, grid=grid, heads=heads)
            if "cca" in kind
            else None
        )
        self.sa = SpatialAttention() if "sa" in kind else None
        self.guided = GuidedConvFusion(channels=channels) if kind == "guided" else None

    def forward(self, f_s: torch.Tensor, f_g: torch.Tensor) -> torch.Tensor:
        if self.guided is not None:
            return self.guided(f_s, f_g)
        fused = self.cca(f_s, f_g) if self.cca is not None else f_s
        return self.sa(fused, f_g) if self.sa is not None else fused


class Encoder(nn.Module):
    """(B, Cin, h, w) -> features at scales 1, 1/2, ..., 1/2^(L-1) with ``widths`` channels."""

    def __init__(self, *, in_channels: int, widths: tuple[int, ...]):
        super().__init__()
        self.stem = nn.Sequential(
            ConvBNReLU(in_channels, widths[0]), ConvBNReLU(widths[0], widths[0])
        )
        self.downs = nn.ModuleList(
            nn.Sequential(ConvBNReLU(a, b, stride=2), ConvBNReLU(b, b)) for a, b in pairwise(widths)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        features = [self.stem(x)]
        for down in self.downs:
            features.append(down(features[-1]))
        return features


class DecoderStage(nn.Module):
    """Upsample the coarser features, concatenate the skip, convolve."""

    def __init__(self, *, coarse: int, skip: int, out: int):
        super().__init__()
        self.conv = ConvBNReLU(coarse + skip, out)

    def forward(self, coarse: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        return self.conv(torch.cat([upsample_to(coarse, skip), skip], 1))


class FDCNet(nn.Module):
    """(gray (B, Cg, h, w), depth input (B, Cd, h, w)) -> normalised depth (B, Cout, h, w) and
    its log-scale (B, Cout, h, w): the log of the expected absolute error, in the same unit.

    Cg = Cout = 1 for a gray image and a depth at the working resolution, or factor^2 for the
    full-resolution gray image as space-to-depth blocks and sub-pixel depths per working pixel.
    The scale head reads the last decoder features and the depth input without passing
    gradients back to them: learning how wrong the depth is never changes the depth.
    """

    def __init__(
        self,
        *,
        gray_channels: int = 1,
        depth_channels: int,
        out_channels: int = 1,
        widths: tuple[int, ...],
        fusion: str,
        grid: int,
        heads: int,
    ):
        super().__init__()
        self.gray_encoder = Encoder(in_channels=gray_channels, widths=widths)
        self.depth_encoder = Encoder(in_channels=depth_channels, widths=widths)
        scales = range(len(widths) - 2, -1, -1)  # decoder scales, coarse to fine
        self.gray_decoder = nn.ModuleList(
            DecoderStage(coarse=widths[i + 1], skip=widths[i], out=widths[i]) for i in scales
        )
        self.depth_decoder = nn.ModuleList(
            DecoderStage(coarse=widths[i + 1], skip=widths[i], out=widths[i]) for i in scales
        )
        self.fusions = nn.ModuleList(
            Fusion(kind=fusion, channels=widths[i], grid=grid, heads=heads) for i in scales
        )
        self.head = nn.Conv2d(widths[0], out_channels, 1)
        self.scale_head = nn.Sequential(
            nn.Conv2d(widths[0] + depth_channels, widths[0], 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(widths[0], out_channels, 1),
        )

    def forward(self, gray: torch.Tensor, depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        g_skips, s_skips = self.gray_encoder(gray), self.depth_encoder(depth)
        g, s = g_skips[-1], s_skips[-1]
        for k, (gray_stage, depth_stage, fusion) in enumerate(
            zip(self.gray_decoder, self.depth_decoder, self.fusions, strict=True)
        ):
            level = len(g_skips) - 2 - k
            g = gray_stage(g, g_skips[level])
            s = fusion(depth_stage(s, s_skips[level]), g)
        log_scale = self.scale_head(torch.cat([s, depth], 1).detach())
        return self.head(s), log_scale
