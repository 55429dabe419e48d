"""LIDAR simulation: the paper's scanning LIDAR (Table 2) and the other kinds users fly.

Every kind is a frozen dataclass (``Lidar`` and its subclasses) that sends beams from its
origin ``offset_m`` in the camera frame, boresighted with the camera (same axes):

- ``ScanningLidar``: a steered beam on an azimuth/elevation grid with a random phase per
  frame; ``PAPER_SCANNER`` is Table 2 (0.09 x 0.13 deg, 280 m, range error < 3 cm, 2 %
  dropout), co-located, with no dark or specular loss;
- ``MultiBeamLidar``: a rotating head of ``beams`` lasers at fixed elevations spinning about
  the camera's y axis (optionally tilted); returns lie on rows far apart, dense along them;
- ``FlashLidar``: a focal-plane array of ``columns`` x ``rows`` detectors over its own field
  of view, each returning the range along its centre ray;
- ``RosetteLidar``: two counter-rotating Risley prisms drawing petals (Livox-like).

Each return's range carries Gaussian noise, sigma = ``range_noise_m`` +
``range_noise_per_100m`` * range / 100, clipped at 3 sigma. A return is lost at random
(``dropout``), beyond ``max_range_m``, on dark surfaces (``dark_loss``: the diffuse echo
albedo * cos(incidence) below ``dark_threshold``) and on specular ones away from normal
incidence (``specular_loss``: the beam is mirrored away). Shadowed surfaces return like lit
ones; only the mesh is cast against (never the Earth or stars). Each return lands on its
nearest camera pixel as camera-frame Z in metres; the nearest return wins a pixel.

Only beams inside the camera's field of view (widened for parallax) and inside the projected
bounding box of the mesh are cast (``lidar_window``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from sdcnet.camera import PAPER_LIDAR, Intrinsics, LidarSpec
from sdcnet.training.data.lidar_window import TanWindow, camera_fov_deg, lidar_window
from sdcnet.training.data.materials import shading_arrays
from sdcnet.training.data.raycast import RayCaster

if TYPE_CHECKING:
    from sdcnet.training.data.render import PosedModel

#: Shininess at which half the specular reflectance counts as a mirror (the rest scatters).
MIRROR_SHININESS = 20.0


def _plain(value):
    """A JSON-ready, rounded copy of a field value."""
    if isinstance(value, bool | int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return round(float(value), 6)
    return [_plain(v) for v in value]


@dataclass(frozen=True, kw_only=True)
class Lidar:
    """What every LIDAR kind shares: range, noise, losses and where it sits on the chaser."""

    kind: ClassVar[str] = ""

    max_range_m: float = 280.0
    range_noise_m: float = 0.01  # 1 sigma at zero range
    range_noise_per_100m: float = 0.0  # growth of sigma per 100 m of range
    dropout: float = 0.02  # fraction of returns lost at random
    dark_loss: float = 0.0  # 0-1: loss of returns whose echo albedo * cos falls to 0
    dark_threshold: float = 0.1  # albedo * cos(incidence) below which returns fade
    specular_loss: float = 0.0  # 0-1: loss on mirror-like surfaces away from normal incidence
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # origin in the camera frame

    def __post_init__(self):
        object.__setattr__(self, "offset_m", tuple(float(v) for v in self.offset_m))
        if len(self.offset_m) != 3:
            raise ValueError(f"offset_m needs 3 values, got {self.offset_m}")
        for name in ("dropout", "dark_loss", "specular_loss"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        if self.max_range_m <= 0 or self.range_noise_m < 0 or self.range_noise_per_100m < 0:
            raise ValueError("max_range_m must be > 0 and the range noise >= 0")
        if self.dark_threshold <= 0:
            raise ValueError(f"dark_threshold must be > 0, got {self.dark_threshold}")

    @property
    def has_losses(self) -> bool:
        """Whether returns depend on the surface (then the materials are needed)."""
        return self.dark_loss > 0 or self.specular_loss > 0

    def range_sigma(self, distance: np.ndarray | float) -> np.ndarray | float:
        """1-sigma range noise (m) at ``distance`` (m); the noise is clipped at 3 sigma."""
        return self.range_noise_m + self.range_noise_per_100m * np.asarray(distance) / 100

    def metadata(self) -> dict:
        """Plain, rounded values (JSON-ready): the kind and every field."""
        return {"kind": self.kind, **{f.name: _plain(getattr(self, f.name)) for f in fields(self)}}

    def directions(self, window: TanWindow, rng: np.random.Generator) -> np.ndarray:
        """Unit beam directions (N, 3) of one frame inside ``window`` (LIDAR frame = camera
        axes), drawing any random phase from ``rng``."""
        raise NotImplementedError


def _unit(az: np.ndarray, el: np.ndarray) -> np.ndarray:
    """Directions at azimuth ``az`` (about y, towards +x) and elevation ``el`` (towards +y)."""
    return np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], axis=-1)


def _steps(lo: float, hi: float, phase: float, step: float) -> np.ndarray:
    """phase + k * step for every integer k that lands in [lo, hi]."""
    k = np.arange(math.ceil((lo - phase) / step), math.floor((hi - phase) / step) + 1)
    return phase + k * step


@dataclass(frozen=True, kw_only=True)
class ScanningLidar(Lidar):
    """A steered beam on an azimuth/elevation grid; the grid's phase is random per frame."""

    kind: ClassVar[str] = "scanning"

    horizontal_step_deg: float = 0.09
    vertical_step_deg: float = 0.13

    def __post_init__(self):
        super().__post_init__()
        if self.horizontal_step_deg <= 0 or self.vertical_step_deg <= 0:
            raise ValueError("scan steps must be > 0")

    @classmethod
    def from_spec(cls, spec: LidarSpec) -> ScanningLidar:
        """The LIDAR of a ``LidarSpec`` (range error = 3 sigma), co-located, no surface loss."""
        return cls(
            max_range_m=spec.max_range_m,
            range_noise_m=spec.range_error_m / 3,
            dropout=spec.dropout,
            horizontal_step_deg=spec.horizontal_step_deg,
            vertical_step_deg=spec.vertical_step_deg,
        )

    def directions(self, window: TanWindow, rng: np.random.Generator) -> np.ndarray:
        h, v = math.radians(self.horizontal_step_deg), math.radians(self.vertical_step_deg)
        phase_h, phase_v = rng.uniform(0, h), rng.uniform(0, v)
        az_lo, az_hi = math.atan(window.x0), math.atan(window.x1)
        # tan(el) = (y/z) cos(az): bound the elevations of the window, then cut it exactly
        cos_min = math.cos(max(abs(az_lo), abs(az_hi)))
        el_lo = math.atan(window.y0 * (cos_min if window.y0 > 0 else 1.0))
        el_hi = math.atan(window.y1 * (cos_min if window.y1 < 0 else 1.0))
        az, el = np.meshgrid(_steps(az_lo, az_hi, phase_h, h), _steps(el_lo, el_hi, phase_v, v))
        d = _unit(az, el).reshape(-1, 3)
        return d[window.contains(d)]


