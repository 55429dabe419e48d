"""Spacecraft models: procedural ones from a seed, and users' own mesh files.

A procedural spacecraft is drawn from one of a few archetypes that real spacecraft follow
(communications satellite, Earth observer, deep-space probe, radial-array probe, small sat)
and then varied in every part: bus shape, number and tilt of solar wings, dishes, antennas,
trusses, thrusters, sensors, radiators, materials. Sizes follow the paper (sec. IV):
solar wings 3-8 m, bus 1-3 m. The model depends only on (seed, model id).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from sdcnet.meshes import load_scaled_mesh
from sdcnet.training.data import parts
from sdcnet.training.data.materials import Material, Shading, jittered_shading
from sdcnet.training.data.parts import Assembly, pose, rot

ARCHETYPES = ("comsat", "observer", "probe", "radial", "smallsat")


@dataclass
class SpacecraftModel:
    """A triangle mesh in metres, centred on its bounding box, with its surface description."""

    name: str
    mesh: trimesh.Trimesh
    materials: np.ndarray  # (F,) Material id per face
    texture: np.ndarray  # (F, 9) solar-cell grid frame per face (zeros where none)
    shading: list[Shading]  # indexed by Material value
    crinkle_waves: np.ndarray  # (K, 4): wave vector (1/m) and phase of the MLI crinkle
    #: Where the origin of the user's mesh file lies in this centred frame, metres (zeros for
    #: procedural models): a known target's frame is the file's (``sdcnet.targets``).
    frame_origin: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def longest_m(self) -> float:
        return float(np.max(self.mesh.extents))

    @property
    def radius_m(self) -> float:
        """Radius of the sphere about the centre that holds the whole mesh, metres."""
        return float(np.max(np.linalg.norm(self.mesh.vertices, axis=1)))

    def file_frame_pose(
        self, rotation: np.ndarray, translation: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """(R, t) of the file's frame, p_camera = R p_file + t, for the model placed at
        (``rotation``, ``translation``) (its centred frame in the camera frame, metres)."""
        return rotation, translation + rotation @ self.frame_origin


def _rng(seed: int, model_id: int, purpose: int) -> np.random.Generator:
    return np.random.default_rng([seed, model_id, purpose])


def _crinkle_waves(rng: np.random.Generator, count: int = 8) -> np.ndarray:
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    wavelengths = rng.uniform(0.04, 0.3, size=(count, 1))
    phases = rng.uniform(0, 2 * np.pi, size=(count, 1))
    return np.hstack([directions * 2 * np.pi / wavelengths, phases])


def _finish(name: str, assembly: Assembly, rng: np.random.Generator) -> SpacecraftModel:
    mesh, materials, texture = assembly.build()
    centre = mesh.bounds.mean(axis=0)
    mesh.apply_translation(-centre)
    has_tex = np.any(texture, axis=1)
    texture[has_tex, 0:3] -= centre
    return SpacecraftModel(
        name, mesh, materials, texture, jittered_shading(rng), _crinkle_waves(rng)
    )


# --- procedural spacecraft -----------------------------------------------------------------


@dataclass
class _Bus:
    mesh: trimesh.Trimesh
    half: np.ndarray  # half extents along x, y, z in metres


def _bus(rng: np.random.Generator, archetype: str) -> _Bus:
    lo, hi = (0.8, 1.4) if archetype == "smallsat" else (1.0, 3.0)
    shape = rng.choice(["box", "box", "hex", "oct", "cylinder"])
    if shape == "box":
        ext = rng.uniform(lo, hi, size=3)
        mesh = parts.box(ext)
    else:
        sides = {"hex": 6, "oct": 8, "cylinder": 32}[shape]
        radius, height = rng.uniform(lo, hi) / 2, rng.uniform(lo, hi)
        mesh = parts.prism(sides, radius, height)
        mesh.apply_transform(pose(rot("z", rng.uniform(0, np.pi))))
    return _Bus(mesh, mesh.extents / 2)


def _surface_point(bus: _Bus, direction: np.ndarray, rng: np.random.Generator, spread=0.6):
    """A point on the bus's bounding box face that ``direction`` points through."""
    axis = int(np.argmax(np.abs(direction)))
    p = rng.uniform(-spread, spread, size=3) * bus.half
    p[axis] = np.sign(direction[axis]) * bus.half[axis]
    return p


