"""Worlds: how the camera, the sensor, the LIDAR, the range and the sky of a frame are drawn.

The paper's frames come from one camera, one LIDAR, 50-250 m and a starry sky; flight frames
come from any of them. A ``World`` names the draw of every factor; ``draw_conditions`` draws
one frame's ``Conditions`` from it, deterministically from the generator it is given, and
each factor records itself in the sample's metadata.

- ``paper``: Tables 1-2 and sec. IV (the first datasets);
- ``any``: cameras of 5-60 deg horizontal field of view at 512-2048 px (square and not,
  principal point off centre), any sensor (``sensor.py``), any LIDAR kind (``lidar.py``),
  ranges 2-300 m (log-uniform, never inside the spacecraft), any background
  (``background/``), the sun from anywhere in front of the target to behind it;
- ``mixed``: the training mixture, a quarter ``paper`` and the rest ``any``;
- the robustness suite's conditions (``ROBUSTNESS``): one factor pushed at a time, the
  renderer's style (``styles.py``) among them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from sdcnet.camera import PAPER_CAMERA, Intrinsics
from sdcnet.training.data.background import BACKGROUND_KINDS
from sdcnet.training.data.lidar import Lidar, sample_lidar
from sdcnet.training.data.scene import SceneConfig
from sdcnet.training.data.sensor import Sensor, sample_sensor
from sdcnet.training.data.styles import OURS, RenderStyle, sample_style

#: Image widths cameras are drawn from, and aspect ratios (width / height).
WIDTHS = (512, 640, 768, 1024, 1024, 1280, 1536, 2048)
ASPECTS = (1.0, 1.0, 1.0, 4 / 3, 5 / 4, 16 / 10)


@dataclass(frozen=True)
class CameraDraw:
    """Ranges a camera is drawn from: horizontal field of view (degrees, log-uniform), image
    widths (pixels), aspect ratios, principal point offset (fraction of the size, 1 sigma)."""

    hfov_deg: tuple[float, float] = (5.0, 60.0)
    widths: tuple[int, ...] = WIDTHS
    aspects: tuple[float, ...] = ASPECTS
    principal_offset: float = 0.02

    def draw(self, rng: np.random.Generator) -> Intrinsics:
        lo, hi = (math.log(v) for v in self.hfov_deg)
        hfov = math.radians(math.exp(rng.uniform(lo, hi)))
        width = int(rng.choice(self.widths))
        height = 2 * round(width / float(rng.choice(self.aspects)) / 2)
        fx = (width / 2) / math.tan(hfov / 2)
        offset = np.clip(rng.normal(0, self.principal_offset, 2), -0.05, 0.05)
        return Intrinsics(
            fx,
            fx,
            (width - 1) / 2 + offset[0] * width,
            (height - 1) / 2 + offset[1] * height,
            width,
            height,
        )


#: The camera of Tables 1-2, drawn as a ``CameraDraw`` that always gives it.
PAPER_CAMERA_DRAW = "paper"


@dataclass(frozen=True)
class World:
    """How the frames of a dataset (or of one robustness condition) are drawn. ``camera``:
    ``"paper"`` or a ``CameraDraw``; ``sensor``: a ``SENSOR_KINDS`` name; ``lidar``: LIDAR
    kinds drawn uniformly (``lidar.LIDAR_KINDS``; empty: ``sample_lidar``'s own mixture);
    ``backgrounds``: background kinds drawn uniformly (empty: ``sample_background``'s mixture
    of the kinds the scene's Sun allows, and ``sun_share`` of frames with the Sun in view);
    ``styles``: render styles drawn uniformly (``styles.STYLE_KINDS``), drawn after every
    other factor so that a world differing only in them draws the same frames otherwise."""

    name: str
    camera: CameraDraw | str = PAPER_CAMERA_DRAW
    sensor: str = "paper"
    lidar: tuple[str, ...] = ("paper",)
    backgrounds: tuple[str, ...] = ("stars",)
    scene: SceneConfig = field(default_factory=SceneConfig)
    sun_share: float = 0.0  # with empty ``backgrounds``: frames with the Sun in or near view
    styles: tuple[str, ...] = ("ours",)


@dataclass(frozen=True)
class Conditions:
    """One frame's camera, sensor, LIDAR, sky, scene ranges and render style."""

    world: str
    intrinsics: Intrinsics
    sensor: Sensor
    lidar: Lidar
    background: str | None  # a background kind, or None: the background sampler's mixture
    scene: SceneConfig
    style: RenderStyle = OURS

    def metadata(self) -> dict:
        return {
            "world": self.world,
            "sensor": self.sensor.metadata(),
            "lidar": self.lidar.metadata(),
            "render_style": self.style.metadata(),
        }


def _pick(rng: np.random.Generator, options: tuple[str, ...]) -> str | None:
    return str(options[int(rng.integers(len(options)))]) if options else None


def draw_conditions(world: World, rng: np.random.Generator, size: int = 1024) -> Conditions:
    """One frame's conditions from ``world``; ``size``: the paper camera's image size."""
    if world.camera == PAPER_CAMERA_DRAW:
        K = PAPER_CAMERA.intrinsics().scaled(size, size)
    else:
        K = world.camera.draw(rng)
    sensor = sample_sensor(rng, K.width, world.sensor)
    lidar = sample_lidar(rng, K, _pick(rng, world.lidar))
    background = _pick(rng, world.backgrounds)
    if not world.backgrounds and rng.random() < world.sun_share:
        background = "sun"
    style = sample_style(rng, _pick(rng, world.styles))
    return Conditions(world.name, K, sensor, lidar, background, world.scene, style)


PAPER = World("paper")
#: Ranges a frame of any world is drawn from: docking to far, anything in the field of view.
ANY_SCENE = SceneConfig(
    min_distance_m=2.0,
    max_distance_m=300.0,
    log_distance=True,
    offset_of_fov=0.6,
    max_sun_angle_deg=130.0,
)
ANY = World("any", CameraDraw(), "any", (), (), ANY_SCENE, sun_share=0.08)
#: The training mixture: this share of frames from ``PAPER``, the rest from ``ANY``.
MIXED_PAPER_SHARE = 0.25

#: Docking range: a flash array or a scanning grid at 2-10 m, the spacecraft overflowing the
#: frame.
DOCKING = World(
    "docking",
    CameraDraw(hfov_deg=(40.0, 60.0), widths=(1024, 1280), aspects=(1.0, 4 / 3)),
    "any",
    ("flash", "grid"),
    (),
    replace(ANY_SCENE, min_distance_m=2.0, max_distance_m=10.0),
)

#: The robustness suite: one condition per factor pushed away from the paper's world.
_PAPER_RANGE = SceneConfig()
ROBUSTNESS: dict[str, World] = {
    world.name: world
    for world in (
        PAPER,
        # the paper's frames drawn by a physically based renderer: the same draws otherwise
        World("other-renderer", styles=("pbr",)),
        World("earth", backgrounds=("earth-nadir", "earth-oblique", "earth-limb")),
        World("sun-moon", backgrounds=("sun", "moon")),
        World(
            "wide-multibeam",
            CameraDraw(hfov_deg=(50.0, 50.0), widths=(1024,), aspects=(1.0,)),
            "any",
            ("multibeam",),
            (),
            replace(ANY_SCENE, min_distance_m=3.0, max_distance_m=80.0),
        ),
        World(
            "flash",
            CameraDraw(hfov_deg=(40.0, 40.0), widths=(1024,), aspects=(1.0,)),
            "any",
            ("flash",),
            (),
            replace(ANY_SCENE, min_distance_m=4.0, max_distance_m=130.0),
        ),
        DOCKING,
        # the costliest frames: docking at 2048 x 2048 px, millions of pixels on the spacecraft
        replace(
            DOCKING,
            name="docking-2048",
            camera=replace(DOCKING.camera, widths=(2048,), aspects=(1.0,)),
        ),
        World(
            "narrow-far",
            CameraDraw(hfov_deg=(5.0, 5.0), widths=(2048,), aspects=(1.0,)),
            "any",
            ("grid", "paper"),
            (),
            replace(ANY_SCENE, min_distance_m=150.0, max_distance_m=300.0, log_distance=False),
        ),
        ANY,
    )
}
WORLDS = ("paper", "any", "mixed", *[name for name in ROBUSTNESS if name not in ("paper", "any")])


def world_for_frame(name: str, rng: np.random.Generator) -> World:
    """The world a frame of the named world is drawn from (``mixed`` picks per frame)."""
    if name == "mixed":
        return PAPER if rng.random() < MIXED_PAPER_SHARE else ANY
    if name not in ROBUSTNESS:
        raise ValueError(f"unknown world {name!r}; choose one of {WORLDS}")
    return ROBUSTNESS[name]


__all__ = ["BACKGROUND_KINDS", "Conditions", "World", "draw_conditions", "world_for_frame"]
