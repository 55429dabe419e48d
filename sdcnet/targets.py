"""Known targets: the spacecraft whose pose the service estimates, prepared once at start-up.

``load_targets(folder)`` reads a folder of meshes as ``sdc-data --meshes`` does (a
``manifest.json`` of ``{"file": ..., "longest_m": ...}`` entries, see ``sdcnet.meshes``). A
target's name is its file's stem; its frame is the mesh file's own coordinates (a glTF
scene's node transforms applied) scaled uniformly so that its longest bounding-box extent is
``longest_m`` metres. Each target is prepared for registration (``sdcnet.registration``)
once, here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sdcnet.meshes import MeshEntry, load_scaled_mesh, read_mesh_folder
from sdcnet.registration import DEFAULT_CONFIG, RegistrationConfig, TargetModel


class TargetError(ValueError):
    """A targets folder, manifest or mesh that cannot be used; the message says why."""


@dataclass(frozen=True)
class Target:
    """One known spacecraft: its mesh in its own frame (metres) and its registration model."""

    name: str
    file: str
    vertices: np.ndarray  # (V, 3) float32, target frame, metres
    faces: np.ndarray  # (F, 3) int32
    model: TargetModel

    @property
    def longest_m(self) -> float:
        return self.model.longest_m

    def describe(self) -> dict:
        """What ``GET /model`` says about it."""
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return {
            "name": self.name,
            "file": self.file,
            "longest_m": round(self.longest_m, 6),
            "bounds_m": [np.round(lo, 6).tolist(), np.round(hi, 6).tolist()],
            "faces": len(self.faces),
            "symmetries": len(self.model.symmetries),
            "near_twins": len(self.model.near_twins),
        }


def prepare_target(
    name: str,
    vertices: np.ndarray,
    faces: np.ndarray,
    file: str = "",
    config: RegistrationConfig = DEFAULT_CONFIG,
) -> Target:
    """A target from a triangle mesh already in its frame, metres."""
    model = TargetModel(vertices, faces, config)
    return Target(name, file, np.asarray(vertices, np.float32), np.asarray(faces, np.int32), model)


def load_target(entry: MeshEntry, config: RegistrationConfig = DEFAULT_CONFIG) -> Target:
    """The target of one mesh entry; ``TargetError`` naming the file when it cannot be used."""
    try:
        mesh = load_scaled_mesh(entry.path, entry.longest_m, entry.scale)
        return prepare_target(entry.path.stem, mesh.vertices, mesh.faces, entry.path.name, config)
    except (FileNotFoundError, ValueError) as exc:
        raise TargetError(f"target {entry.path.name}: {exc}") from exc


def load_targets(
    folder: str | Path, config: RegistrationConfig = DEFAULT_CONFIG
) -> dict[str, Target]:
    """Every target of a folder by name; ``TargetError`` with the reason when the folder, its
    manifest or one of its meshes cannot be used, or two files share a name."""
    try:
        entries = read_mesh_folder(folder)
    except (FileNotFoundError, ValueError) as exc:
        raise TargetError(f"targets folder {folder}: {exc}") from exc
    stems = [entry.path.stem for entry in entries]
    repeated = sorted({s for s in stems if stems.count(s) > 1})
    if repeated:
        raise TargetError(
            f"targets folder {folder}: several files share the name {', '.join(repeated)} "
            "(a target's name is its file's stem)"
        )
    return {entry.path.stem: load_target(entry, config) for entry in entries}
