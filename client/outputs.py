"""What ``sdc-client`` writes for one frame, and the summary it prints.

``depth.npy`` float32 (H, W) metres (0 outside the mask), ``mask.png`` 8-bit (255 =
spacecraft), ``points.ply`` binary PLY (camera frame, metres) and ``preview.png``: the gray
image, the coloured depth, the mask and a side view of the point cloud, side by side, zoomed
on the spacecraft.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sdcnet.client.api import Completion
from sdcnet.pointcloud import write_ply
from sdcnet.visualize import colorize_depth, gray_bgr, labelled, montage, object_crop, side_view

OUTPUT_FILES = ("depth.npy", "mask.png", "points.ply", "preview.png")


def gray_for_display(image: np.ndarray) -> np.ndarray:
    """uint8 (H, W) of a uint8/uint16 gray or colour image (16-bit stretched to its maximum)."""
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype == np.uint8:
        return image
    top = max(float(image.max()), 1.0)
    return (image.astype(np.float32) * (255.0 / top)).astype(np.uint8)


def preview(gray: np.ndarray, result: Completion, tile: int = 320) -> np.ndarray:
    """BGR montage: gray | coloured depth | mask | point-cloud side view."""
    window = object_crop(result.mask)
    valid = result.depth[result.mask & (result.depth > 0)]
    depth_caption = (
        f"depth {valid.min():.1f}-{valid.max():.1f} m" if valid.size else "depth (empty)"
    )
    mask = (result.mask[window] * 255).astype(np.uint8)
    return montage(
        [
            [
                labelled(gray_bgr(gray[window]), "gray"),
                labelled(colorize_depth(result.depth[window]), depth_caption),
                labelled(gray_bgr(mask), f"mask {int(result.mask.sum())} px"),
                labelled(side_view(result.points, tile), f"side view {len(result.points)} pts"),
            ]
        ],
        tile=tile,
    )


def write_outputs(out: Path, gray: np.ndarray, result: Completion) -> list[Path]:
    """Write the four files of one frame into ``out`` (created); returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in OUTPUT_FILES]
    np.save(paths[0], result.depth, allow_pickle=False)
    cv2.imwrite(str(paths[1]), (result.mask * 255).astype(np.uint8))
    comments = [
        "sdcnet point cloud: camera frame (x right, y down, z forward), metres",
        f"model_version {result.model_version}",
    ]
    write_ply(paths[2], result.points, tuple(comments))
    cv2.imwrite(str(paths[3]), preview(gray_for_display(gray), result))
    return paths


def summary(result: Completion, url: str, written: list[Path]) -> str:
    """A one-screen report of one frame."""
    meta = result.meta
    height, width = result.depth.shape
    pixels = max(width * height, 1)
    valid = result.depth[result.mask & (result.depth > 0)]
    depth = (
        f"{valid.min():.2f} .. {valid.max():.2f} m (median {np.median(valid):.2f} m)"
        if valid.size
        else "no foreground"
    )
    t = result.timings_ms
    server = ", ".join(f"{p} {t.get(f'{p}_ms', 0):.1f}" for p in ("decode", "queue", "inference"))
    server += f", encode {t.get('encode_ms', 0):.1f} ms"
    lines = [
        f"sdcnet {result.model_version} on {result.provider} at {url}",
        f"  image     {width} x {height}, {meta.get('returns', '?')} LIDAR returns",
        f"  mask      {int(result.mask.sum()):,} px ({100 * result.mask.sum() / pixels:.1f} %)",
        f"  depth     {depth}",
        f"  points    {len(result.points):,} ({meta.get('outliers_removed', 0)} outliers removed)",
        f"  latency   {result.latency_s * 1e3:.1f} ms round trip; server {server}",
        "  wrote     " + "  ".join(str(p) for p in written),
    ]
    return "\n".join(lines)
