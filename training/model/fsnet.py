"""FSNet: the foreground segmentation subnet (paper sec. III-A, Fig. 3).

Eight convolutions, about 5k parameters, an encoder-decoder on the gray image and the sparse
depth that predicts a foreground logit per pixel. Here it runs at half the input resolution
and still answers at full resolution, without any full-resolution convolution: the gray image
enters as a space-to-depth stack (each 2 x 2 block of pixels as 4 channels) and the head
predicts the 4 sub-pixel logits of each block, put back in place by depth-to-space. Edges seen
in the full-resolution gray image thus reach the mask at the cost of half-resolution work.

With ``context``, three more convolutions at an eighth of FSNet's resolution (a sixteenth of
the working grid: 32 x 32 for 512 x 512) see most of the crop at once and add what they see to
the bottleneck: an output pixel's receptive field grows from 69 to 185 FSNet pixels across
(138 to 370 working pixels; where its input gradient is not zero). With a LIDAR narrower than
the camera, most of the mask the narrow network misses lies inside the crop on parts of the
spacecraft far from any return (docs/development.md, "Measurements"). The branch's last
convolution starts at zero: added to a trained FSNet, it changes nothing until trained.
"""

from __future__ import annotations

import torch
from torch import nn

from sdcnet.training.model.blocks import ConvBNReLU, upsample_to

#: Channels of enc1, enc2, enc3 (= mid1), mid2 (= dec2) and dec1 at ``growth`` 1: the paper's
#: ~5k parameters.
WIDTHS = (6, 8, 12, 8, 6)


def context_branch(channels: int, width: int) -> nn.Sequential:
    """(B, channels, h, w) -> (B, channels, h/2, w/2): the coarse branch (module docstring),
    its last convolution at zero."""
    branch = nn.Sequential(
        ConvBNReLU(channels, width, stride=2),
        ConvBNReLU(width, width, dilation=2),
        ConvBNReLU(width, width, dilation=4),
        nn.Conv2d(width, channels, 1),
    )
    nn.init.zeros_(branch[-1].weight)
    nn.init.zeros_(branch[-1].bias)
    return branch


class FSNet(nn.Module):
    """(B, Cin, h, w) -> logits (B, Cout, h, w); h, w multiples of 4. ``growth`` multiplies
    every width (parameters grow as its square); ``context`` adds the coarse branch (module
    docstring)."""

    def __init__(
        self, *, in_channels: int, out_channels: int = 1, growth: int = 1, context: bool = False
    ):
        super().__init__()
        c1, c2, c3, c4, c5 = (growth * c for c in WIDTHS)
        self.enc1 = ConvBNReLU(in_channels, c1)
        self.enc2 = ConvBNReLU(c1, c2, stride=2)
        self.enc3 = ConvBNReLU(c2, c3, stride=2)
        self.mid1 = ConvBNReLU(c3, c3, dilation=2)
        self.mid2 = ConvBNReLU(c3, c4, dilation=4)
        self.dec2 = ConvBNReLU(c4 + c2, c4)
        self.dec1 = ConvBNReLU(c4 + c1, c5)
        self.head = nn.Conv2d(c5, out_channels, 1)
        self.context = context_branch(c4, c3) if context else None
        # each layer's input channels as the parts concatenated into it, in order
        self.input_parts = {
            "enc1": (in_channels,),
            "enc2": (c1,),
            "enc3": (c2,),
            "mid1": (c3,),
            "mid2": (c3,),
            "dec2": (c4, c2),
            "dec1": (c4, c1),
            "head": (c5,),
        }

    @torch.no_grad()
    def widen_from(self, narrow: FSNet) -> None:
        """Start from the weights of a narrower FSNet (smaller ``growth``, same inputs and
        outputs). Each layer's old channels go into the first of its new ones, part by part of
        a concatenated input; the old outputs' weights on the new inputs start at zero and
        the new outputs keep their random start. The wide network first computes exactly what
        the narrow one did, and its new channels carry activations, so they learn."""
        for name, parts in self.input_parts.items():
            layer, old = getattr(self, name), getattr(narrow, name)
            conv, old_conv = (layer, old) if name == "head" else (layer[0], old[0])
            rows = old_conv.out_channels
            conv.weight[:rows] = 0.0
            start = old_start = 0
            for part, old_part in zip(parts, narrow.input_parts[name], strict=True):
                conv.weight[:rows, start : start + old_part] = old_conv.weight[
                    :, old_start : old_start + old_part
                ]
                start, old_start = start + part, old_start + old_part
            if conv.bias is not None:
                conv.bias[:rows] = old_conv.bias
            if name != "head":
                bn, old_bn = layer[1], old[1]
                for key in ("weight", "bias", "running_mean", "running_var"):
                    getattr(bn, key)[:rows] = getattr(old_bn, key)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        e1 = self.enc1(x)
        e2 = self.enc2(e1)
        m = self.mid2(self.mid1(self.enc3(e2)))
        if self.context is not None:
            m = m + upsample_to(self.context(m), m)
        d2 = self.dec2(torch.cat([upsample_to(m, e2), e2], 1))
        d1 = self.dec1(torch.cat([upsample_to(d2, e1), e1], 1))
        return self.head(d1)
