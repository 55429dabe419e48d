"""SDCNet = pre-fill + FSNet + FDCNet, built for a CPU latency budget.

Input: gray (B, 1, H, W) in [0, 1] and sparse LIDAR depth (B, 1, H, W) in metres (0 = none),
any H x W. Output: dense depth (B, 1, H, W) in metres and foreground probability (B, 1, H, W).

To fit ~100 ms per 1024 x 1024 frame on two cores, the depth networks run at a working
resolution ``factor`` (4) times below the input and FSNet at ``seg_factor`` (2) times below
(the sparse map is downsampled keeping the nearest return). Both see the full-resolution gray
image as space-to-depth blocks and answer at full resolution by depth-to-space, so edges in the
image reach the mask and the depth at the cost of low-resolution work. The mask gets the finer
grid because it decides most of the score: an ideal mask pooled to 1/4 and upsampled keeps IOU
94.7 %, pooled to 1/2 it keeps 97.8 % (mean over 198 training frames).

Depth (``depth_base="plane"``) is a residual on a local plane fitted to the returns around each
pixel (``plane_fit.py``): what was measured is kept, values between scan lines are interpolated,
and the network corrects what a plane cannot follow (depth edges, curvature). The first shipped
model (``depth_base="mean"``) regressed depth relative to the mean LIDAR return of the image on
the morphological pre-fill, which steps between beam rows.
Inputs are padded internally to the network's stride and the padding is cut off again.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import torch
from torch import nn
from torch.nn import functional as F

from sdcnet.training.model.blocks import space_to_depth
from sdcnet.training.model.fdcnet import FDCNet
from sdcnet.training.model.fsnet import FSNet
from sdcnet.training.model.mask_refiner import MaskRefiner
from sdcnet.training.model.plane_fit import PlaneFitPrefill
from sdcnet.training.model.prefill import MorphologicalPrefill, near_wins_downsample

FSNET_INPUTS = ("both", "gray", "sparse")
DEPTH_BASES = ("plane", "mean")


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of one variant. Defaults: SDCNet as shipped."""

    factor: int = 4  # depth networks' working resolution = input / factor
    seg_factor: int = 2  # FSNet's resolution = input / seg_factor: the mask decides the score
    widths: tuple[int, ...] = (8, 16, 32, 48)
    fusion: str = "cca+sa"  # "cca+sa" (SDCNet), "cca", "sa", "guided" (GuideNet baseline)
    use_fsnet: bool = True  # False: the baseline regresses depth everywhere, no segmentation
    fsnet_inputs: str = "both"  # Table 4: "both", "gray", "sparse"
    grid: int = 4  # CCA regions per side: M = grid^2 regions whatever the input size
    heads: int = 4
    depth_scale_m: float = 10.0  # depth inputs (and "mean" outputs) are in units of this
    depth_base: str = "plane"  # "plane": residual on a local plane fit; "mean": on the mean return
    subpixel: bool = True  # FDCNet sees gray blocks and predicts factor^2 sub-pixel residuals
    residual_scale_m: float = 1.0  # "plane": the residual head's output unit
    mask_refiner: bool = True  # full-resolution refinement of FSNet's logits on the gray image

    @property
    def stride(self) -> int:
        """Input sizes are padded to multiples of this."""
        coarsest = 2 ** (len(self.widths) - 1)
        return max(self.factor * max(coarsest, 4 * self.grid), 4 * self.seg_factor)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        """A config as saved; fields it predates take the values models had before them."""
        return cls(**{**LEGACY_FIELDS, **d, "widths": tuple(d["widths"])})

    def __post_init__(self):
        if self.factor % self.seg_factor:
            raise ValueError(
                f"factor {self.factor} must be a multiple of seg_factor {self.seg_factor}"
            )
        if self.fsnet_inputs not in FSNET_INPUTS:
            raise ValueError(f"fsnet_inputs must be one of {FSNET_INPUTS}")
        if self.depth_base not in DEPTH_BASES:
            raise ValueError(f"depth_base must be one of {DEPTH_BASES}")


#: What configs saved before a field existed meant by it (the first shipped model's design).
LEGACY_FIELDS = {
    "depth_base": "mean",
    "subpixel": False,
    "residual_scale_m": 1.0,
    "mask_refiner": False,
}


VARIANTS: dict[str, ModelConfig] = {
    "sdcnet": ModelConfig(),
    "baseline": ModelConfig(fusion="guided", use_fsnet=False),  # GuideNet-style, no FSNet
    "fsnet": ModelConfig(fusion="guided"),  # baseline + FSNet
    "fsnet+cca": ModelConfig(fusion="cca"),
    "fsnet+sa": ModelConfig(fusion="sa"),
    # The depth path's ablation: the first shipped design (residual on the mean return, on the
    # morphological pre-fill, bilinear upsampling), and the plane fit without sub-pixel output.
    "sdcnet-v1": ModelConfig(depth_base="mean", subpixel=False, mask_refiner=False),
    "plane": ModelConfig(subpixel=False),
}