def _wing(rng: np.random.Generator, length: float, width: float, back: Material) -> Assembly:
    """Solar wing along +y from the origin: a boom, then 1-5 panels with gaps, one tilt."""
    wing = Assembly()
    boom = rng.uniform(0.3, 1.5)
    radius = rng.uniform(0.02, 0.06)
    m, T = parts.rod_between((0, 0, 0), (0, boom + 0.05, 0), radius)
    wing.add(m, Material.METAL, T)
    segments = int(rng.integers(1, 6))
    gap = rng.uniform(0.03, 0.15)
    seg_len = (length - gap * (segments - 1)) / segments
    thickness = rng.uniform(0.025, 0.06)
    tilt = rot("y", rng.uniform(-np.pi / 3, np.pi / 3))
    for k in range(segments):
        y = boom + k * (seg_len + gap) + seg_len / 2
        mesh, materials, texture = parts.solar_panel(width, seg_len, thickness, back)
        wing.add(mesh, materials, pose(tilt, (0, y, 0)), texture)
    if rng.random() < 0.5:  # a yoke or stiffener along the wing
        m, T = parts.rod_between((0, boom, 0), (0, boom + length, 0), radius * 0.6)
        wing.add(m, Material.DARK, pose(tilt) @ T)
    return wing


def _add_wings(sc: Assembly, bus: _Bus, rng: np.random.Generator, archetype: str) -> None:
    count = {
        "comsat": 2,
        "observer": int(rng.choice([1, 2])),
        "probe": int(rng.choice([0, 0, 2])),
        "radial": int(rng.choice([3, 4])),
        "smallsat": int(rng.choice([2, 4])),
    }[archetype]
    if count == 0:
        return
    length = rng.uniform(3.0, 8.0) if archetype != "smallsat" else rng.uniform(1.0, 3.0)
    width = rng.uniform(1.0, 3.0) if archetype != "smallsat" else rng.uniform(0.6, 1.2)
    back = rng.choice([Material.WHITE_PAINT, Material.DARK, Material.METAL])
    z = rng.uniform(-0.5, 0.5) * bus.half[2]
    if count == 1:
        angles = [0.0]
    elif count == 2 or archetype == "smallsat":
        angles = list(np.arange(count) * 2 * np.pi / count)
    else:
        angles = list(np.arange(count) * 2 * np.pi / count + rng.uniform(0, np.pi))
    for angle in angles:
        own = np.random.default_rng(rng.integers(2**32))
        wing = _wing(own, length * rng.uniform(0.95, 1.05), width, back)
        direction = rot("z", angle) @ np.array([0.0, 1.0, 0.0])
        reach = float(np.max(np.abs(direction[:2]) * bus.half[:2]))
        sc.merge(wing, pose(rot("z", angle), direction * reach + (0, 0, z)))


def _add_dishes(sc: Assembly, bus: _Bus, rng: np.random.Generator, archetype: str) -> None:
    count = {
        "comsat": int(rng.integers(1, 4)),
        "observer": int(rng.integers(0, 2)),
        "probe": 1,
        "radial": 1,
        "smallsat": int(rng.integers(0, 2)),
    }[archetype]
    for k in range(count):
        big = archetype == "probe" and k == 0
        diameter = rng.uniform(2.0, 4.0) if big else rng.uniform(0.4, 2.2)
        if archetype == "comsat" and rng.random() < 0.4:  # large reflectors (TDRS-like)
            diameter = rng.uniform(2.5, 4.5)
        if archetype == "smallsat":
            diameter = rng.uniform(0.3, 0.7)
        depth = diameter * rng.uniform(0.08, 0.25)
        candidates = [(0, 0, 1), (1, 0, 0), (-1, 0, 0), (0, 0, -1)]
        direction = np.array(candidates[0 if big else int(rng.integers(len(candidates)))], float)
        direction = rot("y", rng.uniform(-0.4, 0.4)) @ direction
        base = _surface_point(bus, direction, rng, spread=0.0 if big else 0.5)
        mast = 0.05 if big else rng.uniform(0.1, 1.0)
        m, T = parts.rod_between(base, base + direction * mast, rng.uniform(0.03, 0.08))
        sc.add(m, Material.METAL, T)
        material = rng.choice([Material.WHITE_PAINT, Material.MLI_GOLD, Material.METAL])
        sc.add(
            parts.dish(diameter, depth),
            material,
            pose(parts.align_z_to(direction), base + direction * mast),
        )


