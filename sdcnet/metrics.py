"""Object-level metrics of the paper (sec. III-D, eqs 8-13), numpy only.

A = ground-truth foreground (depth > 0), Â = predicted foreground.
IOU = |A∩Â| / |A∪Â|; IOI = |A∩Â| / |A|; MAEI, RMSEI = MAE, RMSE over A∩Â;
MATE = mean over Â of min(|d̂ - d|, α); RMSTE = sqrt(mean over Â of min((d̂ - d)², α²)).
Pixels of Â off the object have d = 0, so their error is truncated at α (10 m).

Empty sets, per image: A∪Â empty -> IOU = 1; A empty -> IOI undefined; A∩Â empty -> MAEI and
RMSEI undefined; Â empty while A is not -> MATE = RMSTE = α (the object was missed entirely).
Undefined values are left out of the mean over images and counted (``MetricTable.undefined``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from sdcnet.camera import Intrinsics

ALPHA_M = 10.0
NAMES = ("IOU", "IOI", "MAEI", "MATE", "RMSEI", "RMSTE")
MASK_NAMES = ("IOU", "IOI")  # the metrics of the foreground mask alone


def mask_iou(pred_mask: np.ndarray, true_mask: np.ndarray) -> float:
    """Intersection over union of two boolean masks (1 when both are empty)."""
    union = np.count_nonzero(pred_mask | true_mask)
    return np.count_nonzero(pred_mask & true_mask) / union if union else 1.0


def frame_metrics(
    pred_depth: np.ndarray, pred_mask: np.ndarray, gt_depth: np.ndarray, alpha: float = ALPHA_M
) -> dict[str, float]:
    """The six metrics of one image; depths in metres, masks boolean. NaN = undefined."""
    A = gt_depth > 0
    P = pred_mask.astype(bool)
    inter = A & P
    n_inter, n_a, n_p = int(inter.sum()), int(A.sum()), int(P.sum())
    err = np.abs(pred_depth.astype(np.float64) - gt_depth.astype(np.float64))
    out = {
        "IOU": mask_iou(P, A),
        "IOI": n_inter / n_a if n_a else np.nan,
        "MAEI": err[inter].mean() if n_inter else np.nan,
        "RMSEI": np.sqrt(np.mean(err[inter] ** 2)) if n_inter else np.nan,
    }
    if n_p:
        truncated = np.minimum(err[P], alpha)
        out["MATE"] = truncated.mean()
        out["RMSTE"] = np.sqrt(np.mean(truncated**2))
    else:
        out["MATE"] = out["RMSTE"] = alpha if n_a else np.nan
    return {k: float(out[k]) for k in NAMES}


@dataclass
class MetricTable:
    """Accumulates per-image metrics; means over images, with undefined values counted."""

    rows: list[dict[str, float]] = field(default_factory=list)

    def add(self, metrics: dict[str, float]) -> None:
        self.rows.append(metrics)

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def names(self) -> list[str]:
        """The metrics the rows hold, in the order of the first row."""
        return list(self.rows[0]) if self.rows else list(NAMES)

    def mean(self) -> dict[str, float]:
        """Mean over images of each metric, leaving out undefined values (NaN if all are)."""
        means = {}
        for k in self.names:
            values = np.array([r[k] for r in self.rows], dtype=np.float64)
            defined = values[~np.isnan(values)]
            means[k] = float(defined.mean()) if defined.size else float("nan")
        return means

    def undefined(self) -> dict[str, int]:
        return {k: int(sum(np.isnan(r[k]) for r in self.rows)) for k in self.names}


def markdown_table(
    results: dict[str, dict[str, float]], counts: dict[str, int] | None = None
) -> str:
    """Table-3-style markdown: one row per method, IOU/IOI in %, errors in metres; a metric
    a method has no value for (NaN) shows as "n/a"."""

    def cell(value: float, scale: float, digits: int) -> str:
        return "n/a" if np.isnan(value) else f"{scale * value:.{digits}f}"

    lines = [
        "| method | IOU % | IOI % | MAEI m | MATE m | RMSEI m | RMSTE m |"
        + (" images |" if counts else ""),
        "|---|---|---|---|---|---|---|" + ("---|" if counts else ""),
    ]
    for name, m in results.items():
        cells = [cell(m[k], 100, 2) for k in MASK_NAMES]
        cells += [cell(m[k], 1, 3) for k in ("MAEI", "MATE", "RMSEI", "RMSTE")]
        if counts:
            cells.append(str(counts[name]))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


EDGE_BANDS_PX = (1.5, 3.0)  # "touching the outline" (8-connected), "2nd or 3rd pixel from it"


def mask_error_bands(
    pred_mask: np.ndarray, gt_depth: np.ndarray, seen: np.ndarray | None = None
) -> dict[str, float]:
    """Where a mask's errors lie, as shares of the image's union |A ∪ Â| (so that
    ``missed_unseen`` and the three ``miss_*`` terms add up to 1 - IOU). ``missed_unseen``: the
    true foreground outside ``seen`` (the pixels the network was shown; the whole frame if
    None), which no mask could hold. The rest by each pixel's distance in pixels to the nearest
    pixel of the other class in the ground truth: ``edge`` <= 1.5 px (it touches the outline),
    ``near`` <= 3 px, ``far`` beyond. ``fp_edge`` and ``fn_edge`` split the edge share into
    false foreground and missed foreground, ``fp_far`` is the false foreground of the far
    share; ``IOU_off_edge`` is the IOU with the edge pixels left out of intersection and union.
    NaN where the union is empty."""
    A = gt_depth > 0
    P = pred_mask.astype(bool)
    union = int((A | P).sum())
    if union == 0 or A.all():
        return dict.fromkeys(
            (
                "missed_unseen",
                "miss_edge",
                "miss_near",
                "miss_far",
                "fp_edge",
                "fn_edge",
                "fp_far",
                "IOU_off_edge",
            ),
            np.nan,
        )
    inside = cv2.distanceTransform(A.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform((~A).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    distance = np.where(A, inside, outside)
    unseen = A & ~seen if seen is not None else np.zeros_like(A)
    wrong = (A ^ P) & ~unseen
    edge, near = distance <= EDGE_BANDS_PX[0], distance <= EDGE_BANDS_PX[1]
    off_union = int(((A | P) & ~edge).sum())
    return {
        "missed_unseen": float(unseen.sum() / union),
        "miss_edge": float((wrong & edge).sum() / union),
        "miss_near": float((wrong & near & ~edge).sum() / union),
        "miss_far": float((wrong & ~near).sum() / union),
        "fp_edge": float((wrong & edge & P).sum() / union),
        "fn_edge": float((wrong & edge & A).sum() / union),
        "fp_far": float((wrong & ~near & P).sum() / union),
        "IOU_off_edge": float((A & P & ~edge).sum() / off_union) if off_union else np.nan,
    }


# --- Depth where it is used: beside the classical fill, near and far from the returns ----------

#: Bands of distance to the nearest LIDAR return, pixels: (0, 3], (3, 6], (6, 10], (10, inf).
DISTANCE_BANDS_PX = (3.0, 6.0, 10.0)
BAND_NAMES = ("0-3px", "3-6px", "6-10px", ">10px")
NORMAL_NAMES = ("normal_mean_deg", "normal_median_deg", "normal_within_11.25")
#: A normal counts as right within this angle (degrees), the usual threshold of normal benchmarks.
NORMAL_GOOD_DEG = 11.25
#: Pixels this close to the outline of the foreground, or to a depth edge, have no reliable normal.
NORMAL_MARGIN_PX = 3
#: A depth edge: Z changes faster than this many pixel footprints (Z / f) per pixel, i.e. a surface
#: steeper than ~84 degrees to the line of sight, or a jump between two surfaces.
DEPTH_EDGE_SLOPE = 10.0


def distance_to_returns(sparse: np.ndarray) -> np.ndarray:
    """Euclidean distance in pixels from each pixel to the nearest LIDAR return (float32 H x W);
    +inf everywhere when there is none."""
    if not (sparse > 0).any():
        return np.full(sparse.shape, np.inf, np.float32)
    return cv2.distanceTransform((sparse <= 0).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def band_index(distance: np.ndarray) -> np.ndarray:
    """Index into ``BAND_NAMES`` of each distance (pixels)."""
    return np.searchsorted(np.asarray(DISTANCE_BANDS_PX), distance, side="left")


def same_pixel_errors(
    pred_depth: np.ndarray,
    pred_mask: np.ndarray,
    fill_depth: np.ndarray,
    fill_mask: np.ndarray,
    gt_depth: np.ndarray,
    sparse: np.ndarray,
) -> dict[str, float]:
    """Depth MAE (metres) of a prediction and of the classical fill on the same pixels: the
    predicted ∩ filled ∩ true foreground, overall (``MAE``, ``fill_MAE``) and per band of distance
    to the nearest LIDAR return (``MAE_0-3px``, ``fill_MAE_0-3px``, ...). NaN where a set is empty.

    The paper's MAEI averages over the predicted foreground, where a fill has no answer far from
    the returns; comparing on the pixels both answer shows whether the network beats the fill at
    what the fill does, and the bands show whether it keeps what was measured (near a return) and
    interpolates well between returns (far from them).
    """
    common = pred_mask.astype(bool) & fill_mask.astype(bool) & (gt_depth > 0)
    gt = gt_depth.astype(np.float64)
    err = np.abs(pred_depth - gt)
    fill_err = np.abs(fill_depth - gt)
    band = band_index(distance_to_returns(sparse))

    def mean(values: np.ndarray, where: np.ndarray) -> float:
        return float(values[where].mean()) if where.any() else float("nan")

    out = {"MAE": mean(err, common), "fill_MAE": mean(fill_err, common)}
    for i, name in enumerate(BAND_NAMES):
        out[f"MAE_{name}"] = mean(err, common & (band == i))
        out[f"fill_MAE_{name}"] = mean(fill_err, common & (band == i))
    return out


def surface_normals(depth: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Unit normals (H x W x 3, camera frame) of the surface a depth map (metres) describes:
    the cross product of the back-projected points' central differences along rows and columns,
    oriented towards the camera. Only meaningful where the 3 x 3 neighbourhood is on one surface.
    """
    H, W = depth.shape
    z = depth.astype(np.float64)
    u = np.arange(W, dtype=np.float64)[None, :]
    v = np.arange(H, dtype=np.float64)[:, None]
    points = np.stack(
        [(u - intrinsics.cx) * z / intrinsics.fx, (v - intrinsics.cy) * z / intrinsics.fy, z], -1
    )
    du = np.zeros_like(points)
    dv = np.zeros_like(points)
    du[:, 1:-1] = points[:, 2:] - points[:, :-2]
    dv[1:-1] = points[2:] - points[:-2]
    normal = np.cross(du, dv)
    normal *= -np.sign(np.sum(normal * points, -1, keepdims=True) + 1e-300)  # face the camera
    norm = np.linalg.norm(normal, axis=-1, keepdims=True)
    return normal / np.maximum(norm, 1e-300)


