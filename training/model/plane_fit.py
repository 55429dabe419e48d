"""Interpolating pre-fill: a local plane fitted to the LIDAR returns around every pixel.

The morphological pre-fill (``prefill.py``) copies the nearest return over its neighbours, so a
tilted surface comes out as steps with the period of the beam rows, and the network has to undo
them. Here every pixel of the working resolution gets the value at its centre of the plane
z = a + b x + c y fitted by weighted least squares to the returns around it (first-order
normalised convolution, Knutsson & Westin 1993): exact on planes, linear between returns, and the
range noise (< 3 cm) averaged over several returns, so the network regresses only a residual.

Returns keep their full-resolution positions: each working-resolution cell remembers where in its
``factor`` x ``factor`` block its (nearest) return lies, and the fit uses those offsets, so a
return is never moved by up to half a cell on a slope. Distances are in full-resolution pixels.

All of it is fixed convolutions and element-wise arithmetic, so it exports to ONNX as is:
space-to-depth and a 1 x 1 convolution gather the per-cell moments, a separable pair of
convolutions sums them under a Gaussian window, and the 2 x 2 normal equations of the slopes are
solved in closed form.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import nn
from torch.nn import functional as F

from sdcnet.training.model.blocks import space_to_depth
from sdcnet.training.model.prefill import near_wins_downsample

#: Channels per cell, in order: presence c, then c times dx, dy, dx^2, dy^2, dx dy, and
#: c times the depth z (relative to the reference), z dx, z dy (dx, dy: the return's offset
#: from the cell's centre, full-resolution pixels).
CELL_CHANNELS = ("c", "dx", "dy", "dxx", "dyy", "dxy", "z", "zdx", "zdy")
#: The window sums of the fit: S0 = sum w c, Sx = sum w c X, ..., Sz = sum w c z, Szx, Szy.
MOMENTS = ("S0", "Sx", "Sy", "Sxx", "Syy", "Sxy", "Sz", "Szx", "Szy")


def _separable_terms(factor: int) -> dict[str, list[tuple[str, int, int, float]]]:
    """Each moment as a sum of terms (cell channel, power of u, power of v, coefficient), where
    a neighbour cell lies u columns and v rows away, so its return sits at X = factor u + dx,
    Y = factor v + dy from the output cell's centre (full-resolution pixels)."""
    f = float(factor)
    return {
        "S0": [("c", 0, 0, 1.0)],
        "Sx": [("c", 1, 0, f), ("dx", 0, 0, 1.0)],
        "Sy": [("c", 0, 1, f), ("dy", 0, 0, 1.0)],
        "Sxx": [("c", 2, 0, f * f), ("dx", 1, 0, 2 * f), ("dxx", 0, 0, 1.0)],
        "Syy": [("c", 0, 2, f * f), ("dy", 0, 1, 2 * f), ("dyy", 0, 0, 1.0)],
        "Sxy": [("c", 1, 1, f * f), ("dy", 1, 0, f), ("dx", 0, 1, f), ("dxy", 0, 0, 1.0)],
        "Sz": [("z", 0, 0, 1.0)],
        "Szx": [("z", 1, 0, f), ("zdx", 0, 0, 1.0)],
        "Szy": [("z", 0, 1, f), ("zdy", 0, 0, 1.0)],
    }


