"""The surfaces' textures.

Textures are fractal value noise (fBm): a random periodic tile made from the generator, sampled
with ``cv2.remap`` in a chart of the surface (km), one remap per octave. Each octave fades out
where it falls below the local pixel footprint, so nothing aliases and nothing is wasted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from sdcnet.training.data.background.grid import SphereView

TILE = 256  # noise tile, cells per side
FULL_RES_OCTAVES = 3  # octaves evaluated per pixel (the rest on the coarse grid)


@dataclass(frozen=True)
class Noise:
    """Four fields of value noise (Earth: terrain, cloud, albedo, aux; Moon: maria, detail, -, -)
    from one periodic tile, in octaves of halving cell size (km).

    Octave k maps chart km to tile cells by its own rotation, scale 1 / cells_km[k] and offset.
    ``amplitude[k, c]`` is gain_c ** k normalised so that each field has unit variance."""

    tile: np.ndarray  # (TILE + 1, TILE + 1, 4) float32, unit variance, first row/column repeated
    cells_km: np.ndarray  # (n,)
    transform: np.ndarray  # (n, 2, 3)
    amplitude: np.ndarray  # (n, 4)
    channels: tuple[np.ndarray, ...]  # the tile's channels, contiguous, for one-channel remaps

    def maps(self, k: int, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tile coordinates of octave k, wrapped into [0, TILE] (the padded tile's range)."""
        out = []
        for a, b, c in self.transform[k]:
            m = cv2.addWeighted(u, float(a), v, float(b), float(c))
            turns = np.floor(np.multiply(m, 1.0 / TILE))
            out.append(cv2.scaleAdd(turns, -float(TILE), m, dst=m))
        return out[0], out[1]

    def sample(self, k: int, maps, channel: int | None = None) -> np.ndarray:
        """Octave k of one channel at unit amplitude, or of all four scaled by their amplitude."""
        if channel is None:
            tile = self.tile * self.amplitude[k].astype(np.float32)
        else:
            tile = self.channels[channel]
        return cv2.remap(tile, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def make_noise(
    rng: np.random.Generator, finest_km: float, spectra: tuple[tuple[float, float], ...]
) -> Noise:
    """Tile (smoothed white noise, so octaves have no cell-scale creases) and octave layout.

    ``spectra`` holds, per channel, the amplitude ratio of successive octaves (the roughness)
    and the largest cell (km): octaves above it are left out of that channel."""
    white = rng.standard_normal((TILE, TILE, 4), dtype=np.float32)
    pad = ((4, 4), (4, 4), (0, 0))  # the blur's reach, wrapped so the tile stays periodic
    smooth = cv2.GaussianBlur(np.pad(white, pad, mode="wrap"), (9, 9), 1.0)[4:-4, 4:-4]
    mean, std = cv2.meanStdDev(smooth)
    smooth = (smooth - mean.ravel().astype(np.float32)) / std.ravel().astype(np.float32)
    tile = np.pad(smooth, ((0, 1), (0, 1), (0, 0)), mode="wrap")
    gains, largest = (np.array(column) for column in zip(*spectra, strict=True))
    n = max(math.floor(math.log2(largest.max() / finest_km)) + 1, 1)
    cells = largest.max() * 2.0 ** -np.arange(n)
    angle = rng.uniform(0, 2 * np.pi, n)
    offset = rng.uniform(0, TILE, (n, 2))
    c, s = np.cos(angle) / cells, np.sin(angle) / cells
    transform = np.stack(
        [np.stack([c, -s, offset[:, 0]], axis=1), np.stack([s, c, offset[:, 1]], axis=1)], axis=1
    )
    g = gains[None, :] ** np.arange(n)[:, None] * (cells[:, None] <= largest * 1.001)
    amplitude = g / np.sqrt(np.sum(g**2, axis=0) + 1e-30)
    channels = tuple(np.ascontiguousarray(tile[..., c]) for c in range(4))
    return Noise(tile, cells, transform, amplitude, channels)


def _band_weight(
    log_cell: float, lfp: np.ndarray, lfp_range: tuple[float, float], start: float, stop: float
) -> np.ndarray | float:
    """Weight of an octave of cell 2**log_cell km on pixels of footprint 2**lfp km.

    With x = log2(cell / footprint), the cell's size in pixels, the weight ramps up over
    x = start -+ 0.5 and down over x = stop -+ 0.5 (stop = inf: never). Returns a scalar 0 or 1
    when that holds over all of ``lfp`` (its (min, max) given), sparing the per-pixel work."""
    x_low, x_high = log_cell - lfp_range[1], log_cell - lfp_range[0]
    if x_high <= start - 0.5 or x_low >= stop + 0.5:
        return 0.0
    if x_low >= start + 0.5 and x_high <= stop - 0.5:
        return 1.0
    x = log_cell - lfp
    w = np.clip(x - (start - 0.5), 0.0, 1.0)
    return w - np.clip(x - (stop - 0.5), 0.0, 1.0) if math.isfinite(stop) else w


def _value_range(a: np.ndarray) -> tuple[float, float]:
    return float(a.min()), float(a.max())


def coarse_fbm(noise: Noise, view: SphereView, factor: int) -> np.ndarray:
    """(h, w, 4) fields from the octaves the coarse grid resolves, faded at its cell size."""
    out = np.zeros((*view.q.shape, 4), np.float32)
    lfp_range = _value_range(view.log_footprint)
    for k, cell in enumerate(noise.cells_km):
        start = math.log2(factor)
        w = _band_weight(math.log2(cell), view.log_footprint, lfp_range, start, math.inf)
        if np.isscalar(w) and w == 0:
            continue
        octave = noise.sample(k, noise.maps(k, *view.chart))
        out += octave if np.isscalar(w) else octave * w[..., None]
    return out


def fine_octaves(noise: Noise, view: SphereView, factor: int) -> list[int]:
    """The octaves worth doing per pixel: the FULL_RES_OCTAVES most used over the body."""
    where = view.hit if view.hit.any() else np.ones_like(view.hit)
    lfp = view.log_footprint[where]
    lfp = lfp[:: max(len(lfp) // 4096, 1)]  # a sample is enough to rank them
    lfp_range, stop = _value_range(lfp), math.log2(factor)
    use = [
        float(np.sum(_band_weight(math.log2(c), lfp, lfp_range, 0.0, stop) * np.ones_like(lfp)))
        for c in noise.cells_km
    ]
    ranked = [k for k in np.argsort(use)[::-1][:FULL_RES_OCTAVES] if use[k] > 0]
    return sorted(int(k) for k in ranked)


def finest_cell_km(view: SphereView) -> float:
    where = view.hit if view.hit.any() else np.ones_like(view.hit)
    return 0.7 * 2.0 ** float(view.log_footprint[where].min())


def fine_detail(
    noise: Noise,
    octaves: list[int],
    up: dict[str, np.ndarray],
    factor: int,
    terms: tuple[tuple[int, int], ...],
) -> list[np.ndarray]:
    """Pixel-scale octaves, one sum per (noise channel, amplitude column) term.

    Two terms may share a noise channel with different gains (the Earth's terrain and land
    albedo), which costs one remap."""
    sums = [np.zeros_like(up["u"]) for _ in terms]
    lfp = up["log_footprint"]
    lfp_range, stop = _value_range(lfp), math.log2(factor)
    for k in octaves:
        w = _band_weight(math.log2(noise.cells_km[k]), lfp, lfp_range, 0.0, stop)
        if np.isscalar(w) and w == 0:
            continue
        maps = noise.maps(k, up["u"], up["v"])
        octave = {c: noise.sample(k, maps, c) for c in dict.fromkeys(c for c, _ in terms)}
        if not np.isscalar(w):
            octave = {c: sample * w for c, sample in octave.items()}
        for total, (channel, column) in zip(sums, terms, strict=True):
            cv2.scaleAdd(octave[channel], float(noise.amplitude[k, column]), total, dst=total)
    return sums