def _add_appendages(sc: Assembly, bus: _Bus, rng: np.random.Generator, archetype: str) -> None:
    def random_direction():
        d = rng.normal(size=3)
        return d / np.linalg.norm(d)

    for _ in range(int(rng.integers(0, 5))):  # whip antennas
        d = random_direction()
        p = _surface_point(bus, d, rng)
        m, T = parts.rod_between(p, p + d * rng.uniform(0.5, 3.0), rng.uniform(0.01, 0.04))
        sc.add(m, rng.choice([Material.METAL, Material.DARK, Material.WHITE_PAINT]), T)
    if rng.random() < 0.3:  # a long, slender magnetometer or antenna boom
        d = random_direction()
        p = _surface_point(bus, d, rng, spread=0.3)
        m, T = parts.rod_between(p, p + d * rng.uniform(3.0, 11.0), rng.uniform(0.015, 0.05))
        sc.add(m, rng.choice([Material.METAL, Material.DARK, Material.WHITE_PAINT]), T)
    n_truss = int(rng.integers(1, 3)) if archetype == "probe" else int(rng.random() < 0.25)
    for _ in range(n_truss):  # magnetometer or instrument booms
        d = random_direction()
        d[2] *= 0.3
        d /= np.linalg.norm(d)
        p = _surface_point(bus, d, rng, spread=0.3)
        length = rng.uniform(2.0, 8.0)
        boom = parts.truss(length, rng.uniform(0.15, 0.4), int(rng.integers(3, 10)), 0.015)
        T = pose(parts.align_z_to(d), p)
        sc.merge(boom, T)
        tip = rng.uniform(0.15, 0.5, size=3)
        sc.add(parts.box(tip), Material.MLI_SILVER, T @ pose(None, (0, 0, length + tip[2] / 2)))
    if archetype == "probe":  # radioisotope generators on short booms, with fins
        for _ in range(int(rng.integers(0, 3))):
            d = random_direction()
            d[2] = 0.0
            d /= np.linalg.norm(d)
            p = _surface_point(bus, d, rng, spread=0.2)
            reach = rng.uniform(0.8, 2.0)
            m, T = parts.rod_between(p, p + d * reach, 0.04)
            sc.add(m, Material.METAL, T)
            rtg = pose(parts.align_z_to(d), p + d * (reach + 0.6))
            sc.add(parts.prism(16, 0.2, 1.1), Material.DARK, rtg)
            for k in range(4):
                fin = pose(rot("z", k * np.pi / 2), (0.28, 0, 0))
                sc.add(parts.box((0.2, 0.01, 1.0)), Material.DARK, rtg @ fin)
    for _ in range(int(rng.integers(1, 5))):  # thrusters on the aft face
        p = _surface_point(bus, np.array([0.0, 0.0, -1.0]), rng, spread=0.7)
        size = rng.uniform(0.05, 0.3)
        sc.add(parts.nozzle(size, size * 2.5), Material.METAL, pose(None, p))
    for _ in range(int(rng.integers(1, 6))):  # instruments, star trackers
        d = np.zeros(3)
        d[int(rng.integers(3))] = rng.choice([-1.0, 1.0])
        p = _surface_point(bus, d, rng, spread=0.7)
        ext = rng.uniform(0.15, 0.7, size=3)
        if rng.random() < 0.5:
            sc.add(
                parts.box(ext),
                rng.choice(list(Material)[1:]),
                pose(parts.align_z_to(d), p + d * ext[2] / 2),
            )
        else:
            m = parts.rod(ext[0] / 2, ext[2], sections=16)
            sc.add(m, rng.choice([Material.DARK, Material.METAL]), pose(parts.align_z_to(d), p))
    if rng.random() < 0.5:  # radiator on a side face
        d = np.array([rng.choice([-1.0, 1.0]), 0.0, 0.0])
        p = _surface_point(bus, d, rng, spread=0.0)
        ext = (
            0.02,
            2 * bus.half[1] * rng.uniform(0.6, 0.95),
            2 * bus.half[2] * rng.uniform(0.6, 0.95),
        )
        sc.add(parts.box(ext), Material.RADIATOR, pose(None, p + d * 0.011))
    if archetype == "observer" and rng.random() < 0.5:  # a sunshade or SAR panel
        ext = (rng.uniform(1.5, 3.5), rng.uniform(1.5, 3.5), 0.05)
        d = np.array([0.0, 0.0, 1.0])
        gap = rng.uniform(0.2, 0.8)
        m, T = parts.rod_between(bus.half * d, bus.half * d + d * gap, 0.05)
        sc.add(m, Material.METAL, T)
        material = rng.choice([Material.WHITE_PAINT, Material.SOLAR_CELL, Material.MLI_SILVER])
        sc.add(
            parts.box(ext), material, pose(rot("x", rng.uniform(-0.5, 0.5)), bus.half * d + d * gap)
        )


