"""FSNet: the foreground segmentation subnet (paper sec. III-A, Fig. 3).

Eight convolutions, about 5k parameters, an encoder-decoder on the gray image and the sparse
depth that predicts a foreground logit per pixel. Here it runs at half the input resolution
and still answers at full resolution, without any full-resolution convolution: the gray image
enters as a space-to-depth stack (each 2 x 2 block of pixels as 4 channels) and the head
predicts the 4 sub-pixel logits of each block, put back in place by depth-to-space. Edges seen
in the full-resolution gray image thus reach the mask at the cost of half-resolution work.
"""

from __future__ import annotations

import torch
from torch import nn

from sdcnet.training.model.blocks import ConvBNReLU, upsample_to


class FSNet(nn.Module):
    """(B, Cin, h, w) -> logits (B, Cout, h, w); h, w multiples of 4."""

    def __init__(self, *, in_channels: int, out_channels: int = 1):
        super().__init__()
        self.enc1 = ConvBNReLU(in_channels, 6)
        self.enc2 = ConvBNReLU(6, 8, stride=2)
        self.enc3 = ConvBNReLU(8, 12, stride=2)
        self.mid1 = ConvBNReLU(12, 12, dilation=2)
        self.mid2 = ConvBNReLU(12, 8, dilation=4)
        self.dec2 = ConvBNReLU(8 + 8, 8)
        self.dec1 = ConvBNReLU(8 + 6, 6)
        self.head = nn.Conv2d(6, out_channels, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        m = self.mid2(self.mid1(self.enc3(e2)))
        d2 = self.dec2(torch.cat([upsample_to(m, e2), e2], 1))
        d1 = self.dec1(torch.cat([upsample_to(d2, e1), e1], 1))
        return self.head(d1)