def _tilt(tilt_deg: tuple[float, float]) -> np.ndarray:
    """Rotation (spin frame -> camera frame): about x by tilt[0], then about z by tilt[1]."""
    a, b = np.radians(tilt_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    rz = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]])
    return rz @ rx


@dataclass(frozen=True, kw_only=True)
class MultiBeamLidar(Lidar):
    """A rotating head of ``beams`` lasers at fixed elevations over ``vertical_fov_deg``,
    spinning about the camera's y axis (tilted by ``tilt_deg``: about x, then about z),
    firing every ``azimuth_step_deg``; the azimuth phase is random per frame."""

    kind: ClassVar[str] = "multibeam"

    beams: int = 32
    vertical_fov_deg: float = 30.0
    centre_density: float = 0.0  # 0 = uniform elevations; towards 1 = denser near the centre
    azimuth_step_deg: float = 0.2
    tilt_deg: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "tilt_deg", tuple(float(v) for v in self.tilt_deg))
        if self.beams < 1 or self.vertical_fov_deg <= 0 or self.azimuth_step_deg <= 0:
            raise ValueError("beams, vertical_fov_deg and azimuth_step_deg must be > 0")
        if not 0 <= self.centre_density < 1:
            raise ValueError(f"centre_density must lie in [0, 1), got {self.centre_density}")

    def elevations_deg(self) -> np.ndarray:
        """Elevation of each beam (degrees, + = down), symmetric about the spin plane."""
        t = np.linspace(-1, 1, self.beams) if self.beams > 1 else np.zeros(1)
        c = self.centre_density
        return self.vertical_fov_deg / 2 * ((1 - c) * t + c * t**3)

    def directions(self, window: TanWindow, rng: np.random.Generator) -> np.ndarray:
        step = math.radians(self.azimuth_step_deg)
        phase = rng.uniform(0, step)
        tilt = _tilt(self.tilt_deg)
        corners = window.corner_rays() @ tilt  # in the spin frame
        if np.any(corners[:, 2] <= 0):
            raise ValueError("the window must lie within 90 deg of the spin head's boresight")
        az = np.arctan2(corners[:, 0], corners[:, 2])  # the cone's azimuths peak at corners
        az, el = np.meshgrid(
            _steps(az.min(), az.max(), phase, step), np.radians(self.elevations_deg())
        )
        d = _unit(az, el).reshape(-1, 3) @ tilt.T
        return d[window.contains(d)]


