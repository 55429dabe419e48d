"""Depth anchored to the LIDAR returns: where the sensor measured, the answer agrees with it.

The network's depth is a smooth surface: plane fits to the returns at a quarter of the working
resolution, upsampled. At a return it can be off the measurement by centimetres on a panel
and by metres next to a depth edge, where a fit's window straddles two surfaces; a classical
fill, which repeats the nearest return, is then the better answer next to the returns. This
module corrects the depth by its residuals at the returns (measured - predicted, metres):

1. the residuals within ``SHRINK`` times the frame's noise scale (their median absolute
   value, as a standard deviation) are the LIDAR's noise: a soft threshold takes that much
   off every residual, so that on a panel the model fits well the noise is not copied into
   the surface and the normals stay, while an error far above the noise (a depth edge) is
   corrected, less the noise. Most returns lie on surfaces the model fits, so the median
   measures the noise; a bias of the whole surface up to the cap below is mostly taken for
   noise too (``SHRINK`` x ``MAD_TO_STD``, three quarters of it, is left; the rest is
   corrected near the returns). A LIDAR's noise is centimetres, not metres: the noise scale
   is at most ``MAX_NOISE_M`` or ``MAX_NOISE_OF_DEPTH`` of the returns' median depth,
   whichever is larger; above that the median measures the network's misfit (a few returns
   on a structure the surface smoothed over) and is corrected as one;
2. the corrections are spread by a normalised Gaussian convolution (``sigma_px``
   from the returns' spacing): at a return the correction is mostly its own, between returns a
   weighted mean of the near ones, and it fades to nothing a few ``sigma_px`` away from any;
3. where the surface missed its returns by far more than the noise (the local *misfit*, the
   spread residuals' size, above ``UNRELIABLE_MISFIT_NOISES`` noise scales: a plane fitted
   across a depth edge, a slope the few returns around it got wrong), the returns are the
   better answer next to them: the depth goes linearly from the nearest return's at the
   return to the corrected surface's ``TRUST_RETURN_KERNELS`` kernel widths away. A slope a
   plane got wrong still tilts the corrected surface between its returns (the fill, which
   repeats the nearest return, had the lower error within 3 px of the returns on the frames
   of few or scattered returns); where the surface fits, nothing changes. Nor where the
   nearest return lies across a depth edge (its depth steeper than
   ``EDGE_FOOTPRINTS_PER_PX`` pixel footprints per pixel of the way from the surface): a
   ramp there would put points between the two surfaces.

Anchoring changes how far the depth can be trusted, and the returns say how good the network
was on this frame, so the network's sigma is recombined with what they measured
(``anchored_sigma``): it is first rescaled by the frame's median ratio of the network's error
at the returns to its sigma there (a frame of another camera, LIDAR or sky is harder or easier
than the frames sigma was calibrated on, and the returns show which; a handful of returns,
which the network saw and copied, shows only that it copied them, so from fewer than
``MIN_RETURNS_FOR_RATIO`` the ratio never lowers the network's own sigma); it counts
``SIGMA_AT_RETURN`` times at a return and grows with the lateral distance to the nearest
return in metres (``SIGMA_PER_APART_M``: a surface strays from what was measured on it with
how far one goes, whatever the camera or LIDAR; a distance in pixels or in return spacings
would change with them); where the network missed the returns by more than the noise, the
depth between them is uncertain by about as much (the *misfit*); where the depth differs from
the nearest return's, a depth edge or a steep surface may lie between them (the
*disagreement*); and no depth is better than the LIDAR's own noise. Last, the whole is shaped
by where the pixel lies on the grid the network saw (``shaped_by_grid``): the surface is held
by the returns within the network's reach on that grid, so the sigma grows with the distance
to the nearest return in working pixels, and next to the mask's outline a pixel may straddle
the silhouette.

It runs on the working grid, so it costs the same (a few milliseconds) whatever the camera and
the frame's size. The choice of ``SIGMA_PER_SPACING``, ``SIGMA_BOUNDS_PX`` and ``SHRINK``, and
the fit of the sigma's coefficients: docs/development.md, "Measurements".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: The spreading kernel's standard deviation, in return spacings ...
SIGMA_PER_SPACING = 0.75
#: ... within these bounds, in the frame's pixels: at least a pixel's neighbourhood, at most
#: what keeps a correction on the part of the spacecraft it was measured on.
SIGMA_BOUNDS_PX = (1.5, 6.0)
#: Residuals within this many noise scales (``MAD_TO_STD`` x their median absolute value) are
#: taken as the LIDAR's noise.
SHRINK = 0.5
#: Median absolute deviation -> standard deviation, for Gaussian noise.
MAD_TO_STD = 1.4826
#: The noise scale is at most this many metres or this share of the returns' median depth,
#: whichever is larger: about the range noise of the LIDARs flown (a few cm, growing with the
#: distance); a noisier one keeps more of its noise next to the returns, as the fill keeps
#: all of it (docs/development.md, "Measurements").
MAX_NOISE_M = 0.06
MAX_NOISE_OF_DEPTH = 1e-3

#: Where the local misfit exceeds this many noise scales (``noise_m``, at least
#: ``MIN_NOISE_M``) ...
UNRELIABLE_MISFIT_NOISES = 3.0
#: ... the depth goes from the nearest return's to the corrected surface's over this many
#: kernel widths (``sigma_px``) from the return (docs/development.md, "Measurements").
TRUST_RETURN_KERNELS = 2.0
#: The smallest noise scale the misfit is compared with, metres (a frame whose residuals are
#: all zero has no measured noise).
MIN_NOISE_M = 1e-3
#: A nearest return whose depth differs from the surface's by more than this many pixel
#: footprints (depth / focal length) per pixel between them is across a depth edge.
EDGE_FOOTPRINTS_PER_PX = 8.0

#: ``anchored_sigma``'s coefficients (fit on validation frames of the mixed world, the last
#: four refitted on the `any` world's: docs/development.md, "Measurements"): the network's
#: sigma, rescaled by the frame's error ratio at the returns, counts ``SIGMA_AT_RETURN`` times
#: at a return, and ``SIGMA_PER_APART_M`` times per metre of lateral distance to the nearest
#: return, in quadrature; ...
SIGMA_AT_RETURN = 1.15
SIGMA_PER_APART_M = 15.3
#: ... the local misfit (metres), the frame's noise (metres, a standard deviation) and the
#: disagreement with the nearest return (metres) this many times, all in quadrature.
SIGMA_PER_MISFIT = 1.0
SIGMA_PER_NOISE = 0.44
SIGMA_PER_DISAGREEMENT = 0.88
#: The frame's error ratio is at least this: a network that fits the returns exactly is not
#: exact between them.
MIN_ERROR_RATIO = 0.02
#: From fewer returns on the mask than this, the ratio is at least ``NETWORK_RATIO``: the
#: network sees the returns, so its error at a few of them says little of its error between
#: them (flash and multi-beam frames of 1-6 returns on a boom, matched within 2 cm, were off
#: by metres a little further; docs/development.md, "Measurements").
MIN_RETURNS_FOR_RATIO = 20
#: The ratio that leaves ``recombined_sigma`` the network's own sigma at a return.
NETWORK_RATIO = 1.0 / SIGMA_AT_RETURN
#: ``shaped_by_grid``: the sigma times (1 + the distance to the nearest return in working
#: pixels) to this power (the metres of ``SIGMA_PER_APART_M`` alone left the pixels next to a
#: return over-covered, 90 % within one sigma, and those 16 working pixels or more away under-
#: covered, 65 %, whatever the camera: the network's reach is in the pixels it sees) ...
SIGMA_APART_PX_POWER = 0.2
#: ... times up to 1 + ``SIGMA_OUTLINE_GAIN`` at the mask's outline, fading over
#: ``SIGMA_OUTLINE_PX`` working pixels inside it (the outline's pixels, 58-68 % within one
#: sigma, may lie across the silhouette, the interior's 84 %) ...
SIGMA_OUTLINE_GAIN = 0.6
SIGMA_OUTLINE_PX = 3.0
#: ... and times this, so that 70-76 % of the errors are within one sigma and nine tenths
#: within two (the errors' tails are heavier than a Gaussian's: no one scale gives 68 and
#: 95 %; docs/development.md, "Measurements").
SIGMA_SCALE = 0.415


@dataclass(frozen=True)
class Anchored:
    """The anchored depth (h, w metres) and what anchoring measured on the same grid: how far
    each pixel lies from the nearest return (``apart_m``, metres across the line of sight: its
    distance in pixels times its depth's footprint), how far its depth is from that return's
    (``disagreement_m``, metres: what a fill that repeats the nearest return would answer
    differs by this much), the local ``misfit`` (metres: the kernel-weighted mean of the
    returns' residuals less the noise), the frame's ``noise_m`` (metres, the residuals' robust
    standard deviation), and where the returns on the mask are (``rows``, ``cols``) with the
    depth's ``residual`` there (metres, measured - predicted, before anchoring); ``apart_px``
    is the distance to the nearest return in the grid's pixels, ``nearest_m`` that return's
    depth (metres)."""

    depth: np.ndarray
    apart_px: np.ndarray
    nearest_m: np.ndarray
    apart_m: np.ndarray
    disagreement_m: np.ndarray
    misfit: np.ndarray
    noise_m: float
    rows: np.ndarray
    cols: np.ndarray
    residual: np.ndarray


def spreading_sigma_px(spacing_px: float | None, frame_px_per_pixel: float) -> float:
    """The kernel's standard deviation in the grid's pixels, for returns ``spacing_px`` apart
    on that grid (None: unknown) and ``frame_px_per_pixel`` frame pixels per grid pixel."""
    low, high = SIGMA_BOUNDS_PX
    if spacing_px is None:
        frame_sigma = high
    else:
        frame_sigma = min(max(SIGMA_PER_SPACING * spacing_px * frame_px_per_pixel, low), high)
    return max(frame_sigma / frame_px_per_pixel, 1.0)


def anchor_to_returns(
    depth: np.ndarray, mask: np.ndarray, sparse: np.ndarray, sigma_px: float, focal_px: float
) -> Anchored:
    """``depth`` (H, W metres) corrected by its residuals at the returns of ``sparse`` (H, W
    metres, 0 = none) that fall on ``mask`` (H, W bool, the spacecraft: returns off it are
    not the depth's to agree with), spread with a Gaussian of ``sigma_px`` pixels, and
    drawn to the nearest return's depth next to the returns where it missed them (step 3 of
    the module's docstring); unchanged (apart, disagreement, misfit and noise 0) without such
    returns. The correction covers the whole grid, so that resampling the mask to the frame
    never meets an uncorrected pixel at its border. ``focal_px``: the grid's focal length in
    its pixels, for ``apart_m``."""
    rows, cols = np.nonzero((sparse > 0) & mask & (depth > 0))
    if len(rows) == 0:
        nothing = np.zeros(depth.shape, np.float32)
        none = np.zeros(0, np.float32)
        return Anchored(depth, nothing, nothing, nothing, nothing, nothing, 0.0, rows, cols, none)
    measured = sparse[rows, cols]
    residual = measured - depth[rows, cols]
    noise_m = min(
        MAD_TO_STD * float(np.median(np.abs(residual))),
        max(MAX_NOISE_M, MAX_NOISE_OF_DEPTH * float(np.median(measured))),
    )
    local = np.sign(residual) * np.maximum(np.abs(residual) - SHRINK * noise_m, 0.0)
    _, centre = gaussian_kernel(sigma_px)

    def spread(values: np.ndarray) -> np.ndarray:
        return spread_at(rows, cols, values, depth.shape, sigma_px)

    count = spread(np.ones(len(rows), np.float32))
    total = np.maximum(count, 1e-12)
    reach = np.minimum(count / centre, 1.0)  # 1 at a return, fading away from them
    correction = reach * spread(local) / total
    misfit = spread(np.abs(local)) / total
    corrected = (depth + correction).astype(np.float32)
    apart_px, nearest = nearest_return(sparse)
    unreliable = misfit > UNRELIABLE_MISFIT_NOISES * max(noise_m, MIN_NOISE_M)
    corrected = returns_where_missed(corrected, unreliable, apart_px, nearest, sigma_px, focal_px)
    apart_m = apart_px * np.abs(corrected) / focal_px  # pixels -> metres
    disagreement_m = np.abs(corrected - nearest)
    return Anchored(
        corrected, apart_px, nearest, apart_m, disagreement_m, misfit, noise_m, rows, cols, residual
    )


def gaussian_kernel(sigma_px: float) -> tuple[int, float]:
    """The side (pixels, 2 sigma each way) of a 2-D Gaussian kernel of ``sigma_px`` pixels and
    its peak: ones at isolated pixels, blurred with it and divided by the peak, are 1 there."""
    size = 2 * math.ceil(2 * sigma_px) + 1
    return size, float(cv2.getGaussianKernel(size, sigma_px)[size // 2, 0]) ** 2


def spread_at(
    rows: np.ndarray, cols: np.ndarray, values: np.ndarray, shape: tuple[int, int], sigma_px: float
) -> np.ndarray:
    """``values`` at the pixels (``rows``, ``cols``) of a grid of ``shape``, 0 elsewhere,
    blurred with the Gaussian kernel of ``sigma_px`` pixels (``gaussian_kernel``; nothing
    beyond the grid's border): float32 ``shape``."""
    size, _ = gaussian_kernel(sigma_px)
    grid = np.zeros(shape, np.float32)
    grid[rows, cols] = values
    return cv2.GaussianBlur(grid, (size, size), sigma_px, borderType=cv2.BORDER_CONSTANT)


def returns_where_missed(
    surface: np.ndarray,
    unreliable: np.ndarray,
    apart_px: np.ndarray,
    nearest: np.ndarray,
    sigma_px: float,
    focal_px: float,
) -> np.ndarray:
    """Step 3 of the module's docstring: on the ``unreliable`` pixels (h, w bool, where the
    corrected ``surface`` (h, w metres) missed its returns), the depth from the ``nearest``
    return's (metres, ``apart_px`` grid pixels away: ``nearest_return``) at the return to the
    surface's ``TRUST_RETURN_KERNELS`` x ``sigma_px`` away, but not towards a return across a
    depth edge (``EDGE_FOOTPRINTS_PER_PX``; ``focal_px``: the grid's focal length); float32."""
    step_footprints = np.abs(surface - nearest) * focal_px / np.maximum(np.abs(surface), 1e-6)
    same_surface = step_footprints <= EDGE_FOOTPRINTS_PER_PX * np.maximum(apart_px, 1.0)
    towards_surface = np.minimum(apart_px / (TRUST_RETURN_KERNELS * sigma_px), 1.0)
    ramp = nearest + (surface - nearest) * towards_surface
    return np.where(unreliable & same_surface, ramp, surface).astype(np.float32)


def nearest_return(sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel of ``sparse`` (h, w metres, 0 = no return, at least one return): its
    distance to the nearest return (pixels) and that return's depth (metres), float32 (h, w).
    One distance transform with labels: each return is its own label, numbered in row-major
    order from 1."""
    apart_px, labels = cv2.distanceTransformWithLabels(
        cv2.compare(sparse, 0, cv2.CMP_LE), cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL
    )
    depths = np.concatenate([np.zeros(1, np.float32), sparse[sparse > 0]])
    return apart_px, depths[labels]


def error_ratio(sigma: np.ndarray, anchored: Anchored) -> float:
    """The frame's median of |residual| / ``sigma`` at the returns on the mask (at least
    ``MIN_ERROR_RATIO``, and at least ``NETWORK_RATIO`` from fewer than
    ``MIN_RETURNS_FOR_RATIO`` returns); without such returns, ``NETWORK_RATIO``."""
    if anchored.residual.size == 0:
        return NETWORK_RATIO
    at_returns = np.maximum(sigma[anchored.rows, anchored.cols], 1e-9)
    ratio = max(float(np.median(np.abs(anchored.residual) / at_returns)), MIN_ERROR_RATIO)
    return ratio if anchored.residual.size >= MIN_RETURNS_FOR_RATIO else max(ratio, NETWORK_RATIO)


def anchored_sigma(sigma: np.ndarray, anchored: Anchored, mask: np.ndarray) -> np.ndarray:
    """The network's ``sigma`` (h, w metres) recombined with what anchoring measured on the
    spacecraft's ``mask`` (h, w bool; see the module's docstring): float32 metres on the same
    grid; the network's own sigma without returns on the mask."""
    if anchored.residual.size == 0:
        return sigma.astype(np.float32)
    return shaped_by_grid(recombined_sigma(sigma, anchored), anchored.apart_px, mask)


def recombined_sigma(sigma: np.ndarray, anchored: Anchored) -> np.ndarray:
    """The network's ``sigma`` (h, w metres) rescaled by the frame's error ratio and combined
    in quadrature with the distance to the nearest return in metres, the misfit, the
    disagreement and the noise (the module's docstring): float32 metres, before
    ``shaped_by_grid``."""
    rescaled = sigma * error_ratio(sigma, anchored)
    scale = SIGMA_AT_RETURN**2 + (SIGMA_PER_APART_M * anchored.apart_m) ** 2
    variance = rescaled * rescaled * scale + (SIGMA_PER_MISFIT * anchored.misfit) ** 2
    variance += (SIGMA_PER_DISAGREEMENT * anchored.disagreement_m) ** 2
    variance += (SIGMA_PER_NOISE * anchored.noise_m) ** 2
    return np.sqrt(variance)


def shaped_by_grid(sigma: np.ndarray, apart_px: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``sigma`` (h, w metres) times ``SIGMA_SCALE``, times (1 + ``apart_px``, the distance to
    the nearest return in the grid's pixels) ** ``SIGMA_APART_PX_POWER``, and times 1 +
    ``SIGMA_OUTLINE_GAIN`` x exp(-d / ``SIGMA_OUTLINE_PX``), d the distance in pixels to the
    nearest pixel off ``mask`` (h, w bool; 1 on the outline; the grid's border is not an
    outline: a spacecraft overflowing the frame goes on beyond it): float32 metres. The
    distance transform is most of the cost; a box blur of the mask, a third of it, ranked the
    pixels worse (docs/development.md, "Measurements")."""
    inside_px = cv2.distanceTransform(mask.view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
    outline = 1.0 + SIGMA_OUTLINE_GAIN * np.exp(-inside_px / SIGMA_OUTLINE_PX)
    shaped = SIGMA_SCALE * sigma * np.power(1.0 + apart_px, SIGMA_APART_PX_POWER) * outline
    return shaped.astype(np.float32)
