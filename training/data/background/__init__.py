"""What the camera sees behind the spacecraft: stars, the Earth, the Moon and the Sun.

The output is linear radiance on the camera's pixel grid, in the project's unit: 1.0 is a white
Lambertian surface lit by the Sun at normal incidence (a lit spacecraft panel). There is no PSF,
noise or quantisation here: the camera simulation applies them to spacecraft plus background.

The modules, in the order a background is made:

- ``config``: the kinds, the bodies' sizes, and what each layer is drawn with.
- ``sampling``: ``sample_background`` draws a config for a camera and Sun.
- ``geometry``: directions and the frame (``sun_in_view``, the pixel box of a cone).
- ``grid``: the coarse grid of the smooth quantities, and a sphere seen on it.
- ``noise``: the fractal value noise of the surfaces' textures.
- ``earth``, ``moon``, ``stars``, ``sun``: each layer's light.
- ``compose``: ``render_background`` lays the layers over one another.
"""

from sdcnet.training.data.background.compose import Background, render_background
from sdcnet.training.data.background.config import (
    BACKGROUND_KINDS,
    EARTH_RADIUS_KM,
    BackgroundConfig,
    MoonConfig,
    StarsConfig,
)
from sdcnet.training.data.background.geometry import sun_in_view
from sdcnet.training.data.background.sampling import sample_background, sample_sun_near_view

__all__ = [
    "BACKGROUND_KINDS",
    "EARTH_RADIUS_KM",
    "Background",
    "BackgroundConfig",
    "MoonConfig",
    "StarsConfig",
    "render_background",
    "sample_background",
    "sample_sun_near_view",
    "sun_in_view",
]