@dataclass(frozen=True, kw_only=True)
class FlashLidar(Lidar):
    """A focal-plane array: ``columns`` x ``rows`` detectors over a ``fov_x_deg`` x
    ``fov_y_deg`` field of view on the boresight; each detector ranges along its centre ray."""

    kind: ClassVar[str] = "flash"

    columns: int = 128
    rows: int = 128
    fov_x_deg: float = 5.0
    fov_y_deg: float = 5.0

    def __post_init__(self):
        super().__post_init__()
        if self.columns < 1 or self.rows < 1 or not 0 < self.fov_x_deg < 180:
            raise ValueError("a flash array needs detectors and a field of view in (0, 180)")
        if not 0 < self.fov_y_deg < 180:
            raise ValueError(f"fov_y_deg must lie in (0, 180), got {self.fov_y_deg}")

    def detector_tangents(self) -> tuple[np.ndarray, np.ndarray]:
        """x/z of each column's and y/z of each row's centre ray."""
        tx = math.tan(math.radians(self.fov_x_deg) / 2)
        ty = math.tan(math.radians(self.fov_y_deg) / 2)
        x = tx * ((np.arange(self.columns) + 0.5) / self.columns * 2 - 1)
        y = ty * ((np.arange(self.rows) + 0.5) / self.rows * 2 - 1)
        return x, y

    def directions(self, window: TanWindow, rng: np.random.Generator) -> np.ndarray:
        x, y = self.detector_tangents()
        x = x[(x >= window.x0) & (x <= window.x1)]
        y = y[(y >= window.y0) & (y <= window.y1)]
        xx, yy = np.meshgrid(x, y)
        d = np.stack([xx, yy, np.ones_like(xx)], axis=-1).reshape(-1, 3)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass(frozen=True, kw_only=True)
class RosetteLidar(Lidar):
    """Two Risley prisms turning ``prism_turns`` revolutions per frame (opposite signs: a
    rosette of petals through the centre) deflect ``points`` beams per frame over a circular
    ``fov_deg``; the prisms' phases are random per frame (the pattern never repeats)."""

    kind: ClassVar[str] = "rosette"

    fov_deg: float = 38.4
    points: int = 10000
    prism_turns: tuple[float, float] = (12.2, -7.8)

    def __post_init__(self):
        super().__post_init__()
        object.__setattr__(self, "prism_turns", tuple(float(v) for v in self.prism_turns))
        if self.points < 1 or not 0 < self.fov_deg < 180 or len(self.prism_turns) != 2:
            raise ValueError("a rosette needs points, a field of view in (0, 180), two prisms")

    def directions(self, window: TanWindow, rng: np.random.Generator) -> np.ndarray:
        phase = rng.uniform(0, 2 * np.pi, 2)
        t = np.arange(self.points) / self.points
        a = 2 * np.pi * self.prism_turns[0] * t + phase[0]
        b = 2 * np.pi * self.prism_turns[1] * t + phase[1]
        half = math.radians(self.fov_deg) / 4  # each prism deflects by a quarter of the FOV
        dx, dy = half * (np.cos(a) + np.cos(b)), half * (np.sin(a) + np.sin(b))
        off_axis, around = np.hypot(dx, dy), np.arctan2(dy, dx)
        sin = np.sin(off_axis)
        d = np.stack([sin * np.cos(around), sin * np.sin(around), np.cos(off_axis)], axis=-1)
        return d[window.contains(d)]


#: Table 2 of the paper: 0.09 x 0.13 deg steps, 280 m, range error < 3 cm, 2 % dropout.
PAPER_SCANNER = ScanningLidar.from_spec(PAPER_LIDAR)

LIDAR_CLASSES: dict[str, type[Lidar]] = {
    c.kind: c for c in (ScanningLidar, MultiBeamLidar, FlashLidar, RosetteLidar)
}
#: What ``sample_lidar`` draws, and how often when no kind is asked for.
KIND_WEIGHTS: dict[str, float] = {
    "paper": 0.27,
    "grid": 0.27,
    "multibeam": 0.18,
    "flash": 0.18,
    "rosette": 0.10,
}
LIDAR_KINDS: tuple[str, ...] = tuple(KIND_WEIGHTS)


