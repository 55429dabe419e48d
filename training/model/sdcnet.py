"""SDCNet = pre-fills + FSNet + FDCNet, for any camera, any LIDAR and any range.

Inputs: gray (B, 1, H, W) in [0, 1]; sparse LIDAR depth (B, 1, H, W) in metres (0 = none);
focal_px (B, 1, 1, 1), the focal length in pixels of the grid the two maps are on. Any H x W.
Outputs: dense depth (B, 1, H, W) in metres, foreground probability (B, 1, H, W) and the
depth's uncertainty sigma (B, 1, H, W) in metres: the scale of a Laplace distribution of the
error times ``sigma_per_scale`` (1.14 for a Laplace error: |error| <= sigma for 68 % of
pixels; ``sdc-train calibrate`` measures it on frames not trained on). At inference a depth-edge
term joins it: ``sigma_edge_weight`` times the spread of the predicted depth over the 5 x 5
working pixels around each foreground pixel, added in quadrature. The scale head alone says
centimetres where a pixel sits between two surfaces metres apart; the spread says how far
apart they are. The term is set by ``sdc-train calibrate``, not trained: in training mode
sigma is the scale head's alone (its loss is the Laplace likelihood of that scale).

The pipeline (``sdcnet.pipeline``) resamples every frame's crop to about the same number of
working pixels, so the network sees a spacecraft a few hundred pixels across whatever the
camera and the range. What it must not see is the scale in metres: a panel tilted 45 deg
changes depth by one pixel footprint (range / focal length) per pixel, at 3 m with a wide
camera as at 250 m with the paper's. So depths enter relative to the mean return ``d_ref``,
in units of the metres ``input_span_px`` working pixels span at that range, and the head's
residual is in units of ``residual_span_px`` footprints; the depth loss is scaled the same
way (``residual_unit``). The gray image is scaled so that the spacecraft's mean brightness
at its returns is ``GRAY_TARGET`` (``normalise_gray``): exposure and bit depth vary by
camera, the spacecraft's look does not.

For ~100 ms per frame on two cores, the depth networks run at ``factor`` (4) times below the
input and FSNet at ``seg_factor`` (2) times below; both see the full-resolution gray image as
space-to-depth blocks and answer at full resolution by depth-to-space. Depth is a residual on
a local plane fitted to the returns around each pixel (``plane_fit.py``, its window following
the returns' spacing). Inputs are padded internally to the network's stride and cut back.
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
from sdcnet.training.model.plane_fit import AdaptivePlaneFit
from sdcnet.training.model.prefill import NearestReturnFill, near_wins_downsample

FSNET_INPUTS = ("both", "gray", "sparse")
DEPTH_INPUTS = 6  # channels of the depth branch's input (``SDCNet._regress``)
#: The spacecraft's mean gray level at its LIDAR returns after ``normalise_gray``.
GRAY_TARGET = 0.3
#: Bounds of the gain ``normalise_gray`` applies, and the ceiling of the scaled image (bright
#: Earth or Sun beside a dark spacecraft stay bright, not unbounded).
GRAY_GAIN = (0.5, 16.0)
GRAY_CEILING = 2.0


@dataclass(frozen=True)
class ModelConfig:
    """Architecture of one variant. Defaults: SDCNet as shipped."""

    factor: int = 4  # depth networks' working resolution = input / factor
    seg_factor: int = 2  # FSNet's resolution = input / seg_factor: the mask decides the score
    widths: tuple[int, ...] = (8, 16, 32, 48)
    fusion: str = "cca+sa"  # "cca+sa" (SDCNet), "cca", "sa", "guided" (GuideNet baseline)
    use_fsnet: bool = True  # False: the baseline regresses depth everywhere, no segmentation
    fsnet_inputs: str = "both"  # Table 4: "both", "gray", "sparse"
    fsnet_growth: int = 1  # FSNet's widths x this (1: the paper's ~5k parameters)
    fsnet_context: bool = False  # FSNet's coarse branch, which sees most of the crop at once
    grid: int = 4  # CCA regions per side: M = grid^2 regions whatever the input size
    heads: int = 4
    input_span_px: float = 256.0  # depth inputs: units of the metres this many pixels span
    residual_span_px: float = 16.0  # the residual head's unit, likewise
    mask_refiner: bool = True  # full-resolution refinement of FSNet's logits on the gray image
    sigma_per_scale: float = 1.14  # sigma / the Laplace scale: set by ``sdc-train calibrate``
    sigma_edge_weight: float = 0.0  # sigma's depth-edge term per metre of local depth range

    @property
    def stride(self) -> int:
        """Input sizes are padded to multiples of this."""
        coarsest = 2 ** (len(self.widths) - 1)
        return max(self.factor * max(coarsest, 4 * self.grid), 4 * self.seg_factor)

    def to_dict(self) -> dict:
        return asdict(self)

    def architecture_differences(self, other: ModelConfig) -> dict[str, tuple]:
        """Field -> (ours, theirs) where the two differ, leaving out sigma's calibration
        (``sdc-train calibrate`` sets it on a trained model; the weights do not depend on it)."""
        calibration = ("sigma_per_scale", "sigma_edge_weight")
        ours, theirs = self.to_dict(), other.to_dict()
        return {
            k: (v, theirs[k]) for k, v in ours.items() if k not in calibration and v != theirs[k]
        }

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        """A config as saved in a checkpoint."""
        return cls(**{**d, "widths": tuple(d["widths"])})

    def __post_init__(self):
        if self.factor % self.seg_factor:
            raise ValueError(
                f"factor {self.factor} must be a multiple of seg_factor {self.seg_factor}"
            )
        if self.fsnet_inputs not in FSNET_INPUTS:
            raise ValueError(f"fsnet_inputs must be one of {FSNET_INPUTS}")


VARIANTS: dict[str, ModelConfig] = {
    "sdcnet": ModelConfig(),
    "baseline": ModelConfig(fusion="guided", use_fsnet=False),  # GuideNet-style, no FSNet
    "fsnet": ModelConfig(fusion="guided"),  # baseline + FSNet
    "fsnet+cca": ModelConfig(fusion="cca"),
    "fsnet+sa": ModelConfig(fusion="sa"),
}


def build_model(variant: str = "sdcnet", **overrides) -> SDCNet:
    """SDCNet of a named variant (``VARIANTS``) with any config fields overridden."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose one of {sorted(VARIANTS)}")
    return SDCNet(replace(VARIANTS[variant], **overrides))


