"""Pictures a person reads at a glance: coloured depth, dilated LIDAR returns, montages.

Used by the dataset preview, the client's preview and the evaluation gallery. OpenCV only.
"""

from __future__ import annotations

import cv2
import numpy as np


def colorize_depth(
    depth: np.ndarray, near: float | None = None, far: float | None = None
) -> np.ndarray:
    """BGR image of a depth map (metres): turbo colour map over the valid range, black = 0."""
    valid = depth > 0
    out = np.zeros((*depth.shape, 3), np.uint8)
    if not np.any(valid):
        return out
    near = float(depth[valid].min()) if near is None else near
    far = float(depth[valid].max()) if far is None else far
    scaled = np.clip((depth - near) / max(far - near, 1e-6), 0, 1)
    colored = cv2.applyColorMap((255 - scaled * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    out[valid] = colored[valid]
    return out


def colorize_normals(normals: np.ndarray) -> np.ndarray:
    """BGR image of unit normals (H, W, 3, camera frame: x right, y down, z forward) in the
    usual normal-map colours: red = right, green = up, blue = towards the camera, each from
    -1..1 to 0..255; black where the normal is 0 (no point there)."""
    rgb = normals * np.array([0.5, -0.5, -0.5], np.float32) + np.float32(0.5)
    out = np.clip(rgb[..., ::-1] * 255, 0, 255).astype(np.uint8)
    out[~normals.any(axis=-1)] = 0
    return out


def dilated_returns(sparse: np.ndarray, radius: int = 3, near=None, far=None) -> np.ndarray:
    """Sparse LIDAR returns drawn as coloured dots, so a person can see them."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    inverted = np.where(sparse > 0, 1000.0 - sparse, 0).astype(np.float32)  # near wins
    grown = cv2.dilate(inverted, kernel)
    return colorize_depth(np.where(grown > 0, 1000.0 - grown, 0), near, far)


def gray_bgr(gray: np.ndarray) -> np.ndarray:
    """A gray image as 8-bit BGR for a picture: 8 bits as they are; 12 and 16 bits stretched so
    that the 99.9th percentile is white (a 12-bit image in 0-4095 would look black)."""
    if gray.dtype != np.uint8:
        top = max(float(np.percentile(gray, 99.9)), 1.0)
        gray = np.clip(gray.astype(np.float32) * (255 / top), 0, 255).astype(np.uint8)
    return cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)


def labelled(image: np.ndarray, text: str) -> np.ndarray:
    """Copy of a BGR image with a caption in its top-left corner."""
    out = image.copy()
    scale = max(out.shape[1] / 700, 0.4)
    cv2.putText(
        out,
        text,
        (8, int(24 * scale)),
        cv2.FONT_HERSHEY_SIMPLEX,
        scale,
        (255, 255, 255),
        max(1, int(2 * scale)),
        cv2.LINE_AA,
    )
    return out


def montage(rows: list[list[np.ndarray]], tile: int = 320, gap: int = 4) -> np.ndarray:
    """Grid of BGR tiles, each resized to ``tile`` x ``tile``, with thin gaps."""
    lines = []
    for row in rows:
        tiles = [cv2.resize(t, (tile, tile), interpolation=cv2.INTER_AREA) for t in row]
        spaced = []
        for t in tiles:
            spaced += [t, np.full((tile, gap, 3), 40, np.uint8)]
        lines.append(np.hstack(spaced[:-1]))
        lines.append(np.full((gap, lines[-1].shape[1], 3), 40, np.uint8))
    return np.vstack(lines[:-1])


def object_crop(mask: np.ndarray, margin: float = 0.15, min_size: int = 96) -> tuple[slice, slice]:
    """Square window around the foreground (or the whole image when there is none)."""
    ys, xs = np.nonzero(mask)
    h, w = mask.shape
    if len(ys) == 0:
        return slice(0, h), slice(0, w)
    cy, cx = (ys.min() + ys.max()) / 2, (xs.min() + xs.max()) / 2
    half = max(ys.max() - ys.min(), xs.max() - xs.min(), min_size) * (0.5 + margin)
    half = min(half, max(h, w) / 2)
    y0 = int(np.clip(cy - half, 0, max(h - 2 * half, 0)))
    x0 = int(np.clip(cx - half, 0, max(w - 2 * half, 0)))
    return slice(y0, int(y0 + 2 * half)), slice(x0, int(x0 + 2 * half))


def side_view(
    points: np.ndarray, size: int = 320, azimuth_deg: float = 90.0, elevation_deg: float = 20.0
) -> np.ndarray:
    """BGR picture of a camera-frame point cloud (N, 3) metres seen from the side.

    The cloud is turned about its centroid (``azimuth_deg`` about the camera's y axis, then
    ``elevation_deg`` about x), orthographically projected and drawn far-to-near as dots
    coloured by distance from the original camera, so the 3-D shape reads at a glance.
    """
    canvas = np.zeros((size, size, 3), np.uint8)
    if len(points) == 0:
        return canvas
    p = points.astype(np.float64) - points.mean(axis=0)
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    turn = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    tilt = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    q = p @ (tilt @ turn).T
    extent = max(np.ptp(q[:, 0]), np.ptp(q[:, 1]), 1e-6)
    scale = 0.9 * size / extent
    u = np.round(q[:, 0] * scale + size / 2).astype(int)
    v = np.round(q[:, 1] * scale + size / 2).astype(int)
    colours = colorize_depth(points[:, 2:3].T.astype(np.float32))[0]
    order = np.argsort(-q[:, 2])  # far first, near drawn over
    inside = (u >= 0) & (u < size) & (v >= 0) & (v < size)
    order = order[inside[order]]
    canvas[v[order], u[order]] = colours[order]
    return cv2.dilate(canvas, np.ones((2, 2), np.uint8))


def draw_points(
    image: np.ndarray,
    points: np.ndarray,
    intrinsics,
    colour: tuple[int, int, int] | None = None,
    radius: int = 0,
) -> np.ndarray:
    """Copy of BGR ``image`` with camera-frame ``points`` (N, 3, metres; e.g. a target's
    surface samples at a pose) projected by ``intrinsics`` (``sdcnet.camera.Intrinsics``) as
    dots of ``radius`` pixels: one ``colour``, or coloured by distance (turbo), the far ones
    drawn first."""
    front = points[points[:, 2] > 0]
    layer = np.zeros_like(image)
    if len(front):
        u, v = intrinsics.project(front)
        u, v = np.round(u).astype(int), np.round(v).astype(int)
        h, w = image.shape[:2]
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
        order = np.argsort(-front[:, 2])
        order = order[inside[order]]
        if colour is None:
            colours = colorize_depth(front[:, 2:3].T.astype(np.float32))[0]
        else:
            colours = np.tile(np.array(colour, np.uint8), (len(front), 1))
        layer[v[order], u[order]] = colours[order]
    if radius > 0:
        size = 2 * radius + 1
        layer = cv2.dilate(layer, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size)))
    drawn = layer.any(axis=2)
    out = image.copy()
    out[drawn] = layer[drawn]
    return out
