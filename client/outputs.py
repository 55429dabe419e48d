"""What ``sdc-client`` writes for one frame, and the summary it prints.

``depth.npy`` float32 (H, W) metres (0 outside the mask), ``sigma.npy`` float32 (H, W) metres
(the depth's 1-sigma uncertainty, 0 outside the mask), ``mask.png`` 8-bit (255 = spacecraft),
``points.ply`` binary PLY (camera frame, metres; each point's unit normal as the vertex
properties ``nx``, ``ny``, ``nz`` and its sigma as ``sigma``, as the service's PLY answer) and
``preview.png``: the gray image, the coloured depth, its sigma, the points' normals, the mask
and a side view of the point cloud, side by side, zoomed on the spacecraft.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sdcnet.camera import Intrinsics
from sdcnet.caveats import CAVEATS
from sdcnet.client.api import Completion
from sdcnet.pointcloud import point_pixels, write_ply
from sdcnet.visualize import (
    colorize_depth,
    colorize_normals,
    gray_bgr,
    labelled,
    montage,
    object_crop,
    side_view,
)

OUTPUT_FILES = ("depth.npy", "sigma.npy", "mask.png", "points.ply", "preview.png")


def gray_for_display(image: np.ndarray) -> np.ndarray:
    """uint8 (H, W) of a uint8/uint16 gray or colour image (16-bit stretched to its maximum)."""
    if image.ndim == 3:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
        image = cv2.cvtColor(image, code)
    if image.dtype == np.uint8:
        return image
    top = max(float(image.max()), 1.0)
    return (image.astype(np.float32) * (255.0 / top)).astype(np.uint8)


def sigma_caption(result: Completion) -> str:
    """The preview's caption of the sigma panel: its range on the mask, centimetres."""
    sigma = result.sigma[result.mask]
    if not sigma.size:
        return "sigma (empty)"
    return f"sigma {100 * sigma.min():.1f}-{100 * sigma.max():.1f} cm"


def preview(
    gray: np.ndarray,
    result: Completion,
    pixels: tuple[np.ndarray, np.ndarray],
    tile: int = 320,
) -> np.ndarray:
    """BGR montage: gray | coloured depth | coloured sigma | normals | mask | point-cloud side
    view; ``pixels``: those of the points (``pixels_of_points``)."""
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
                labelled(colorize_depth(result.sigma[window]), sigma_caption(result)),
                labelled(colorize_normals(normal_image(result, pixels)[window]), "normals"),
                labelled(gray_bgr(mask), f"mask {int(result.mask.sum())} px"),
                labelled(side_view(result.points, tile), f"side view {len(result.points)} pts"),
            ]
        ],
        tile=tile,
    )


def pixels_of_points(result: Completion) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the pixel each point was made from."""
    height, width = result.depth.shape
    K = Intrinsics(**result.meta["intrinsics"], width=width, height=height)
    return point_pixels(result.points, K)


def normal_image(result: Completion, pixels: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """float32 (H, W, 3): each point's normal at its pixel (``pixels``), 0 where there is no
    point; a cloud of every k-th pixel (``cloud_stride``) fills each k x k block from its
    point, for the eye."""
    image = np.zeros((*result.depth.shape, 3), np.float32)
    image[pixels] = result.normals
    stride = int(result.meta.get("cloud_stride", 1))
    if stride > 1:
        height, width = result.depth.shape
        blocks = image[::stride, ::stride]
        image = cv2.resize(blocks, None, fx=stride, fy=stride, interpolation=cv2.INTER_NEAREST)
        image = image[:height, :width]
    return image


def write_outputs(out: Path, gray: np.ndarray, result: Completion) -> list[Path]:
    """Write the five files of one frame into ``out`` (created); returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = dict(zip(OUTPUT_FILES, (out / name for name in OUTPUT_FILES), strict=True))
    np.save(paths["depth.npy"], result.depth, allow_pickle=False)
    np.save(paths["sigma.npy"], result.sigma, allow_pickle=False)
    cv2.imwrite(str(paths["mask.png"]), (result.mask * 255).astype(np.uint8))
    comments = (
        "sdcnet point cloud: camera frame (x right, y down, z forward), metres",
        "nx, ny, nz: the unit surface normal, facing the camera",
        "sigma: the depth's 1-sigma uncertainty, metres",
        f"model_version {result.model_version}",
    )
    pixels = pixels_of_points(result)
    normals = dict(zip(("nx", "ny", "nz"), result.normals.T, strict=True))
    properties = {**normals, "sigma": result.sigma[pixels]}  # each point's own pixel's
    write_ply(paths["points.ply"], result.points, comments, properties)
    cv2.imwrite(str(paths["preview.png"]), preview(gray_for_display(gray), result, pixels))
    return list(paths.values())


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
    sigma = result.sigma[result.mask]
    uncertainty = f"median {np.median(sigma):.3f} m on the mask" if sigma.size else "no foreground"
    t = result.timings_ms
    server = ", ".join(f"{p} {t.get(f'{p}_ms', 0):.1f}" for p in ("decode", "queue", "inference"))
    server += f", encode {t.get('encode_ms', 0):.1f} ms"
    stride = meta.get("cloud_stride", 1)
    thinned = f"; one per {stride} px in rows and columns" if stride > 1 else ""
    iou = meta.get("mask_iou_estimate")
    estimate = f", IOU {100 * iou:.1f} % as the network expects it" if iou is not None else ""
    strays = meta.get("stray_returns", 0)
    left_out = f" ({strays} left out as strays)" if strays else ""
    lines = [
        f"sdcnet {result.model_version} on {result.provider} at {url}",
        f"  image     {width} x {height}, {meta.get('returns', '?')} LIDAR returns{left_out}",
        f"  mask      {int(result.mask.sum()):,} px ({100 * result.mask.sum() / pixels:.1f} %)"
        f"{estimate}",
        f"  depth     {depth}",
        f"  sigma     {uncertainty}",
        f"  points    {len(result.points):,} ({meta.get('outliers_removed', 0)} outliers, "
        f"{meta.get('uncertain_removed', 0)} above max_sigma removed{thinned})",
        f"  latency   {result.latency_s * 1e3:.1f} ms round trip; server {server}",
        *(f"  caveat    {code}: {CAVEATS.get(code, '')}" for code in meta.get("caveats", [])),
        "  wrote     " + "  ".join(str(p) for p in written),
    ]
    return "\n".join(lines)
