"""Users' mesh folders: a directory of mesh files, optionally with a manifest of scales.

``manifest.json`` is a list of entries ``{"file": "cassini.stl", "longest_m": 11.0}``
(``name`` and other keys are kept as notes). Without a manifest every mesh file in the
folder is used at its own units (times ``scale``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from sdcnet.training.data.spacecraft import MESH_SUFFIXES


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
        return tuple(MeshEntry(p, None, scale) for p in files)
    try:
        entries = json.loads(manifest.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{manifest} is not valid JSON: {exc}") from exc
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{manifest} must be a non-empty list of {{file, longest_m}} entries")
    result = []
    for k, entry in enumerate(entries):
        if not isinstance(entry, dict) or "file" not in entry:
            raise ValueError(f"{manifest} entry {k} has no 'file'")
        longest = entry.get("longest_m")
        if longest is not None and (not isinstance(longest, int | float) or longest <= 0):
            raise ValueError(
                f"{manifest} entry {k} ({entry['file']}): longest_m must be a positive number"
            )
        path = folder / entry["file"]
        if not path.is_file():
            raise FileNotFoundError(f"{manifest} entry {k}: mesh file not found: {path}")
        result.append(MeshEntry(path, None if longest is None else float(longest), scale))
    return tuple(result)
