"""Training losses of the paper (sec. III-C)."""

from __future__ import annotations

import torch
from torch.nn import functional as F


def segmentation_loss(probability: torch.Tensor, gt_depth: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the foreground probability against depth > 0 (eq. 6)."""
    target = (gt_depth > 0).to(probability.dtype)
    return F.binary_cross_entropy(probability.clamp(1e-6, 1 - 1e-6), target)


def soft_iou_loss(
    probability: torch.Tensor, gt_depth: torch.Tensor, per_tile: bool = False
) -> torch.Tensor:
    """1 - soft IOU of the foreground probability with depth > 0, over the whole batch, or
    (``per_tile``) the mean of 1 - soft IOU over the tiles that hold some foreground.

    BCE weighs every pixel alike, so a mask can be sure of its interior and still lose IOU on
    its outline, where the blurred image leaves a pixel or two in doubt; this term scores the
    mask the way IOU does (Rahman & Wang 2016). Over the batch a large spacecraft outweighs a
    small one; per tile each weighs alike, as in the IOU metric, a mean over frames.
    """
    target = (gt_depth > 0).to(probability.dtype)
    dims = (1, 2, 3) if per_tile else tuple(range(probability.dim()))
    inter = (probability * target).sum(dims)
    union = (probability + target - probability * target).sum(dims)
    loss = 1 - inter / union.clamp_min(1e-6)
    if not per_tile:
        return loss
    held = target.sum(dims) > 0
    return loss[held].mean() if torch.any(held) else probability.sum() * 0.0


def foreground_depth_loss(
    depth: torch.Tensor,
    probability: torch.Tensor,
    gt_depth: torch.Tensor,
    unit: torch.Tensor | float = 1.0,
) -> torch.Tensor:
    """L1 depth error over the predicted foreground (eq. 7), in ``unit`` (metres, or a (B, 1,
    1, 1) tensor of each frame's unit: the model's ``residual_unit``, so that a frame at 3 m
    and one at 250 m weigh alike).

    Pixels of the predicted foreground that are sky in the ground truth have no depth to learn
    (eq. 7 would pull them towards 0 m), so the mean runs over predicted ∩ true foreground.
    Pixels outside the predicted foreground never contribute.
    """
    region = (probability > 0.5) & (gt_depth > 0)
    if not torch.any(region):
        return depth.sum() * 0.0
    return ((depth - gt_depth).abs() / unit)[region].mean()


def dense_depth_loss(depth: torch.Tensor, gt_depth: torch.Tensor) -> torch.Tensor:
    """L1 over every pixel, sky = 0 m: how the no-FSNet baseline (GuideNet) is trained."""
    return (depth - gt_depth).abs().mean()


def depth_gradient_loss(
    depth: torch.Tensor,
    probability: torch.Tensor,
    gt_depth: torch.Tensor,
    unit: torch.Tensor | float = 1.0,
) -> torch.Tensor:
    """L1 error of the depth differences between horizontally and vertically adjacent pixels,
    where both lie in predicted ∩ true foreground, ``unit`` per pixel (as
    ``foreground_depth_loss``).

    The L1 depth loss forgives a ripple of a centimetre between scan lines; the slopes it leaves
    tilt the surface normals by degrees (a flat panel comes out corrugated). This term asks for
    the slopes themselves, and for sharp steps where the ground truth has them.
    """
    region = (probability > 0.5) & (gt_depth > 0)
    errors, count = depth.new_zeros(()), 0
    for dim in (-1, -2):
        n = depth.shape[dim] - 1
        both = region.narrow(dim, 0, n) & region.narrow(dim, 1, n)
        pred_step = depth.narrow(dim, 1, n) - depth.narrow(dim, 0, n)
        true_step = gt_depth.narrow(dim, 1, n) - gt_depth.narrow(dim, 0, n)
        errors = errors + ((pred_step - true_step).abs() / unit)[both].sum()
        count += int(both.sum())
    return errors / max(count, 1)


def laplace_nll(
    depth: torch.Tensor,
    scale: torch.Tensor,
    probability: torch.Tensor,
    gt_depth: torch.Tensor,
    unit: torch.Tensor | float = 1.0,
) -> torch.Tensor:
    """Negative log-likelihood of the true depth under a Laplace distribution centred on the
    predicted depth with ``scale`` (metres), mean over predicted ∩ true foreground:
    |d - d_true| / b + log(b / unit), constant log 2 left out. Its minimum over b is the mean
    absolute error, so a scale trained with it says how wrong each pixel's depth is. Callers
    pass ``depth`` detached: the uncertainty learns from the depth, never the other way."""
    region = (probability > 0.5) & (gt_depth > 0)
    if not torch.any(region):
        return scale.sum() * 0.0
    b = scale.clamp_min(1e-6)
    return ((depth - gt_depth).abs() / b + torch.log(b / unit))[region].mean()
