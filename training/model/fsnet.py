"""FSNet: the foreground segmentation subnet (paper sec. III-A, Fig. 3).

Eight convolutions, about 5k parameters, an encoder-decoder on the gray image and the sparse
depth that predicts a foreground logit per pixel. Here it runs at the working resolution; a
two-layer ``MaskRefiner`` then sharpens the upsampled logit against the full-resolution gray
image, where the silhouette's edges are.
"""

from __future__ import annotations

import torch
from torch import nn

from sdcnet.training.model.blocks import ConvBNReLU, upsample_to


class FSNet(nn.Module):
    """(B, Cin, h, w) -> foreground logit (B, 1, h, w); h, w multiples of 4."""

    def __init__(self, in_channels: int):
        super().__init__()
        self.enc1 = ConvBNReLU(in_channels, 6)
        self.enc2 = ConvBNReLU(6, 8, stride=2)
        self.enc3 = ConvBNReLU(8, 12, stride=2)
        self.mid1 = ConvBNReLU(12, 12, dilation=2)
        self.mid2 = ConvBNReLU(12, 8, dilation=4)
        self.dec2 = ConvBNReLU(8 + 8, 8)
        self.dec1 = ConvBNReLU(8 + 6, 6)
        self.head = nn.Conv2d(6, 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        m = self.mid2(self.mid1(self.enc3(e2)))
        d2 = self.dec2(torch.cat([upsample_to(m, e2), e2], 1))
        d1 = self.dec1(torch.cat([upsample_to(d2, e1), e1], 1))
        return self.head(d1)


class MaskRefiner(nn.Module):
    """Residual correction of an upsampled logit from the full-resolution gray image.

    (gray (B, 1, H, W), logit (B, 1, H, W)) -> logit (B, 1, H, W). Two small convolutions:
    cheap enough to run on a whole 1024 x 1024 frame within the latency budget.
    """

    def __init__(self, hidden: int = 8):
        super().__init__()
        self.conv1 = nn.Conv2d(2, hidden, 3, padding=1)
        self.conv2 = nn.Conv2d(hidden, 1, 3, padding=1)

    def forward(self, gray: torch.Tensor, logit: torch.Tensor) -> torch.Tensor:
        h = torch.relu(self.conv1(torch.cat([gray, logit], 1)))
        return logit + self.conv2(h)
