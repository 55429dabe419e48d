"""Small convolutional building blocks shared by the subnets."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


class ConvBNReLU(nn.Sequential):
    """3 x 3 (or k x k) convolution, batch norm, ReLU. (B, Cin, H, W) -> (B, Cout, H/s, W/s)."""

    def __init__(self, cin: int, cout: int, *, kernel: int = 3, stride: int = 1, dilation: int = 1):
        padding = dilation * (kernel - 1) // 2
        super().__init__(
            nn.Conv2d(cin, cout, kernel, stride, padding, dilation=dilation, bias=False),
            nn.BatchNorm2d(cout),
            nn.ReLU(inplace=True),
        )


def upsample_to(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """Bilinear resize of ``x`` to the spatial size of ``like``."""
    return F.interpolate(x, size=like.shape[-2:], mode="bilinear", align_corners=False)


def space_to_depth(x: torch.Tensor, block: int) -> torch.Tensor:
    """``F.pixel_unshuffle`` of a one-channel map, (B, 1, H, W) -> (B, block², H/block,
    W/block), as a strided convolution with one-hot kernels: the same values exactly (each
    output is one input times 1 plus zeros), but exported as one convolution, which onnxruntime
    runs in its blocked layout, instead of a reshape-transpose-reshape over the whole crop
    (about 2 ms per 768 x 768 crop on 2 cores, three times per frame)."""
    if x.shape[1] != 1:
        raise ValueError(f"space_to_depth takes one channel, got {x.shape[1]}")
    kernel = torch.eye(block * block, dtype=x.dtype, device=x.device)
    return F.conv2d(x, kernel.reshape(block * block, 1, block, block), stride=block)
