"""The star field."""

from __future__ import annotations

import numpy as np

from sdcnet.training.data.background.config import StarsConfig


def add_stars(
    cfg: StarsConfig, rng: np.random.Generator, radiance: np.ndarray, transmission: np.ndarray
) -> None:
    """Single-pixel stars (a few 2 x 2), dimmed by the air and hidden by the Earth and Moon."""
    H, W = radiance.shape
    count = int(rng.poisson(cfg.density_per_mpx * H * W / 1e6))
    rows, cols = rng.integers(0, H, count), rng.integers(0, W, count)
    log_b = rng.uniform(np.log(cfg.brightness_min), np.log(cfg.brightness_max), count)
    block = rng.random(count) < cfg.fraction_2x2
    rows[block] = np.minimum(rows[block], max(H - 2, 0))
    cols[block] = np.minimum(cols[block], max(W - 2, 0))
    index = rows * W + cols
    corners = [index[block] + offset for offset in (1, W, W + 1)] if H > 1 and W > 1 else []
    index = np.concatenate([index, *corners])
    brightness = np.exp(np.concatenate([log_b, *[log_b[block]] * len(corners)]))
    np.add.at(
        radiance.ravel(), index, (brightness * transmission.ravel()[index]).astype(np.float32)
    )
