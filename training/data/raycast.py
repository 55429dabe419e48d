"""Thin wrapper over Embree (through embreex): closest hits and occlusion for ray batches."""

from __future__ import annotations

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh


class RayCaster:
    """Ray queries against one set of triangles, given in the frame the rays use (metres)."""

    def __init__(self, triangles: np.ndarray):
        self._scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self._scene, np.ascontiguousarray(triangles, dtype=np.float32))

    def closest(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Face index (-1 = miss) and distance along each unit direction to the first hit."""
        if len(directions) == 0:
            return np.empty(0, np.int64), np.empty(0, np.float64)
        res = self._scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            output=1,
        )
        face = res["primID"].astype(np.int64)
        face[res["geomID"] < 0] = -1
        return face, res["tfar"].astype(np.float64)

    def occluded(
        self, origins: np.ndarray, directions: np.ndarray, max_distance: float
    ) -> np.ndarray:
        """Whether anything lies within ``max_distance`` along each ray."""
        if len(directions) == 0:
            return np.zeros(0, bool)
        hit = self._scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
            dists=np.full(len(origins), max_distance, dtype=np.float32),
            query="OCCLUDED",
        )
        return hit >= 0
