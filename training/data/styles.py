"""Render styles: how another renderer would draw the same spacecraft.

Our renderer (``render.py``) casts one ray through each pixel's centre and shades with
Blinn-Phong, hard shadows and a dim ambient term. Users' frames come from other renderers
(path tracers, game engines, their own) and from cameras, whose images differ from ours in
ways a network can learn to depend on. A ``RenderStyle`` draws the same spacecraft as such a
renderer would:

- ``samples``: a grid of ``samples`` x ``samples`` rays a pixel, averaged with the background
  by coverage (anti-aliased outlines, as every production renderer and every real optics give;
  ours are stair-stepped before the camera's blur);
- ``brdf``: ``"ggx"``, the microfacet reflection with Fresnel that physically based renderers
  use (wide glossy tails, grazing reflections), instead of Blinn-Phong;
- ``fill``: a second, unshadowed light (the Earth's albedo, light bounced between parts), its
  irradiance a fraction of the Sun's: shadowed parts are seen dimly rather than not at all;
- ``stain``: albedo varying over each surface by up to this fraction (textured CAD models,
  weathering, labels).

The depth truth is unchanged (the pixel centre's ray); only the gray image differs.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

#: ``"ours"``: the renderer the datasets were made with; ``"pbr"``: a physically based one.
STYLE_KINDS = ("ours", "pbr")


@dataclass(frozen=True)
class RenderStyle:
    """One renderer's way of drawing (``kind``: a ``STYLE_KINDS`` name): rays a pixel side,
    reflection model, fill light (irradiance, Sun = 1, and its unit direction in the camera
    frame), albedo variation (fraction) and its pattern's seed and scale (metres)."""

    kind: str = "ours"
    samples: int = 1
    brdf: str = "blinn-phong"
    fill: float = 0.0
    fill_direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    stain: float = 0.0
    stain_scale_m: float = 0.5
    stain_seed: int = 0

    def metadata(self) -> dict:
        out = asdict(self)
        out["fill"] = round(self.fill, 5)
        out["stain"] = round(self.stain, 5)
        out["stain_scale_m"] = round(self.stain_scale_m, 5)
        out["fill_direction"] = [round(v, 6) for v in self.fill_direction]
        return out


OURS = RenderStyle()


def sample_style(rng: np.random.Generator, kind: str = "ours") -> RenderStyle:
    """A render style of ``kind`` (``STYLE_KINDS``); ``"pbr"`` draws 2-4 rays a pixel side,
    GGX, a fill light of 2-30 % of the Sun from any direction and 0-40 % albedo variation."""
    if kind == "ours":
        return OURS
    if kind != "pbr":
        raise ValueError(f"unknown render style {kind!r}; choose one of {STYLE_KINDS}")
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return RenderStyle(
        kind="pbr",
        samples=int(rng.integers(2, 5)),
        brdf="ggx",
        fill=float(math.exp(rng.uniform(math.log(0.02), math.log(0.3)))),
        fill_direction=tuple(float(v) for v in direction),
        stain=float(rng.uniform(0.0, 0.4)),
        stain_scale_m=float(rng.uniform(0.2, 1.5)),
        stain_seed=int(rng.integers(2**31)),
    )


def subpixel_offsets(samples: int) -> np.ndarray:
    """(samples^2, 2) offsets (pixels, x then y) of a regular grid of rays within a pixel,
    centred on its centre; (0, 0) alone for one sample."""
    steps = (np.arange(samples) + 0.5) / samples - 0.5
    xx, yy = np.meshgrid(steps, steps)
    return np.stack([xx.ravel(), yy.ravel()], axis=1)


def ggx_specular(
    n: np.ndarray, to_light: np.ndarray, to_eye: np.ndarray, f0: np.ndarray, shininess: np.ndarray
) -> np.ndarray:
    """Reflected radiance (Sun irradiance = 1, the diffuse term's scale: albedo x cos) of a GGX
    microfacet surface with Schlick's Fresnel and Smith's shadowing. ``n``, ``to_eye``: (N, 3)
    unit; ``to_light``: (3,) unit; ``f0``: reflectance at normal incidence (N,); the roughness
    from the Blinn-Phong exponent ``shininess`` (N,) as alpha = sqrt(2 / (shininess + 2))."""
    alpha2 = 2.0 / (shininess + 2.0)
    half = to_light + to_eye
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    n_h = np.clip(np.sum(n * half, axis=1), 0.0, 1.0)
    n_l = np.clip(n @ to_light, 1e-4, 1.0)
    n_v = np.clip(np.sum(n * to_eye, axis=1), 1e-4, 1.0)
    v_h = np.clip(np.sum(to_eye * half, axis=1), 0.0, 1.0)
    d = alpha2 / (math.pi * (n_h**2 * (alpha2 - 1.0) + 1.0) ** 2)
    k = np.sqrt(alpha2) / 2.0
    g = (n_l / (n_l * (1 - k) + k)) * (n_v / (n_v * (1 - k) + k))
    fresnel = f0 + (1.0 - f0) * (1.0 - v_h) ** 5
    # pi x the BRDF x cos(light): the diffuse term's convention (albedo x cos, no 1 / pi)
    return math.pi * d * g * fresnel / (4.0 * n_v)


def stained(albedo: np.ndarray, points_obj: np.ndarray, style: RenderStyle) -> np.ndarray:
    """``albedo`` (N,) times a smooth pattern over the object's surface (object-frame points
    (N, 3), metres) within 1 -/+ ``style.stain``: a sum of plane waves of the style's scale."""
    if style.stain <= 0:
        return albedo
    rng = np.random.default_rng(style.stain_seed)
    waves = rng.normal(size=(6, 3)) * (2 * math.pi / style.stain_scale_m)
    phases = rng.uniform(0, 2 * math.pi, 6)
    pattern = np.sin(points_obj @ waves.T + phases).sum(axis=1) / math.sqrt(3.0)
    return np.clip(albedo * (1.0 + style.stain * np.clip(pattern, -1.0, 1.0)), 0.0, 1.0)
