"""Users' mesh files: a folder of meshes with an optional manifest of scales, and one mesh
loaded in its own frame, in metres.

Shared by the dataset generator (``sdc-data --meshes``) and the service's known targets
(``sdc-serve --targets``). Needs trimesh (the ``data`` and ``serve`` extras), no torch.

``manifest.json`` is a list of entries ``{"file": "cassini.stl", "longest_m": 11.0}``
(``name`` and other keys are kept as notes). Without a manifest every mesh file in the
folder is used at its own units (times ``scale``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".glb", ".gltf", ".off")


@dataclass(frozen=True)
class MeshEntry:
    path: Path
    longest_m: float | None = None
    scale: float = 1.0

    def describe(self) -> dict:
        return {"file": self.path.name, "longest_m": self.longest_m, "scale": self.scale}


def read_mesh_folder(folder: str | Path, scale: float = 1.0) -> tuple[MeshEntry, ...]:
    """Mesh entries of a folder, from its manifest.json if present. Clear errors otherwise."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"mesh folder not found: {folder}")
    manifest = folder / "manifest.json"
    if not manifest.exists():
        files = sorted(p for p in folder.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
        if not files:
            raise ValueError(f"no mesh files ({', '.join(MESH_SUFFIXES)}) in {folder}")
        for path in files:
            _inside(folder, path, path.name)
        return tuple(MeshEntry(p, None, scale) for p in files)
    try:
        entries = json.loads(manifest.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{manifest} is not valid JSON: {exc}") from exc
    except RecursionError:
        raise ValueError(f"{manifest} nests too deep to be a list of entries") from None
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{manifest} must be a non-empty list of {{file, longest_m}} entries")
    return tuple(_entry(folder, manifest, k, entry, scale) for k, entry in enumerate(entries))


def _entry(folder: Path, manifest: Path, k: int, entry: object, scale: float) -> MeshEntry:
    """Entry ``k`` of a manifest, checked: ``file`` the name of a file inside the folder (once
    links are resolved), ``longest_m`` a positive finite number (not a boolean) or absent."""
    if not isinstance(entry, dict) or "file" not in entry:
        raise ValueError(f"{manifest} entry {k} has no 'file'")
    name = entry["file"]
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"{manifest} entry {k}: 'file' must be a file name, got {name!r}")
    longest = entry.get("longest_m")
    if longest is not None and (
        isinstance(longest, bool)
        or not isinstance(longest, int | float)
        or not math.isfinite(longest)
        or longest <= 0
    ):
        raise ValueError(
            f"{manifest} entry {k} ({name}): longest_m must be a positive number of metres, "
            f"got {longest!r}"
        )
    path = _inside(folder, folder / name, f"{manifest} entry {k}: {name}")
    if not path.is_file():
        raise FileNotFoundError(f"{manifest} entry {k}: mesh file not found: {path}")
    return MeshEntry(path, None if longest is None else float(longest), scale)


def _inside(folder: Path, path: Path, what: str) -> Path:
    """``path`` when it lies in ``folder`` once links are resolved; ValueError otherwise."""
    if not path.resolve().is_relative_to(folder.resolve()):
        raise ValueError(
            f"{what} lies outside the folder {folder} (links resolved): a folder's meshes are "
            "its own files"
        )
    return path


def load_scaled_mesh(
    path: str | Path, longest_m: float | None = None, scale: float = 1.0
) -> trimesh.Trimesh:
    """The triangles of a mesh file (OBJ/STL/PLY/glTF/GLB/OFF) in the file's own frame, in
    metres: a glTF scene's node transforms are applied, then the whole is scaled uniformly
    so that its longest bounding-box extent is ``longest_m`` (else its units times ``scale``
    are metres). Not centred: the file's origin stays the origin.
    Raises FileNotFoundError or ValueError with the reason.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(
            f"unsupported mesh format {path.suffix!r} for {path}; use one of {MESH_SUFFIXES}"
        )
    try:
        # force="mesh" flattens a scene: every node's geometry moved by its world transform.
        mesh = trimesh.load(path, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for malformed files
        raise ValueError(f"cannot read mesh {path}: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"mesh {path} holds no triangles")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(f"mesh {path} has vertices that are not finite numbers")
    extent = float(np.max(mesh.extents))
    if not extent > 0 or not mesh.area > 0:
        raise ValueError(
            f"mesh {path} is degenerate: its triangles span {extent:g} units and cover "
            f"{mesh.area:g} square units"
        )
    if longest_m is not None:
        if longest_m <= 0:
            raise ValueError(f"longest_m must be positive, got {longest_m}")
        scale = longest_m / extent
    mesh.apply_scale(scale)
    return mesh