def reference_depth(sparse: torch.Tensor) -> torch.Tensor:
    """Mean LIDAR return per image (B, 1, 1, 1) metres; 0 when there is none."""
    total = sparse.sum(dim=(2, 3), keepdim=True)
    count = (sparse > 0).to(sparse.dtype).sum(dim=(2, 3), keepdim=True)
    return total / count.clamp_min(1.0)


def footprint_m(d_ref: torch.Tensor, focal_px: torch.Tensor) -> torch.Tensor:
    """Metres one pixel spans at the mean return's range (B, 1, 1, 1); 1 m without returns."""
    return torch.where(d_ref > 0, d_ref / focal_px.clamp_min(1e-6), torch.ones_like(d_ref))


def normalise_gray(gray: torch.Tensor, sparse: torch.Tensor) -> torch.Tensor:
    """Gray (B, 1, H, W) scaled so that its mean at the LIDAR returns (the spacecraft, whatever
    the sky behind it) is ``GRAY_TARGET``: an 8-bit frame and a 12-bit one stored in 16 bits,
    an under- and an over-exposed one, look alike. Gain within ``GRAY_GAIN``; 1 without
    returns; values capped at ``GRAY_CEILING``."""
    returns = (sparse > 0).to(gray.dtype)
    count = returns.sum(dim=(2, 3), keepdim=True)
    mean = (gray * returns).sum(dim=(2, 3), keepdim=True) / count.clamp_min(1.0)
    gain = (GRAY_TARGET / mean.clamp_min(1e-4)).clamp(*GRAY_GAIN)
    gain = torch.where(count > 0, gain, torch.ones_like(gain))
    return (gray * gain).clamp_max(GRAY_CEILING)


