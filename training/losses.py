"""Training losses of the paper (sec. III-C)."""

from __future__ import annotations

import torch
from torch.nn import functional as F


def segmentation_loss(probability: torch.Tensor, gt_depth: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the foreground probability against depth > 0 (eq. 6)."""
    target = (gt_depth > 0).to(probability.dtype)
    return F.binary_cross_entropy(probability.clamp(1e-6, 1 - 1e-6), target)


def foreground_depth_loss(
    depth: torch.Tensor, probability: torch.Tensor, gt_depth: torch.Tensor
) -> torch.Tensor:
    """L1 depth error over the predicted foreground (eq. 7), metres.

    Pixels of the predicted foreground that are sky in the ground truth have no depth to learn
    (eq. 7 would pull them towards 0 m), so the mean runs over predicted ∩ true foreground.
    Pixels outside the predicted foreground never contribute.
    """
    region = (probability > 0.5) & (gt_depth > 0)
    if not torch.any(region):
        return depth.sum() * 0.0
    return (depth - gt_depth).abs()[region].mean()


def dense_depth_loss(depth: torch.Tensor, gt_depth: torch.Tensor) -> torch.Tensor:
    """L1 over every pixel, sky = 0 m: how the no-FSNet baseline (GuideNet) is trained."""
    return (depth - gt_depth).abs().mean()
