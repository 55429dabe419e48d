"""Camera simulation: ray-cast gray image and ground-truth depth of a spacecraft.

One primary ray per pixel centre (only inside the projected bounding box of the mesh),
Blinn-Phong shading with per-material parameters, hard shadows from the sun by shadow rays,
a small ambient term; in front of a background (stars on a black sky by default, or the Earth,
the Moon, the Sun's glare: ``background/``), seen by a camera's optics and electronics
(``sensor.py``). Another renderer's style (``styles.py``: rays a pixel, GGX, a fill light,
stains) draws the same scene otherwise. Depth is camera-frame Z in metres at pixel centres, 0
off the object.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.training.data.background import Background, render_background, sample_background
from sdcnet.training.data.materials import shading_arrays
from sdcnet.training.data.raycast import RayCaster
from sdcnet.training.data.scene import Scene
from sdcnet.training.data.sensor import Sensor, expose, paper_sensor
from sdcnet.training.data.spacecraft import SpacecraftModel
from sdcnet.training.data.styles import OURS, RenderStyle, ggx_specular, stained, subpixel_offsets

SHADOW_OFFSET_M = 0.003  # start shadow rays off the surface, above float32 noise at 280 m
INTERCONNECT_FRACTION = 0.12  # share of a solar-cell pitch taken by the grid lines


@dataclass(frozen=True)
class PosedModel:
    """A spacecraft placed in the camera frame, with a ray caster over it."""

    model: SpacecraftModel
    scene: Scene
    caster: RayCaster
    normals: np.ndarray  # (F, 3) face normals in the camera frame

    @classmethod
    def place(cls, model: SpacecraftModel, scene: Scene) -> PosedModel:
        R, t = scene.rotation, scene.translation
        triangles = model.mesh.triangles @ R.T + t
        return cls(model, scene, RayCaster(triangles), model.mesh.face_normals @ R.T)

    def to_object(self, points: np.ndarray) -> np.ndarray:
        return (points - self.scene.translation) @ self.scene.rotation


@dataclass
class CameraFrame:
    gray: np.ndarray  # (H, W) uint8 or uint16
    depth: np.ndarray  # (H, W) float32 metres, 0 = background
    exposure: float  # full-scale fraction a lit white surface reaches


def _bounding_rect(posed: PosedModel, K: Intrinsics, margin: int = 2) -> tuple[int, int, int, int]:
    corners = np.array(np.meshgrid(*posed.model.mesh.bounds.T)).reshape(3, -1).T
    cam = corners @ posed.scene.rotation.T + posed.scene.translation
    u, v = K.project(cam)
    u0 = int(np.clip(np.floor(u.min()) - margin, 0, K.width))
    u1 = int(np.clip(np.ceil(u.max()) + margin + 1, 0, K.width))
    v0 = int(np.clip(np.floor(v.min()) - margin, 0, K.height))
    v1 = int(np.clip(np.ceil(v.max()) + margin + 1, 0, K.height))
    return u0, u1, v0, v1


def _crinkled(
    normals: np.ndarray, points_obj: np.ndarray, amplitude: np.ndarray, waves: np.ndarray
):
    """Perturb normals of crinkled foil with a sum of plane waves over the object surface."""
    phase = points_obj @ waves[:, :3].T + waves[:, 3]
    directions = np.roll(waves[:, :3], 1, axis=0)
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    g = np.sin(phase) @ directions / np.sqrt(len(waves))
    g -= np.sum(g * normals, axis=1, keepdims=True) * normals
    n = normals + amplitude[:, None] * g
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _cell_albedo(points_obj, texture, base, grid, pitch, footprint):
    """Albedo of solar cells with the interconnect grid, box-filtered over the pixel footprint."""
    rel = points_obj - texture[:, 0:3]
    coverage = np.zeros(len(rel))
    width = INTERCONNECT_FRACTION * pitch
    for axis in (texture[:, 3:6], texture[:, 6:9]):
        s = np.sum(rel * axis, axis=1) / pitch
        d = np.abs(s - np.round(s)) * pitch  # metres to the nearest grid line
        line = np.clip((width / 2 + footprint / 2 - d) / footprint, 0, 1) * np.minimum(
            1, width / footprint
        )
        coverage = np.maximum(coverage, line)
    return base * (1 - coverage) + grid * coverage


def shade(
    posed: PosedModel,
    points: np.ndarray,
    rays: np.ndarray,
    faces: np.ndarray,
    K: Intrinsics,
    ambient: float,
    style: RenderStyle = OURS,
) -> np.ndarray:
    """Linear radiance (sun irradiance = 1) of the hit points seen along ``rays``, shaded in
    ``style``'s way (reflection model, fill light, stains)."""
    model, sun = posed.model, posed.scene.sun
    table = shading_arrays(model.shading)
    mat = model.materials[faces]
    n = posed.normals[faces]
    n = np.where(np.sum(n * rays, axis=1, keepdims=True) > 0, -n, n)  # face the viewer
    points_obj = posed.to_object(points)
    crinkle = table["crinkle"][mat]
    if np.any(crinkle > 0):
        wavy = crinkle > 0
        n[wavy] = _crinkled(n[wavy], points_obj[wavy], crinkle[wavy], model.crinkle_waves)
    albedo = table["albedo"][mat]
    cells = np.any(model.texture[faces], axis=1) & (table["cell_pitch_m"][mat] > 0)
    if np.any(cells):
        footprint = points[cells, 2] / K.fx  # metres per pixel at that depth
        albedo[cells] = _cell_albedo(
            points_obj[cells],
            model.texture[faces[cells]],
            albedo[cells],
            table["grid_albedo"][mat[cells]],
            table["cell_pitch_m"][mat[cells]],
            footprint,
        )
    albedo = stained(albedo, points_obj, style)
    n_dot_l = np.sum(n * sun, axis=1)
    lit = n_dot_l > 0
    if np.any(lit):
        origins = points[lit] + n[lit] * SHADOW_OFFSET_M
        shadowed = posed.caster.occluded(origins, np.broadcast_to(sun, origins.shape), 100.0)
        lit[np.flatnonzero(lit)[shadowed]] = False
    shininess = table["shininess"][mat]
    if style.brdf == "ggx":
        specular = ggx_specular(n, sun, -rays, table["specular"][mat], shininess)
    else:
        half = sun - rays
        half /= np.linalg.norm(half, axis=1, keepdims=True)
        specular = table["specular"][mat] * np.clip(np.sum(n * half, axis=1), 0, 1) ** shininess
        specular *= (shininess + 8) / 32  # rough energy normalisation: tight lobes peak higher
    radiance = np.where(lit, albedo * n_dot_l + specular, 0.0)
    if style.fill > 0:  # unshadowed: an extended source (the Earth) or light between parts
        fill = np.clip(n @ np.asarray(style.fill_direction), 0.0, 1.0)
        radiance = radiance + style.fill * albedo * fill
    return radiance + ambient * albedo