def procedural_spacecraft(seed: int, model_id: int) -> SpacecraftModel:
    """The ``model_id``-th procedural spacecraft of ``seed``; deterministic."""
    rng = _rng(seed, model_id, 0)
    archetype = str(ARCHETYPES[int(rng.integers(len(ARCHETYPES)))])
    bus = _bus(rng, archetype)
    sc = Assembly()
    skin = rng.choice(
        [Material.MLI_GOLD, Material.MLI_GOLD, Material.MLI_SILVER, Material.WHITE_PAINT]
    )
    sc.add(bus.mesh, skin)
    if archetype == "smallsat" and rng.random() < 0.6:  # body-mounted cells
        for sign in (-1.0, 1.0):
            width, length = 2 * bus.half[0] * 0.9, 2 * bus.half[2] * 0.9
            mesh, mats, tex = parts.solar_panel(width, length, 0.01, Material.DARK)
            T = pose(rot("x", -sign * np.pi / 2), (0, sign * (bus.half[1] + 0.006), 0))
            sc.add(mesh, mats, T, tex)
    _add_wings(sc, bus, rng, archetype)
    _add_dishes(sc, bus, rng, archetype)
    _add_appendages(sc, bus, rng, archetype)
    return _finish(f"proc-{model_id:03d}-{archetype}", sc, _rng(seed, model_id, 1))


# --- users' own meshes ---------------------------------------------------------------------


def _principal_frame(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre, axes (rows, longest first) and full extents of a point set along its axes."""
    centre = points.mean(axis=0)
    _, _, axes = np.linalg.svd(points - centre, full_matrices=False)
    local = (points - centre) @ axes.T
    lo, hi = local.min(axis=0), local.max(axis=0)
    return centre + ((lo + hi) / 2) @ axes, axes, hi - lo


def infer_materials(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Deterministic materials for a mesh that carries none, by connected part.

    The rule reads each connected component's principal extents e1 >= e2 >= e3 (metres):
    - thin and broad (e3 < 6 % of e2, e2 > 0.4 m, e1 * e2 > 1 m^2): a solar panel, cells on
      both broad faces, grid along its principal axes;
    - thin and small: a radiator;
    - long and slender (e1 > 6 e2): a boom, metal;
    - the largest bulky part: the bus, gold MLI; other bulky parts: silver MLI.
    """
    labels = trimesh.graph.connected_component_labels(
        mesh.face_adjacency, node_count=len(mesh.faces)
    )
    materials = np.full(len(mesh.faces), Material.MLI_SILVER, dtype=np.int16)
    texture = np.zeros((len(mesh.faces), 9))
    bulky: list[tuple[float, np.ndarray]] = []
    for label in np.unique(labels):
        faces = np.flatnonzero(labels == label)
        points = mesh.vertices[np.unique(mesh.faces[faces])]
        if len(points) < 3:
            continue
        centre, axes, ext = _principal_frame(points)
        e1, e2, e3 = ext
        if e3 < 0.06 * e2 and e2 > 0.4 and e1 * e2 > 1.0:
            materials[faces] = Material.SOLAR_CELL
            origin = centre - axes[0] * e1 / 2 - axes[1] * e2 / 2
            texture[faces] = np.concatenate([origin, axes[0], axes[1]])
        elif e3 < 0.06 * e2:
            materials[faces] = Material.RADIATOR
        elif e1 > 6 * e2:
            materials[faces] = Material.METAL
        else:
            bulky.append((e1 * e2 * e3, faces))
    if bulky:
        materials[max(bulky, key=lambda b: b[0])[1]] = Material.MLI_GOLD
    return materials, texture


def load_mesh_file(
    path: str | Path, longest_m: float | None = None, scale: float = 1.0, seed: int = 0
) -> SpacecraftModel:
    """A user's mesh (OBJ/STL/PLY/glTF/OFF) as a spacecraft model, centred, in metres.

    Scaled as ``sdcnet.meshes.load_scaled_mesh`` says, then centred on its bounding box
    (``frame_origin`` keeps where the file's origin went). Materials follow
    ``infer_materials``. Raises FileNotFoundError or ValueError with the reason.
    """
    path = Path(path)
    mesh = load_scaled_mesh(path, longest_m, scale)
    centre = mesh.bounds.mean(axis=0)
    mesh.apply_translation(-centre)
    materials, texture = infer_materials(mesh)
    rng = np.random.default_rng([seed, zlib.crc32(path.stem.encode()), 1])
    return SpacecraftModel(
        path.stem,
        mesh,
        materials,
        texture,
        jittered_shading(rng),
        _crinkle_waves(rng),
        frame_origin=-centre,
    )