class PlaneFitPrefill(nn.Module):
    """Sparse depth (B, 1, H, W) metres -> locally planar depth (B, 1, H/f, W/f) metres and the
    window weight of the returns behind each value (B, 1, H/f, W/f); H, W multiples of ``factor``.

    ``sigma_px`` (rows, columns): the Gaussian window in full-resolution pixels, half a beam
    spacing (returns ~18 px apart vertically, ~12.5 px horizontally on the paper's camera): the
    fit leans on the few nearest returns, so it follows the surface they lie on rather than
    averaging across depth edges (on 12 test frames, a window of one spacing had a depth error
    of 0.184 m on the fill's pixels, half a spacing 0.130 m, a quarter 0.134 m).
    ``ridge_px2`` keeps the slopes defined when the returns around a pixel lie on one line.
    """

    def __init__(
        self,
        *,
        factor: int = 4,
        sigma_px: tuple[float, float] = (9.0, 6.0),
        ridge_px2: float = 0.5,
    ):
        super().__init__()
        self.factor = factor
        self.ridge_px2 = ridge_px2
        f = factor
        offsets = torch.arange(f, dtype=torch.float32) - (f - 1) / 2
        dy, dx = torch.meshgrid(offsets, offsets, indexing="ij")
        dx, dy = dx.reshape(-1), dy.reshape(-1)  # pixel_unshuffle's channel order: row-major
        gather = torch.stack([torch.ones_like(dx), dx, dy, dx * dx, dy * dy, dx * dy])
        self.register_buffer("gather", gather[:, :, None, None], persistent=False)
        radius = [math.ceil(2 * s / f) for s in sigma_px]  # cells: the window reaches 2 sigma
        cells = [torch.arange(-r, r + 1, dtype=torch.float32) for r in radius]
        window = [torch.exp(-0.5 * (f * c / s) ** 2) for c, s in zip(cells, sigma_px, strict=True)]
        terms = _separable_terms(f)
        # Horizontal pass: one intermediate channel per distinct (cell channel, power of u),
        # then the vertical pass combines them with the powers of v into the nine moments.
        rows = sorted({(ch, pu) for ts in terms.values() for ch, pu, _, _ in ts})
        horizontal = torch.zeros(len(rows), len(CELL_CHANNELS), 1, len(cells[1]))
        for i, (ch, pu) in enumerate(rows):
            horizontal[i, CELL_CHANNELS.index(ch), 0] = window[1] * cells[1] ** pu
        vertical = torch.zeros(len(MOMENTS), len(rows), len(cells[0]), 1)
        for m, name in enumerate(MOMENTS):
            for ch, pu, pv, coeff in terms[name]:
                vertical[m, rows.index((ch, pu)), :, 0] += coeff * window[0] * cells[0] ** pv
        self.register_buffer("horizontal", horizontal, persistent=False)
        self.register_buffer("vertical", vertical, persistent=False)
        self.padding = radius
        #: Weight of one return at one sigma in both directions: less than this is no support.
        self.min_weight = math.exp(-1.0)

    def cell_channels(self, sparse: torch.Tensor, d_ref: torch.Tensor) -> torch.Tensor:
        """(B, 9, H/f, W/f): each cell's nearest return (presence, offsets, depth minus
        ``d_ref``) as the products the moments need; 0 where a cell holds no return."""
        f = self.factor
        nearest = near_wins_downsample(sparse, f)
        expanded = F.interpolate(nearest, scale_factor=f, mode="nearest")
        winner = ((sparse > 0) & ((sparse - expanded).abs() < 1e-3)).to(sparse.dtype)
        sums = F.conv2d(space_to_depth(winner, f), self.gather)
        count = sums[:, :1]
        present = (count > 0).to(sparse.dtype)
        mean = sums / count.clamp_min(1.0)  # ties (equal depths in one cell): mean offset
        z = present * (nearest - d_ref)
        dx, dy = mean[:, 1:2], mean[:, 2:3]
        return torch.cat([present, mean[:, 1:6] * present, z, z * dx, z * dy], 1)

    def forward(
        self, sparse: torch.Tensor, d_ref: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``d_ref`` (B, 1, 1, 1) metres: subtracted before the fit for float32 precision."""
        fit = self.fit(self.cell_channels(sparse, d_ref), d_ref)
        return fit.plane, fit.weight

    def fit(self, cells: torch.Tensor, d_ref: torch.Tensor) -> Fit:
        """The fit at every cell from ``cell_channels``' output (computed once when several
        windows fit the same returns)."""
        py, px = self.padding
        moments = F.conv2d(
            F.conv2d(cells, self.horizontal, padding=(0, px)), self.vertical, padding=(py, 0)
        )
        S0, Sx, Sy, Sxx, Syy, Sxy, Sz, Szx, Szy = moments.split(1, 1)
        supported = self.min_weight < S0
        inv = 1.0 / S0.clamp_min(self.min_weight)
        mx, my, mz = Sx * inv, Sy * inv, Sz * inv
        cxx = Sxx * inv - mx * mx + self.ridge_px2  # weighted covariances, ridge on the slopes
        cyy = Syy * inv - my * my + self.ridge_px2
        cxy = Sxy * inv - mx * my
        czx = Szx * inv - mz * mx
        czy = Szy * inv - mz * my
        det = cxx * cyy - cxy * cxy
        slope_x = (czx * cyy - czy * cxy) / det
        slope_y = (cxx * czy - cxy * czx) / det
        plane = d_ref + mz - slope_x * mx - slope_y * my  # the plane at the cell's centre
        half_trace = (cxx + cyy) / 2 - self.ridge_px2
        zero = torch.zeros_like(S0)
        return Fit(
            torch.where(supported, plane, zero),
            torch.where(supported, S0, zero),
            half_trace - torch.sqrt(((cxx - cyy) / 2) ** 2 + cxy * cxy),
            torch.where(supported, slope_x, zero),
            torch.where(supported, slope_y, zero),
        )


class Fit(NamedTuple):
    """A plane fit at every cell (B, 1, h, w): the plane at the cell's centre (metres, 0 where
    unsupported), the window weight of its returns (0 = unsupported), their spread (the
    smaller eigenvalue of the weighted covariance of their positions, px^2: near 0 when they
    lie on one line, whose slope across it the fit cannot know) and the slopes (metres per
    full-resolution pixel along columns and rows)."""

    plane: torch.Tensor
    weight: torch.Tensor
    spread: torch.Tensor
    slope_x: torch.Tensor
    slope_y: torch.Tensor

    def upsampled(self, cell_px: float) -> Fit:
        """The fit on a grid twice as fine: each cell of ``cell_px`` full-resolution pixels
        split in four, the plane evaluated at the new cells' centres (a quarter cell off)."""
        q = cell_px / 4
        plane = torch.cat(
            [
                self.plane + q * (sx * self.slope_x + sy * self.slope_y)
                for sy in (-1, 1)
                for sx in (-1, 1)
            ],
            1,
        )  # pixel_shuffle's order: sub-row, then sub-column
        twice = [F.pixel_shuffle(plane, 2)]
        for t in self[1:]:
            twice.append(F.interpolate(t, scale_factor=2, mode="nearest"))
        return Fit(*twice)