@dataclass
class Radiance:
    """The spacecraft as the renderer sees it: linear radiance (H, W) float64, the radiance of
    a pixel's rays that hit summed over all its rays' count (0 off it: the background adds the
    rest, by ``coverage``); the share of a pixel's rays that hit (H, W) float64, 1 or 0 with
    one ray a pixel; ground-truth depth (H, W) float32 metres at pixel centres (0 =
    background)."""

    radiance: np.ndarray
    coverage: np.ndarray
    depth: np.ndarray


def _cast(
    posed: PosedModel, K: Intrinsics, uu: np.ndarray, vv: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unit rays through image points ``uu``, ``vv`` (pixels, flat), the faces they hit (-1 =
    none), whether they hit, and the hit points (camera frame, metres)."""
    rays = K.pixel_rays(uu, vv)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    faces, distance = posed.caster.closest(np.zeros_like(rays), rays)
    hit = faces >= 0
    return rays, faces, hit, rays[hit] * distance[hit, None]


def render_radiance(
    posed: PosedModel, K: Intrinsics, rng: np.random.Generator, style: RenderStyle = OURS
) -> Radiance:
    """The spacecraft's ``Radiance`` in ``style``: one ray through each pixel centre for our
    renderer, a grid of ``style.samples`` squared rays a pixel otherwise (one offset at a time:
    memory as one ray a pixel)."""
    H, W = K.height, K.width
    radiance = np.zeros((H, W), np.float64)
    coverage = np.zeros((H, W), np.float64)
    depth = np.zeros((H, W), np.float32)
    u0, u1, v0, v1 = _bounding_rect(posed, K)
    if u1 > u0 and v1 > v0:
        vv, uu = np.mgrid[v0:v1, u0:u1]
        uu, vv = uu.ravel().astype(np.float64), vv.ravel().astype(np.float64)
        rays, faces, hit, points = _cast(posed, K, uu, vv)
        ambient = rng.uniform(0.01, 0.06)
        z = np.zeros(len(rays), np.float32)
        z[hit] = points[:, 2]
        depth[v0:v1, u0:u1] = z.reshape(v1 - v0, u1 - u0)
        offsets = subpixel_offsets(style.samples)
        for dx, dy in offsets:
            if style.samples > 1:
                rays, faces, hit, points = _cast(posed, K, uu + dx, vv + dy)
            values = np.zeros(len(rays))
            values[hit] = shade(posed, points, rays[hit], faces[hit], K, ambient, style)
            radiance[v0:v1, u0:u1] += values.reshape(v1 - v0, u1 - u0)
            coverage[v0:v1, u0:u1] += hit.reshape(v1 - v0, u1 - u0)
        radiance /= len(offsets)
        coverage /= len(offsets)
    return Radiance(radiance, coverage, depth)


def render_camera(
    posed: PosedModel,
    K: Intrinsics,
    rng: np.random.Generator,
    background: Background | np.ndarray | None = None,
    sensor: Sensor | None = None,
    style: RenderStyle = OURS,
) -> CameraFrame:
    """Gray image (uint8, or uint16 for a 12/16-bit ``sensor``) and ground-truth depth
    (float32 m) of a posed spacecraft drawn in ``style`` in front of ``background``
    (``background/``, or a radiance image (H, W); default: stars on a black sky), seen by
    ``sensor`` (default: the paper-like camera). The lens's stray light falls on the
    spacecraft too."""
    seen = render_radiance(posed, K, rng, style)
    if background is None:
        sun = posed.scene.sun
        background = render_background(sample_background(rng, K, sun, "stars"), K, sun, rng)
    if not isinstance(background, Background):
        background = Background(background, None)
    sensor = sensor or paper_sensor(rng, K.width)
    # a pixel's rays that missed the spacecraft see the background
    scene = seen.radiance + (1.0 - seen.coverage) * background.scene
    if background.stray is not None:
        scene += background.stray
    return CameraFrame(expose(scene, sensor, rng), seen.depth, sensor.exposure)