def lidar_from_metadata(meta: dict) -> Lidar:
    """The LIDAR that ``Lidar.metadata`` describes (values as rounded there)."""
    cls = LIDAR_CLASSES[meta["kind"]]
    return cls(**{f.name: meta[f.name] for f in fields(cls) if f.name in meta})


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _common(rng: np.random.Generator, max_range: tuple[float, float], noise, growth) -> dict:
    """Range, noise, losses and mounting of a drawn LIDAR."""
    radius, angle = rng.uniform(0.03, 0.3), rng.uniform(0, 2 * np.pi)
    return {
        "max_range_m": float(rng.uniform(*max_range)),
        "range_noise_m": float(rng.uniform(*noise)),
        "range_noise_per_100m": float(rng.uniform(*growth)),
        "dropout": float(rng.uniform(0.0, 0.08)),
        "dark_loss": float(rng.uniform(0.2, 0.95)) if rng.random() < 0.7 else 0.0,
        "dark_threshold": float(rng.uniform(0.03, 0.15)),
        "specular_loss": float(rng.uniform(0.2, 1.0)) if rng.random() < 0.7 else 0.0,
        "offset_m": (
            float(radius * np.cos(angle)),
            float(radius * np.sin(angle)),
            float(rng.uniform(-0.05, 0.05)),
        ),
    }


def sample_lidar(rng: np.random.Generator, K: Intrinsics, kind: str | None = None) -> Lidar:
    """A LIDAR for camera ``K``: ``kind`` one of ``LIDAR_KINDS``, or None for a random one
    (``KIND_WEIGHTS``). ``"paper"`` is Table 2 exactly; the others are drawn in plausible
    ranges, their patterns sized to the camera (pixel spacing, field of view)."""
    if kind is None:
        kind = str(rng.choice(LIDAR_KINDS, p=list(KIND_WEIGHTS.values())))
    if kind == "paper":
        return PAPER_SCANNER
    fov_x, fov_y = camera_fov_deg(K)
    if kind == "grid":
        spacing, aspect = _log_uniform(rng, 2.5, 30.0), _log_uniform(rng, 0.5, 2.0)
        du = float(np.clip(spacing * np.sqrt(aspect), 2.0, 40.0))  # pixels between beams
        dv = float(np.clip(spacing / np.sqrt(aspect), 2.0, 40.0))
        return ScanningLidar(
            horizontal_step_deg=math.degrees(math.atan(du / K.fx)),
            vertical_step_deg=math.degrees(math.atan(dv / K.fy)),
            **_common(rng, (200.0, 400.0), (0.003, 0.04), (0.0, 0.03)),
        )
    if kind == "multibeam":
        return MultiBeamLidar(
            beams=int(rng.choice([16, 32, 64, 128, 256])),
            vertical_fov_deg=float(rng.uniform(20.0, 45.0)),
            centre_density=float(rng.uniform(0.3, 0.8)) if rng.random() < 0.5 else 0.0,
            azimuth_step_deg=float(rng.uniform(0.05, 0.4)),
            tilt_deg=(float(rng.uniform(-3.0, 3.0)), float(rng.uniform(-5.0, 5.0))),
            **_common(rng, (150.0, 350.0), (0.005, 0.03), (0.0, 0.02)),
        )
    if kind == "flash":
        columns = round(_log_uniform(rng, 32, 256))
        rows = int(np.clip(round(columns * rng.uniform(0.75, 1.33)), 32, 256))
        fraction = rng.uniform(0.3, 1.0)
        return FlashLidar(
            columns=columns,
            rows=rows,
            fov_x_deg=float(fraction * fov_x),
            fov_y_deg=float(np.clip(fraction * rng.uniform(0.8, 1.25), 0.3, 1.0) * fov_y),
            **_common(rng, (150.0, 400.0), (0.01, 0.08), (0.0, 0.05)),
        )
    if kind == "rosette":
        turns = rng.uniform(5.0, 20.0)
        return RosetteLidar(
            fov_deg=float(np.clip(max(fov_x, fov_y) * rng.uniform(1.2, 6.0), 1.0, 90.0)),
            points=round(_log_uniform(rng, 1e4, 1e5)),
            prism_turns=(float(turns), float(-turns * rng.uniform(0.5, 0.9))),
            **_common(rng, (150.0, 350.0), (0.005, 0.03), (0.0, 0.02)),
        )
    raise ValueError(f"unknown LIDAR kind {kind!r}; expected one of {', '.join(LIDAR_KINDS)}")


