"""Known targets for the pose tests, without the generator: a small spacecraft built from
trimesh's primitives, a targets folder as ``sdc-serve --targets`` reads it, and a frame of a
mesh at a known pose, ray cast with numpy (no Embree), for the tiny model to complete.

Needs trimesh (the ``serve`` extra).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import trimesh

from sdcnet.camera import PAPER_CAMERA, Intrinsics
from sdcnet.dataset_format import Sample
from sdcnet.rigid import Pose
from tests.support.frames import beam_grid

#: Rays intersected with every triangle at once, per chunk: bounds the memory of ``cast_depth``.
_RAYS_PER_CHUNK = 2048


def _placed(mesh: trimesh.Trimesh, at: tuple[float, float, float]) -> trimesh.Trimesh:
    mesh.apply_translation(at)
    return mesh


def probe_mesh() -> trimesh.Trimesh:
    """A spacecraft of primitives with no symmetry, 6.3 m long (x -1.3 .. 5 m) in its frame:
    a box bus, one solar wing on its +x side, a mast and a dish off-centre on top, a nozzle
    off-centre below. The same mesh every call."""
    mast = trimesh.creation.cylinder(0.08, 1.5, sections=12)
    dish = trimesh.creation.cone(0.7, 0.3, sections=24)
    nozzle = trimesh.creation.cylinder(0.3, 0.5, sections=16)
    return trimesh.util.concatenate(
        [
            trimesh.creation.box((2.0, 1.6, 1.2)),
            _placed(trimesh.creation.box((4.0, 1.2, 0.05)), (3.0, 0.0, 0.0)),
            _placed(mast, (-0.6, 0.4, 1.35)),
            _placed(dish, (-0.6, 0.4, 2.1)),
            _placed(nozzle, (0.5, -0.5, -0.85)),
        ]
    )


def write_targets(folder: Path, meshes: dict[str, tuple[trimesh.Trimesh, float | None]]) -> Path:
    """A targets folder: ``NAME.stl`` per mesh and the ``manifest.json`` giving each its
    ``longest_m`` (``None``: the file's own units are metres); returns ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    manifest = []
    for name, (mesh, longest_m) in meshes.items():
        mesh.export(folder / f"{name}.stl")
        entry = {"file": f"{name}.stl"}
        if longest_m is not None:
            entry["longest_m"] = longest_m
        manifest.append(entry)
    (folder / "manifest.json").write_text(json.dumps(manifest))
    return folder


def cast_depth(mesh: trimesh.Trimesh, pose: Pose, K: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """The mesh at ``pose`` (p_camera = R p_mesh + t) seen through ``K``: camera-frame Z of
    the nearest surface through each pixel's centre, float32 (H, W) metres (0 = sky), and the
    cosine between that surface's normal and the ray (0 on the sky), by Moller-Trumbore."""
    triangles = pose.apply(mesh.vertices)[mesh.faces]  # (F, 3 corners, 3)
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    normals = np.cross(e1, e2)
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    rays = np.stack(
        [(u.ravel() - K.cx) / K.fx, (v.ravel() - K.cy) / K.fy, np.ones(u.size)], axis=1
    )  # Z = 1: the distance along a ray is its Z
    depth = np.zeros(len(rays))
    facing = np.zeros(len(rays))
    for start in range(0, len(rays), _RAYS_PER_CHUNK):
        d = rays[start : start + _RAYS_PER_CHUNK, None, :]  # (R, 1, 3)
        p = np.cross(d, e2)  # (R, F, 3)
        det = np.einsum("fk,rfk->rf", e1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = -v0  # the camera at the origin
        a = np.einsum("fk,rfk->rf", s, p) * inv
        q = np.cross(s, e1)  # (F, 3)
        b = np.einsum("rk,fk->rf", d[:, 0], q) * inv
        z = np.einsum("fk,fk->f", e2, q) * inv
        hit = ok & (a >= 0) & (b >= 0) & (a + b <= 1) & (z > 0)
        z = np.where(hit, z, np.inf)
        nearest = np.argmin(z, axis=1)
        found = np.take_along_axis(z, nearest[:, None], axis=1)[:, 0]
        chunk = slice(start, start + len(d))
        depth[chunk] = np.where(np.isfinite(found), found, 0.0)
        cosine = np.abs(normals[nearest] @ np.array([0.0, 0.0, 1.0]))
        facing[chunk] = np.where(np.isfinite(found), cosine, 0.0)
    shape = (K.height, K.width)
    return depth.reshape(shape).astype(np.float32), facing.reshape(shape)


def target_frame(mesh: trimesh.Trimesh, pose: Pose, size: int = 256, seed: int = 0) -> Sample:
    """A frame of ``mesh`` at ``pose`` with the paper camera's optics at ``size`` x ``size``:
    the surface lit by its facing (gray 120-250) on a black sky, and LIDAR returns on the
    beam grid (phase from ``seed``) exactly on the surface. Completed by the tiny model
    (``tests.support.models.tiny_model``), it gives a cloud to register."""
    K = PAPER_CAMERA.intrinsics().scaled(size, size)
    depth, facing = cast_depth(mesh, pose, K)
    gray = np.where(depth > 0, 120 + 130 * facing, 0).astype(np.uint8)
    sparse = np.zeros_like(depth)
    grid = beam_grid(K, np.random.default_rng(seed))
    sparse[grid] = depth[grid]
    meta = {"returns": int(np.count_nonzero(sparse)), "pose": pose.as_dict()}
    return Sample(gray, sparse, depth, meta)
