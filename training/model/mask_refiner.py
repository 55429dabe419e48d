"""Outline refiner: FSNet's full-resolution logits sharpened by the gray image around them.

FSNet runs at half resolution and places its sub-pixel logits by depth-to-space; most of the
IOU it misses lies on the one pixel layer along the true outline (5.1 of 6.0 points for the
first shipped model), where the camera's blur leaves a pixel half bright. Two 3 x 3
convolutions at full resolution on (gray, logit) see that pixel and its neighbours and add a
correction to the logit: about 200 multiply-adds per pixel. The last convolution starts at
zero, so a refiner added to a trained FSNet changes nothing until it is trained.

The convolutions are defined at full resolution (their weights are what a checkpoint holds)
but computed on ``block`` x ``block`` space-to-depth blocks, where FSNet's output and input
already are: a 3 x 3 convolution at full resolution is exactly a 3 x 3 convolution over
blocks with ``block``² times the channels (``block_weight``). With one or two channels at full
resolution onnxruntime spends much of the time re-laying tensors out; over blocks it does not,
and no depth-to-space / space-to-depth pair is needed around it (the whole pipeline 80.7 ->
75.0 ms per test frame, ``benchmarks.pipeline_latency``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def block_selection(block: int) -> torch.Tensor:
    """(block, block, 3, 3) 0/1: entry [o, i, b, k] is 1 when kernel tap k (0..2, offset k - 1
    pixels) of an output at sub-position o reads sub-position i of the block at offset b - 1.
    One axis; the 2-D map is the product of the rows' and the columns'."""
    sel = torch.zeros(block, block, 3, 3)
    for o in range(block):
        for k in range(3):
            b, i = divmod(o + k - 1, block)  # pixel offset -> (block offset, sub-position)
            sel[o, i, b + 1, k] = 1.0
    return sel


def block_weight(weight: torch.Tensor, sel: torch.Tensor) -> torch.Tensor:
    """A full-resolution 3 x 3 kernel (C_out, C_in, 3, 3) as the equivalent kernel over
    s x s space-to-depth blocks (C_out·s², C_in·s², 3, 3), ``sel`` = ``block_selection(s)``;
    channels in ``pixel_unshuffle``'s order (channel-major, then row, then column of the block).
    """
    block = sel.shape[0]
    c_out, c_in = weight.shape[:2]
    # [c, n, ky, kx] x [oy, iy, by, ky] x [ox, ix, bx, kx] -> [c, oy, ox, n, iy, ix, by, bx]
    big = torch.einsum("cnyx,aiby,djex->cadnijbe", weight, sel, sel)
    return big.reshape(c_out * block * block, c_in * block * block, 3, 3)


class MaskRefiner(nn.Module):
    """(gray blocks (B, s², h, w) in [0, 1], logit blocks (B, s², h, w)) -> refined logit blocks
    (B, s², h, w), where s = ``block`` and h, w = H / s, W / s: ``pixel_unshuffle`` of the
    full-resolution (B, 1, H, W) maps (``block`` = 1 works on them directly)."""

    def __init__(self, *, block: int, hidden: int = 8):
        super().__init__()
        self.block = block
        # a constant of the graph (not of the checkpoint): the exported kernels fold to plain convs
        self.register_buffer("selection", block_selection(block), persistent=False)
        # a Sequential for the checkpoints' key names (features.0.*), written before blocks
        self.features = nn.Sequential(nn.Conv2d(2, hidden, 3, padding=1))
        self.correction = nn.Conv2d(hidden, 1, 3, padding=1)
        nn.init.zeros_(self.correction.weight)
        nn.init.zeros_(self.correction.bias)

    def _conv(self, conv: nn.Conv2d, x: torch.Tensor) -> torch.Tensor:
        bias = conv.bias.repeat_interleave(self.block * self.block)
        return F.conv2d(x, block_weight(conv.weight, self.selection), bias, padding=1)

    def forward(self, gray_blocks: torch.Tensor, logit_blocks: torch.Tensor) -> torch.Tensor:
        hidden = F.relu(self._conv(self.features[0], torch.cat([gray_blocks, logit_blocks], 1)))
        return logit_blocks + self._conv(self.correction, hidden)