def depth_edges(depth: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Boolean H x W: pixels where the depth (metres) changes by more than ``DEPTH_EDGE_SLOPE``
    pixel footprints per pixel towards a neighbour, or that border the background."""
    z = depth.astype(np.float64)
    footprint = np.maximum(z, 1e-6) / intrinsics.fx
    edge = np.zeros(z.shape, bool)
    for axis in (0, 1):
        step = np.abs(np.diff(z, axis=axis))
        jump = step > DEPTH_EDGE_SLOPE * np.minimum(
            footprint.take(range(z.shape[axis] - 1), axis),
            footprint.take(range(1, z.shape[axis]), axis),
        )
        if axis == 0:
            edge[:-1] |= jump
            edge[1:] |= jump
        else:
            edge[:, :-1] |= jump
            edge[:, 1:] |= jump
    return edge | (z <= 0)


def normal_errors(
    pred_depth: np.ndarray,
    pred_mask: np.ndarray,
    gt_depth: np.ndarray,
    intrinsics: Intrinsics,
    pred_normals: np.ndarray | None = None,
) -> dict[str, float]:
    """Angle (degrees) between the predicted normals (``pred_normals``, (H, W, 3) unit
    vectors; without them, those of the predicted depth map) and those of the true depth map on
    the interior of predicted ∩ true foreground, ``NORMAL_MARGIN_PX`` away from the outline and
    from the true depth edges: ``normal_mean_deg``, ``normal_median_deg`` and
    ``normal_within_11.25`` (share of pixels within 11.25 degrees), NaN when no pixel qualifies.

    A point cloud must be flat where the spacecraft is flat: a ripple between scan lines that
    MAE barely sees tilts the normals by degrees.
    """
    region = pred_mask.astype(bool) & (gt_depth > 0) & (pred_depth > 0)
    unsure = depth_edges(gt_depth, intrinsics) | ~region
    unsure[[0, -1]] = unsure[:, [0, -1]] = True  # the image's border has no central difference
    size = 2 * NORMAL_MARGIN_PX + 1
    interior = ~cv2.dilate(unsure.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)
    if not interior.any():
        return dict.fromkeys(NORMAL_NAMES, float("nan"))
    if pred_normals is None:
        pred_normals = surface_normals(pred_depth, intrinsics)
    dot = np.sum(pred_normals[interior] * surface_normals(gt_depth, intrinsics)[interior], -1)
    angle = np.degrees(np.arccos(np.clip(dot, -1.0, 1.0)))
    values = (angle.mean(), np.median(angle), (angle <= NORMAL_GOOD_DEG).mean())
    return {name: float(v) for name, v in zip(NORMAL_NAMES, values, strict=True)}


def false_specks(pred_mask: np.ndarray, sparse: np.ndarray, gt_depth: np.ndarray) -> int:
    """Predicted foreground components (8-connected) that hold no LIDAR return and not one pixel
    of the spacecraft: stars and noise taken for the target, each one a point of the cloud off
    it. Parts of the spacecraft that look detached and have no return are not specks, however
    wide the mask draws them around a thin boom (that is an outline error, which IOU counts)."""
    count, labels = cv2.connectedComponents(pred_mask.astype(np.uint8), connectivity=8)
    if count <= 1:
        return 0
    on_target = np.bincount(labels.ravel(), weights=(gt_depth > 0).ravel(), minlength=count)
    with_return = np.bincount(labels.ravel(), weights=(sparse > 0).ravel(), minlength=count) > 0
    speck = (~with_return) & (on_target == 0)
    return int(speck[1:].sum())


#: The uncertainty's metrics (``uncertainty_metrics``).
SIGMA_NAMES = ("sigma_within_1", "sigma_within_2", "sigma_mae_cut_10")
#: Share of the most uncertain pixels left out for ``sigma_mae_cut_10``.
UNCERTAIN_SHARE = 0.1


def uncertainty_metrics(
    pred_depth: np.ndarray, pred_mask: np.ndarray, gt_depth: np.ndarray, sigma: np.ndarray | None
) -> dict[str, float]:
    """Whether the depth's sigma (metres) is honest, on predicted ∩ true foreground: the share
    of pixels with |error| <= sigma (``sigma_within_1``, 68 % if calibrated) and <= 2 sigma
    (``sigma_within_2``), and how much leaving out the ``UNCERTAIN_SHARE`` most uncertain
    pixels cuts the MAE of the rest (``sigma_mae_cut_10``, a fraction: 0.3 = 30 % lower).
    NaN without sigma or pixels."""
    region = pred_mask.astype(bool) & (gt_depth > 0)
    if sigma is None or not region.any():
        return dict.fromkeys(SIGMA_NAMES, float("nan"))
    err = np.abs(pred_depth[region].astype(np.float64) - gt_depth[region])
    s = sigma[region].astype(np.float64)
    keep = s <= np.quantile(s, 1 - UNCERTAIN_SHARE)
    mae = err.mean()
    return {
        "sigma_within_1": float(np.mean(err <= s)),
        "sigma_within_2": float(np.mean(err <= 2 * s)),
        "sigma_mae_cut_10": float(1 - err[keep].mean() / mae) if mae > 0 else float("nan"),
    }


def frame_report(
    pred_depth: np.ndarray,
    pred_mask: np.ndarray,
    fill_depth: np.ndarray,
    fill_mask: np.ndarray,
    gt_depth: np.ndarray,
    sparse: np.ndarray,
    intrinsics: Intrinsics,
    sigma: np.ndarray | None = None,
    normals: np.ndarray | None = None,
) -> dict[str, float]:
    """Every metric of one image: the paper's six, depth on the classical fill's pixels by
    distance to the returns, normals (``normals``, (H, W, 3), when the method answers some;
    else its depth map's), false specks and the uncertainty's honesty (NaN without ``sigma``).
    Depths in metres, masks boolean."""
    report = frame_metrics(pred_depth, pred_mask, gt_depth)
    report |= same_pixel_errors(pred_depth, pred_mask, fill_depth, fill_mask, gt_depth, sparse)
    # Normals only where the spacecraft is: a crop around everything that is foreground
    rows, cols = np.nonzero((gt_depth > 0) | pred_mask)
    if len(rows):
        y0, x0 = max(rows.min() - 1, 0), max(cols.min() - 1, 0)
        window = (slice(y0, rows.max() + 2), slice(x0, cols.max() + 2))
        shifted = replace(intrinsics, cx=intrinsics.cx - x0, cy=intrinsics.cy - y0)
        given = None if normals is None else normals[window]
        report |= normal_errors(
            pred_depth[window], pred_mask[window], gt_depth[window], shifted, given
        )
    else:
        report |= dict.fromkeys(NORMAL_NAMES, float("nan"))
    report["specks"] = float(false_specks(pred_mask, sparse, gt_depth))
    report |= uncertainty_metrics(pred_depth, pred_mask, gt_depth, sigma)
    return report


def depth_table(results: dict[str, dict[str, float]]) -> str:
    """Markdown: each method's depth MAE on the pixels it shares with the classical fill, the
    fill's own in brackets, overall and by distance to the nearest return (metres); normal
    errors (degrees) and false specks per image."""

    def pair(m: dict[str, float], key: str) -> str:
        own, fill = m.get(key, np.nan), m.get(f"fill_{key}", np.nan)
        return "n/a" if np.isnan(own) else f"{own:.3f} ({fill:.3f})"

    def num(value: float, fmt: str) -> str:
        return "n/a" if np.isnan(value) else format(value, fmt)

    bands = " | ".join(f"{b} m" for b in BAND_NAMES)
    lines = [
        f"| method | MAE m (fill) | {bands} | normal mean ° | median ° | within 11.25° % "
        "| specks / image |",
        "|---|---|" + "---|" * len(BAND_NAMES) + "---|---|---|---|",
    ]
    for name, m in results.items():
        if "MAE" not in m:
            continue
        cells = [pair(m, "MAE"), *(pair(m, f"MAE_{b}") for b in BAND_NAMES)]
        cells += [
            num(m["normal_mean_deg"], ".1f"),
            num(m["normal_median_deg"], ".1f"),
            num(100 * m["normal_within_11.25"], ".0f"),
            num(m["specks"], ".2f"),
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def uncertainty_table(results: dict[str, dict[str, float]]) -> str:
    """Markdown: per method with an uncertainty, the share of true-positive pixels within one
    and two sigma of the truth (68 % and 95 % if sigma is calibrated) and the cut in MAE when
    the 10 % most uncertain pixels are left out."""
    lines = [
        "| method | within sigma % | within 2 sigma % | MAE cut, 10 % most uncertain out |",
        "|---|---|---|---|",
    ]
    for name, m in results.items():
        if np.isnan(m.get("sigma_within_1", np.nan)):
            continue
        lines.append(
            f"| {name} | {100 * m['sigma_within_1']:.1f} | {100 * m['sigma_within_2']:.1f} | "
            f"{100 * m['sigma_mae_cut_10']:.0f} % |"
        )
    return "\n".join(lines)
