"""The background composed: the Earth, the Moon, the stars and the Sun, each layer in turn."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background.config import BackgroundConfig
from sdcnet.training.data.background.earth import render_earth
from sdcnet.training.data.background.geometry import unit
from sdcnet.training.data.background.moon import render_moon
from sdcnet.training.data.background.stars import add_stars
from sdcnet.training.data.background.sun import add_sun


@dataclass(frozen=True)
class Background:
    """What the camera sees besides the spacecraft, radiance (H, W) float32: ``scene`` lies
    behind it (sky, stars, Earth, Moon, the Sun's disc), ``stray`` is the Sun's light
    scattered in the lens (halo, glare, ghosts; None when the Sun is far) and falls on the
    spacecraft as well."""

    scene: np.ndarray
    stray: np.ndarray | None

    @property
    def radiance(self) -> np.ndarray:
        """Everything, as a frame without a spacecraft shows it."""
        return self.scene if self.stray is None else self.scene + self.stray


def render_background(
    config: BackgroundConfig, K: Intrinsics, sun: np.ndarray, rng: np.random.Generator
) -> Background:
    """The background for a camera and Sun (unit vector, camera frame).

    The generator supplies the textures and the star field: the same config, camera, Sun and
    generator state give the same image bit for bit."""
    sun = unit(sun)
    radiance = np.zeros((K.height, K.width), np.float32)
    transmission = np.ones((K.height, K.width), np.float32)  # of light from beyond the bodies
    if config.earth is not None:
        render_earth(config.earth, K, sun, rng, radiance, transmission)
    if config.moon is not None:
        render_moon(config.moon, K, sun, rng, radiance, transmission)
    add_stars(config.stars, rng, radiance, transmission)
    stray = add_sun(config, K, sun, radiance, transmission)
    return Background(radiance, stray)