def _bounding_corners(posed: PosedModel) -> np.ndarray:
    """The 8 corners of the mesh's bounding box in the camera frame."""
    corners = np.array(np.meshgrid(*posed.model.mesh.bounds.T)).reshape(3, -1).T
    return corners @ posed.scene.rotation.T + posed.scene.translation


def surface_loss(
    lidar: Lidar, posed: PosedModel, faces: np.ndarray, directions: np.ndarray
) -> np.ndarray:
    """Probability (0-1) that the returns of beams ``directions`` hitting ``faces`` are lost
    to the surface: dark (echo albedo * |cos incidence| under the threshold) and specular
    (mirrored share of the reflection, lost away from normal incidence)."""
    table = shading_arrays(posed.model.shading)
    material = posed.model.materials[faces]
    cos = np.abs(np.sum(posed.normals[faces] * directions, axis=1))
    albedo, specular = table["albedo"][material], table["specular"][material]
    shininess = table["shininess"][material]
    kept = np.ones(len(faces))
    if lidar.dark_loss > 0:
        fade = np.clip(1 - albedo * cos / lidar.dark_threshold, 0, 1)
        kept *= 1 - lidar.dark_loss * fade
    if lidar.specular_loss > 0:
        mirrored = specular / np.maximum(specular + albedo, 1e-9)
        mirrored *= shininess / (shininess + MIRROR_SHININESS)
        kept *= 1 - lidar.specular_loss * mirrored * (1 - cos**shininess)
    return 1 - kept


def _cast(
    caster: RayCaster,
    lidar: Lidar,
    K: Intrinsics,
    rng: np.random.Generator,
    window: TanWindow | None,
    posed: PosedModel | None,
) -> np.ndarray:
    sparse = np.zeros((K.height, K.width), np.float32)
    if window is None:
        return sparse
    origin = np.asarray(lidar.offset_m, np.float64)
    directions = lidar.directions(window, rng)
    faces, distance = caster.closest(np.broadcast_to(origin, directions.shape), directions)
    hit = faces >= 0
    faces, distance, directions = faces[hit], distance[hit], directions[hit]
    sigma = lidar.range_sigma(distance)
    measured = distance + np.clip(rng.normal(0.0, sigma), -3 * sigma, 3 * sigma)
    loss = surface_loss(lidar, posed, faces, directions) if lidar.has_losses else 0.0
    lost = rng.random(len(distance)) < lidar.dropout + (1 - lidar.dropout) * loss
    keep = (measured <= lidar.max_range_m) & ~lost
    points = origin + directions[keep] * measured[keep, None]
    points = points[points[:, 2] > 1e-6]  # in front of the camera
    u, v = K.project(points)
    u, v = np.round(u).astype(np.int64), np.round(v).astype(np.int64)
    inside = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
    nearest = np.full((K.height, K.width), np.inf, np.float32)
    np.minimum.at(nearest, (v[inside], u[inside]), points[inside, 2].astype(np.float32))
    sparse[np.isfinite(nearest)] = nearest[np.isfinite(nearest)]
    return sparse


def scan_lidar(
    posed: PosedModel, lidar: Lidar, K: Intrinsics, rng: np.random.Generator
) -> np.ndarray:
    """Sparse depth map (H, W) float32 of ``lidar`` looking at ``posed``: camera-frame Z in
    metres of each return at its nearest pixel (the nearest return wins), 0 elsewhere."""
    origin = np.asarray(lidar.offset_m, np.float64)
    window = lidar_window(K, origin, _bounding_corners(posed))
    return _cast(posed.caster, lidar, K, rng, window, posed)


def scan(
    caster: RayCaster, spec: LidarSpec | Lidar, K: Intrinsics, rng: np.random.Generator
) -> np.ndarray:
    """Sparse depth map (H, W) float32 of a LIDAR without surface losses (``LidarSpec``: a
    co-located ``ScanningLidar``) over the camera's whole field of view; see ``scan_lidar``."""
    lidar = spec if isinstance(spec, Lidar) else ScanningLidar.from_spec(spec)
    if lidar.has_losses:
        raise ValueError("dark and specular losses need the materials: use scan_lidar")
    origin = np.asarray(lidar.offset_m, np.float64)
    return _cast(caster, lidar, K, rng, lidar_window(K, origin), None)
