"""CAD-like spacecraft parts as triangle meshes, in metres.

An ``Assembly`` collects parts, each with a material per face and, for solar arrays, a
texture frame (origin and two in-plane axes) so the renderer can draw the cell grid.
Every builder works in the part's own frame; ``Assembly.add`` places it with a 4 x 4 pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from sdcnet.training.data.materials import Material


def pose(rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4 x 4 rigid transform from a 3 x 3 rotation and a translation in metres."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def rot(axis: str, angle_rad: float) -> np.ndarray:
    """3 x 3 rotation about a principal axis ('x', 'y' or 'z')."""
    v = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[axis]
    return trimesh.transformations.rotation_matrix(angle_rad, v)[:3, :3]


def align_z_to(direction) -> np.ndarray:
    """Rotation taking +z to ``direction`` (unit vector)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    c = float(np.dot(z, d))
    if c > 1 - 1e-9:
        return np.eye(3)
    if c < -1 + 1e-9:
        return rot("x", np.pi)
    axis = np.cross(z, d)
    return trimesh.transformations.rotation_matrix(np.arccos(c), axis)[:3, :3]


@dataclass
class Assembly:
    """A spacecraft under construction: triangles with a material and a texture frame each."""

    vertices: list[np.ndarray] = field(default_factory=list)
    faces: list[np.ndarray] = field(default_factory=list)
    materials: list[np.ndarray] = field(default_factory=list)
    texture: list[np.ndarray] = field(default_factory=list)  # (F, 9): origin, u, v
    _count: int = 0

    def add(
        self,
        mesh: trimesh.Trimesh,
        material: Material | np.ndarray,
        transform: np.ndarray | None = None,
        texture: np.ndarray | None = None,
    ) -> None:
        """Add ``mesh`` placed by ``transform``; ``material`` is one id or one per face."""
        T = np.eye(4) if transform is None else transform
        verts = trimesh.transform_points(mesh.vertices, T)
        n_faces = len(mesh.faces)
        self.vertices.append(verts)
        self.faces.append(np.asarray(mesh.faces) + self._count)
        self._count += len(verts)
        self.materials.append(np.broadcast_to(np.asarray(material, dtype=np.int16), (n_faces,)))
        tex = np.zeros((n_faces, 9)) if texture is None else texture
        if texture is not None:  # texture frames are given in the part's frame
            tex = tex.copy()
            tex[:, 0:3] = trimesh.transform_points(tex[:, 0:3], T)
            tex[:, 3:6] = tex[:, 3:6] @ T[:3, :3].T
            tex[:, 6:9] = tex[:, 6:9] @ T[:3, :3].T
        self.texture.append(tex)

    def merge(self, other: Assembly, transform: np.ndarray) -> None:
        """Add every part of ``other``, placed by ``transform``."""
        for v, f, m, t in zip(
            other.vertices, other.faces, other.materials, other.texture, strict=True
        ):
            sub = trimesh.Trimesh(v, f - f.min() if len(f) else f, process=False)
            has_tex = bool(np.any(t))
            self.add(sub, m, transform, t if has_tex else None)

    def build(self) -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
        """One mesh, its per-face material ids and per-face texture frames."""
        mesh = trimesh.Trimesh(np.vstack(self.vertices), np.vstack(self.faces), process=False)
        return mesh, np.concatenate(self.materials), np.vstack(self.texture)


def box(extents) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents)


def prism(sides: int, radius: float, height: float) -> trimesh.Trimesh:
    """Regular prism along z (hexagonal, octagonal bus) or, with many sides, a cylinder."""
    return trimesh.creation.cylinder(radius=radius, height=height, sections=sides)


def rod(radius: float, length: float, sections: int = 10) -> trimesh.Trimesh:
    """Thin cylinder along z from z=0 to z=length."""
    m = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    m.apply_translation((0, 0, length / 2))
    return m


def rod_between(a, b, radius: float, sections: int = 6) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A rod from point a to point b, returned with the transform that places it."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = float(np.linalg.norm(b - a))
    return rod(radius, length, sections), pose(align_z_to(b - a), a)


def dish(
    diameter: float, depth: float, thickness: float = 0.03, sections: int = 40
) -> trimesh.Trimesh:
    """Parabolic reflector opening towards +z, vertex at the origin, with a rim thickness."""
    r = np.linspace(0.0, diameter / 2, 12)
    z = depth * (r / r[-1]) ** 2
    outer = np.column_stack([r, z])
    inner = np.column_stack([r[::-1], z[::-1] - thickness])
    profile = np.vstack([outer, inner])
    profile[0, 0] = 0.0
    profile[-1, 0] = 0.0
    return trimesh.creation.revolve(profile, sections=sections)


def nozzle(exit_radius: float, length: float, sections: int = 20) -> trimesh.Trimesh:
    """Bell-shaped thruster nozzle along -z from the origin, open at the exit."""
    t = np.linspace(0.0, 1.0, 8)
    r = exit_radius * (0.35 + 0.65 * t**1.5)
    z = -length * t
    outer = np.column_stack([r, z])
    inner = np.column_stack([r[::-1] * 0.9, z[::-1]])
    return trimesh.creation.revolve(np.vstack([outer, inner]), sections=sections)


def solar_panel(
    width: float, length: float, thickness: float, back: Material
) -> tuple[trimesh.Trimesh, np.ndarray, np.ndarray]:
    """Flat panel in the xy plane, cells on the +z face, ``back`` on the rest.

    Returns the mesh, per-face materials and texture frames (cell grid axes along x and y).
    """
    mesh = box((width, length, thickness))
    front = mesh.face_normals[:, 2] > 0.9
    materials = np.where(front, Material.SOLAR_CELL, back).astype(np.int16)
    texture = np.zeros((len(mesh.faces), 9))
    texture[front] = [-width / 2, -length / 2, thickness / 2, 1, 0, 0, 0, 1, 0]
    return mesh, materials, texture


def truss(length: float, width: float, bays: int, radius: float) -> Assembly:
    """Square lattice boom along +z: four longerons, rings and diagonals."""
    part = Assembly()
    h = width / 2
    corners = [(-h, -h), (h, -h), (h, h), (-h, h)]
    for x, y in corners:
        m, T = rod_between((x, y, 0), (x, y, length), radius)
        part.add(m, Material.METAL, T)
    for k in range(bays + 1):
        z = length * k / bays
        for i in range(4):
            (x0, y0), (x1, y1) = corners[i], corners[(i + 1) % 4]
            m, T = rod_between((x0, y0, z), (x1, y1, z), radius * 0.7)
            part.add(m, Material.METAL, T)
            if k < bays:
                z1 = length * (k + 1) / bays
                m, T = rod_between((x0, y0, z), (x1, y1, z1), radius * 0.6)
                part.add(m, Material.METAL, T)
    return part