#: Side (pixels) of the window over which sigma's depth-edge term reads the predicted depth and
#: mask: a pixel's sigma depends on the foreground decisions within half of it.
SPREAD_WINDOW = 5


def local_depth_spread(
    depth: torch.Tensor, foreground: torch.Tensor, size: int = SPREAD_WINDOW
) -> torch.Tensor:
    """(B, 1, H, W) metres: max - min of ``depth`` over the foreground pixels of the ``size`` x
    ``size`` window around each foreground pixel; 0 off the foreground."""
    pad = size // 2
    far = torch.where(foreground, depth, torch.zeros_like(depth))
    near = torch.where(foreground, -depth, torch.full_like(depth, -1e6))
    high = F.max_pool2d(far, size, stride=1, padding=pad)
    low = -F.max_pool2d(near, size, stride=1, padding=pad)
    return torch.where(foreground, high - low, torch.zeros_like(depth))


class SDCNet(nn.Module):
    def __init__(self, config: ModelConfig = ModelConfig()):
        super().__init__()
        self.config = config
        self.prefill = NearestReturnFill()
        self.plane_fit = AdaptivePlaneFit(factor=config.factor)
        blocks = config.seg_factor**2  # full-resolution pixels per FSNet pixel
        fs_channels = {"both": blocks + 3, "gray": blocks, "sparse": 3}[config.fsnet_inputs]
        self.fsnet = (
            FSNet(
                in_channels=fs_channels,
                out_channels=blocks,
                growth=config.fsnet_growth,
                context=config.fsnet_context,
            )
            if config.use_fsnet
            else None
        )
        self.refiner = (
            MaskRefiner(block=config.seg_factor)
            if config.use_fsnet and config.mask_refiner
            else None
        )
        cells = config.factor**2  # sub-pixel outputs per working pixel
        self.fdcnet = FDCNet(
            gray_channels=cells,
            depth_channels=DEPTH_INPUTS,
            out_channels=cells,
            widths=config.widths,
            fusion=config.fusion,
            grid=config.grid,
            heads=config.heads,
        )
        # start from the plane fit itself: the residual head begins at zero
        nn.init.zeros_(self.fdcnet.head.weight)
        nn.init.zeros_(self.fdcnet.head.bias)

    def float_modules(self) -> tuple[str, ...]:
        """Names of the modules that INT8 export keeps in float (``sdcnet.export.variants``):
        the depth head, whose output the residual unit scales to metres, and FSNet's head,
        whose outputs are the full-resolution mask logits (a variant without FSNet has only
        the first). ``tests/test_export.py`` checks that each name is a convolution of every
        variant, so renaming a head breaks the test rather than quantising the head."""
        return ("fdcnet.head", "fsnet.head") if self.fsnet is not None else ("fdcnet.head",)

    def segmentation_parameters(self) -> list[nn.Parameter]:
        """Stage 1 trains these; stage 2 freezes them."""
        parts = [m for m in (self.fsnet, self.refiner) if m is not None]
        return [p for m in parts for p in m.parameters()]

    def residual_unit(self, sparse: torch.Tensor, focal_px: torch.Tensor) -> torch.Tensor:
        """Metres of one unit of the residual head (B, 1, 1, 1): also the depth loss's unit,
        so that a frame at 3 m and one at 250 m weigh alike in training."""
        return self.config.residual_span_px * footprint_m(reference_depth(sparse), focal_px)

    def _prepare(
        self, gray: torch.Tensor, sparse: torch.Tensor, focal_px: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """Padded, normalised full-resolution gray; the sparse map at full, FSNet's and the
        depth networks' resolutions; the nearest-return fill at the latter; the mean return
        and the depth inputs' unit."""
        H, W = gray.shape[-2:]
        s = self.config.stride
        pad = (0, (s - W % s) % s, 0, (s - H % s) % s)
        gray_p, sparse_p = F.pad(gray, pad), F.pad(sparse, pad)
        sparse_seg = near_wins_downsample(sparse_p, self.config.seg_factor)
        sparse_lr = near_wins_downsample(sparse_seg, self.config.factor // self.config.seg_factor)
        filled, reach = self.prefill(sparse_lr)
        d_ref = reference_depth(sparse_p)
        return {
            "gray": normalise_gray(gray_p, sparse_p),
            "sparse": sparse_p,
            "sparse_seg": sparse_seg,
            "filled": filled,
            "reach": reach,
            "d_ref": d_ref,
            "unit": self.config.input_span_px * footprint_m(d_ref, focal_px),
        }

    def _segment(self, x: dict[str, torch.Tensor]) -> torch.Tensor:
        """Foreground probability at full (padded) resolution."""
        seg = self.config.seg_factor
        returns = (x["sparse_seg"] > 0).to(x["gray"].dtype)
        relative = returns * (x["sparse_seg"] - x["d_ref"]) / x["unit"]
        reach = F.interpolate(x["reach"], size=returns.shape[-2:], mode="nearest")
        blocks = space_to_depth(x["gray"], seg)  # space-to-depth: full-resolution detail
        fs_in = {
            "both": [blocks, returns, relative, reach],
            "gray": [blocks],
            "sparse": [returns, relative, reach],
        }[self.config.fsnet_inputs]
        logit_blocks = self.fsnet(torch.cat(fs_in, 1))
        if self.refiner is not None:
            logit_blocks = self.refiner(blocks, logit_blocks)
        return torch.sigmoid(F.pixel_shuffle(logit_blocks, seg))

    def _regress(
        self, x: dict[str, torch.Tensor], focal_px: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Dense depth and its sigma in metres at full (padded) resolution: the local plane
        fit (else the nearest return, else the mean return) plus the residual FDCNet
        regresses from the gray image and the pre-fills."""
        d_ref, unit = x["d_ref"], x["unit"]
        plane, weight, level = self.plane_fit(x["sparse"], d_ref)
        fitted = (weight > 0).to(plane.dtype)
        filled = x["filled"]
        valid = (filled > 0).to(filled.dtype)
        depth_in = [
            fitted * (plane - d_ref) / unit,
            fitted,
            valid * (filled - d_ref) / unit,
            valid,
            level,
            x["reach"],
        ]
        base_lr = torch.where(weight > 0, plane, torch.where(filled > 0, filled, d_ref))
        gray = space_to_depth(x["gray"], self.config.factor)
        out, log_scale = self.fdcnet(gray, torch.cat(depth_in, 1))
        residual = F.pixel_shuffle(out, self.config.factor)
        scale = torch.exp(F.pixel_shuffle(log_scale, self.config.factor).clamp(-12.0, 8.0))
        unit_out = self.config.residual_span_px * footprint_m(d_ref, focal_px)
        depth = self._upsample(base_lr) + unit_out * residual
        return depth, self.config.sigma_per_scale * unit_out * scale

    def _upsample(self, x: torch.Tensor) -> torch.Tensor:
        """Working resolution -> full resolution, bilinear between cell centres."""
        return F.interpolate(
            x, scale_factor=self.config.factor, mode="bilinear", align_corners=False
        )

    def segment(
        self, gray: torch.Tensor, sparse: torch.Tensor, focal_px: torch.Tensor
    ) -> torch.Tensor:
        """Foreground probability (B, 1, H, W) alone: what stage 1 trains, at a fraction of
        the cost of the whole network."""
        H, W = gray.shape[-2:]
        return self._segment(self._prepare(gray, sparse, focal_px))[..., :H, :W]

    def forward(
        self, gray: torch.Tensor, sparse: torch.Tensor, focal_px: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Depth (metres), foreground probability, sigma (metres), each (B, 1, H, W)."""
        H, W = gray.shape[-2:]
        x = self._prepare(gray, sparse, focal_px)
        depth, sigma = self._regress(x, focal_px)
        if self.fsnet is not None:
            prob = self._segment(x)
        else:  # no segmentation: foreground where the regressed depth is not background
            prob = (depth > 0.5 * x["d_ref"]).to(depth.dtype)
        if self.config.sigma_edge_weight > 0 and not self.training:
            spread = self.config.sigma_edge_weight * local_depth_spread(depth, prob > 0.5)
            sigma = torch.sqrt(sigma * sigma + spread * spread)
        return depth[..., :H, :W], prob[..., :H, :W], sigma[..., :H, :W]