class AdaptivePlaneFit(nn.Module):
    """The plane fit with a window that follows the returns' spacing, pixel by pixel.

    One window cannot serve every LIDAR: half the paper's beam spacing (9 x 6 px) finds no
    return between the rows of a 16-beam sensor 100 px apart and averages across depth edges
    where a flash array puts a return on every other pixel. Here the fit runs with isotropic
    windows ``sigmas_px`` (full-resolution pixels, finest first) and each cell takes the finest
    whose window weight reaches ``min_support`` (about one return at the window's centre, or
    several around it) and whose returns spread across the window in every direction (the
    smaller eigenvalue of their positions' covariance at least (``min_spread`` sigma)^2: a
    window that sees one scan line cannot tell the slope across it), else the coarsest with
    any support. Sparse (B, 1, H, W) metres ->
    plane (B, 1, H/f, W/f) metres (0 = none), weight (B, 1, H/f, W/f) (0 = none) and level
    (B, 1, H/f, W/f): the chosen window's index over the count of windows (1 = none), which
    tells the network how far apart the returns are around each cell.
    """

    def __init__(
        self,
        *,
        factor: int = 4,
        sigmas_px: tuple[float, ...] = (3.0, 6.0, 12.0, 24.0),
        min_support: float = 1.0,
        min_spread: float = 0.25,
        ridge_px2: float = 0.5,
        coarse_from: int = 2,
    ):
        super().__init__()
        # The coarsest window is the fallback where no finer one sees returns spread around
        # it: a few far returns, often on one line, whose slopes would swing the plane by
        # their float32 rounding. Its ridge grows with its area; the others are well posed.
        ridges = [ridge_px2] * (len(sigmas_px) - 1)
        ridges.append(ridge_px2 * (sigmas_px[-1] / sigmas_px[0]) ** 2)
        # Windows from ``coarse_from`` on are fitted on cells twice as large (a quarter of the
        # cost; they serve where returns are sparse) and evaluated at the finer cells' centres.
        self.factors = [factor * (2 if k >= coarse_from else 1) for k in range(len(sigmas_px))]
        self.fits = nn.ModuleList(
            PlaneFitPrefill(factor=f, sigma_px=(s, s), ridge_px2=r)
            for f, s, r in zip(self.factors, sigmas_px, ridges, strict=True)
        )
        self.min_support = min_support
        self.min_spread_px2 = [(min_spread * s) ** 2 for s in sigmas_px]

    def _fit(self, k: int, cells: dict[int, torch.Tensor], d_ref: torch.Tensor) -> Fit:
        """Window ``k``'s fit on the finest cells."""
        fit = self.fits[k].fit(cells[self.factors[k]], d_ref)
        return fit.upsampled(self.factors[k]) if self.factors[k] != self.factors[0] else fit

    def forward(
        self, sparse: torch.Tensor, d_ref: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        first = {f: self.fits[self.factors.index(f)] for f in set(self.factors)}
        cells = {f: fit.cell_channels(sparse, d_ref) for f, fit in first.items()}
        count = len(self.fits)
        coarsest = self._fit(count - 1, cells, d_ref)
        plane, weight = coarsest.plane, coarsest.weight
        level = torch.where(weight > 0, torch.full_like(weight, (count - 1) / count), 1.0)
        for k in range(count - 2, -1, -1):  # finer windows overwrite where they are supported
            fit = self._fit(k, cells, d_ref)
            chosen = (fit.weight >= self.min_support) & (fit.spread >= self.min_spread_px2[k])
            plane = torch.where(chosen, fit.plane, plane)
            weight = torch.where(chosen, fit.weight, weight)
            level = torch.where(chosen, torch.full_like(level, k / count), level)
        return plane, weight, level
