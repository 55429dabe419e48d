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
   measures the noise; a bias of the whole surface is taken for noise too, and left;
2. the corrections are spread by a normalised Gaussian convolution (``sigma_px``
   from the returns' spacing): at a return the correction is mostly its own, between returns a
   weighted mean of the near ones, and it fades to nothing a few ``sigma_px`` away from any.

It runs on the working grid, so it costs the same (a few milliseconds) whatever the camera and
the frame's size. The choice of ``SIGMA_PER_SPACING``, ``SIGMA_BOUNDS_PX`` and ``SHRINK``:
docs/development.md, "Measurements".
"""

from __future__ import annotations

import math

import cv2
import numpy as np

#: The spreading kernel's standard deviation, in return spacings ...
SIGMA_PER_SPACING = 0.75
#: ... within these bounds, in the frame's pixels: at least a pixel's neighbourhood, at most
#: what keeps a correction on the part of the spacecraft it was measured on.
SIGMA_BOUNDS_PX = (1.5, 6.0)
#: Residuals within this many noise scales (``MAD_TO_STD`` x their median absolute value) are
#: taken as the LIDAR's noise.
SHRINK = 0.75
#: Median absolute deviation -> standard deviation, for Gaussian noise.
MAD_TO_STD = 1.4826


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
    depth: np.ndarray, mask: np.ndarray, sparse: np.ndarray, sigma_px: float
) -> np.ndarray:
    """``depth`` (H, W metres) corrected by its residuals at the returns of ``sparse`` (H, W
    metres, 0 = none) that fall on ``mask`` (H, W bool, the spacecraft: returns off it are
    not the depth's to agree with), spread with a Gaussian of ``sigma_px`` pixels; unchanged
    without such returns. The correction covers the whole grid, so that resampling the mask
    to the frame never meets an uncorrected pixel at its border."""
    rows, cols = np.nonzero((sparse > 0) & mask & (depth > 0))
    if len(rows) == 0:
        return depth
    residual = sparse[rows, cols] - depth[rows, cols]
    noise = SHRINK * MAD_TO_STD * float(np.median(np.abs(residual)))
    local = np.sign(residual) * np.maximum(np.abs(residual) - noise, 0.0)
    weighted = np.zeros(depth.shape, np.float32)
    count = np.zeros(depth.shape, np.float32)
    weighted[rows, cols] = local
    count[rows, cols] = 1.0
    size = 2 * math.ceil(2 * sigma_px) + 1
    blur = {"ksize": (size, size), "sigmaX": sigma_px, "borderType": cv2.BORDER_CONSTANT}
    weighted, count = cv2.GaussianBlur(weighted, **blur), cv2.GaussianBlur(count, **blur)
    centre = float(cv2.getGaussianKernel(size, sigma_px)[size // 2, 0]) ** 2
    reach = np.minimum(count / centre, 1.0)  # 1 at a return, fading away from them
    correction = reach * weighted / np.maximum(count, 1e-12)
    return (depth + correction).astype(np.float32)