def build_model(variant: str = "sdcnet", **overrides) -> SDCNet:
    """SDCNet of a named variant (``VARIANTS``) with any config fields overridden."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose one of {sorted(VARIANTS)}")
    return SDCNet(replace(VARIANTS[variant], **overrides))


class SDCNet(nn.Module):
    def __init__(self, config: ModelConfig = ModelConfig()):
        super().__init__()
        self.config = config
        self.prefill = MorphologicalPrefill()
        blocks = config.seg_factor**2  # full-resolution pixels per FSNet pixel
        fs_channels = {"both": blocks + 2, "gray": blocks, "sparse": 2}[config.fsnet_inputs]
        self.fsnet = (
            FSNet(in_channels=fs_channels, out_channels=blocks) if config.use_fsnet else None
        )
        self.refiner = (
            MaskRefiner(block=config.seg_factor)
            if config.use_fsnet and config.mask_refiner
            else None
        )
        plane = config.depth_base == "plane"
        self.plane_fit = PlaneFitPrefill(factor=config.factor) if plane else None
        cells = config.factor**2 if config.subpixel else 1  # outputs per working pixel
        self.fdcnet = FDCNet(
            gray_channels=cells,
            depth_channels=4 if plane else 2,
            out_channels=cells,
            widths=config.widths,
            fusion=config.fusion,
            grid=config.grid,
            heads=config.heads,
        )
        if plane:  # start from the plane fit itself: the residual head begins at zero
            nn.init.zeros_(self.fdcnet.head.weight)
            nn.init.zeros_(self.fdcnet.head.bias)

    def segmentation_parameters(self) -> list[nn.Parameter]:
        """Stage 1 trains these; stage 2 freezes them."""
        parts = [m for m in (self.fsnet, self.refiner) if m is not None]
        return [p for m in parts for p in m.parameters()]

    def reference_depth(self, sparse_lr: torch.Tensor) -> torch.Tensor:
        """Mean LIDAR return per image (B, 1, 1, 1) metres; 0 when there is none."""
        total = sparse_lr.sum(dim=(2, 3), keepdim=True)
        count = (sparse_lr > 0).to(sparse_lr.dtype).sum(dim=(2, 3), keepdim=True)
        return total / count.clamp_min(1.0)

    def _prepare(self, gray: torch.Tensor, sparse: torch.Tensor) -> dict[str, torch.Tensor]:
        """Padded full-resolution gray, the sparse map at FSNet's and at the depth networks'
        resolutions, the gray image at the latter, and the reference depth."""
        H, W = gray.shape[-2:]
        s = self.config.stride
        pad = (0, (s - W % s) % s, 0, (s - H % s) % s)
        gray_p, sparse_p = F.pad(gray, pad), F.pad(sparse, pad)
        sparse_seg = near_wins_downsample(sparse_p, self.config.seg_factor)
        sparse_lr = near_wins_downsample(sparse_seg, self.config.factor // self.config.seg_factor)
        return {
            "gray": gray_p,
            "gray_lr": F.avg_pool2d(gray_p, self.config.factor),
            "sparse": sparse_p,
            "sparse_seg": sparse_seg,
            "sparse_lr": sparse_lr,
            "d_ref": self.reference_depth(sparse_lr),
        }

    def _segment(self, x: dict[str, torch.Tensor]) -> torch.Tensor:
        """Foreground probability at full (padded) resolution."""
        seg = self.config.seg_factor
        returns = (x["sparse_seg"] > 0).to(x["gray"].dtype)
        relative = returns * (x["sparse_seg"] - x["d_ref"]) / self.config.depth_scale_m
        blocks = space_to_depth(x["gray"], seg)  # space-to-depth: full-resolution detail
        fs_in = {
            "both": [blocks, returns, relative],
            "gray": [blocks],
            "sparse": [returns, relative],
        }[self.config.fsnet_inputs]
        logit_blocks = self.fsnet(torch.cat(fs_in, 1))
        if self.refiner is not None:
            logit_blocks = self.refiner(blocks, logit_blocks)
        return torch.sigmoid(F.pixel_shuffle(logit_blocks, seg))

    def _regress(self, x: dict[str, torch.Tensor]) -> torch.Tensor:
        """Dense depth in metres at full (padded) resolution: a base (the local plane fit, or
        the mean return) plus the residual FDCNet regresses from the gray image and pre-fills."""
        c = self.config
        d_ref, scale = x["d_ref"], c.depth_scale_m
        filled = self.prefill(x["sparse_lr"])
        valid = (filled > 0).to(filled.dtype)
        depth_in = [valid * (filled - d_ref) / scale, valid]
        if self.plane_fit is None:
            base, unit = d_ref, scale
        else:
            plane, weight = self.plane_fit(x["sparse"], d_ref)
            fitted = (weight > 0).to(plane.dtype)
            depth_in = [fitted * (plane - d_ref) / scale, fitted, *depth_in]
            base_lr = torch.where(weight > 0, plane, torch.where(filled > 0, filled, d_ref))
            base, unit = self._upsample(base_lr), c.residual_scale_m
        gray = space_to_depth(x["gray"], c.factor) if c.subpixel else x["gray_lr"]
        out = self.fdcnet(gray, torch.cat(depth_in, 1))
        residual = F.pixel_shuffle(out, c.factor) if c.subpixel else self._upsample(out)
        return base + unit * residual

    def _upsample(self, x: torch.Tensor) -> torch.Tensor:
        """Working resolution -> full resolution, bilinear between cell centres."""
        return F.interpolate(
            x, scale_factor=self.config.factor, mode="bilinear", align_corners=False
        )

    def segment(self, gray: torch.Tensor, sparse: torch.Tensor) -> torch.Tensor:
        """Foreground probability (B, 1, H, W) alone: what stage 1 trains, at a fraction of
        the cost of the whole network."""
        H, W = gray.shape[-2:]
        return self._segment(self._prepare(gray, sparse))[..., :H, :W]

    def forward(
        self, gray: torch.Tensor, sparse: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        H, W = gray.shape[-2:]
        x = self._prepare(gray, sparse)
        depth = self._regress(x)
        if self.fsnet is not None:
            prob = self._segment(x)
        else:  # no segmentation: foreground where the regressed depth is not background
            prob = (depth > 0.5 * x["d_ref"]).to(depth.dtype)
        return depth[..., :H, :W], prob[..., :H, :W]
