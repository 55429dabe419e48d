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

from dataclasses import dataclass, field

import cv2
import numpy as np

ALPHA_M = 10.0
NAMES = ("IOU", "IOI", "MAEI", "MATE", "RMSEI", "RMSTE")
MASK_NAMES = ("IOU", "IOI")  # the metrics of the foreground mask alone


def frame_metrics(
    pred_depth: np.ndarray, pred_mask: np.ndarray, gt_depth: np.ndarray, alpha: float = ALPHA_M
) -> dict[str, float]:
    """The six metrics of one image; depths in metres, masks boolean. NaN = undefined."""
    A = gt_depth > 0
    P = pred_mask.astype(bool)
    inter, union = A & P, A | P
    n_inter, n_a, n_p = int(inter.sum()), int(A.sum()), int(P.sum())
    err = np.abs(pred_depth.astype(np.float64) - gt_depth.astype(np.float64))
    out = {
        "IOU": n_inter / union.sum() if union.any() else 1.0,
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

    def mean(self) -> dict[str, float]:
        """Mean over images of each metric, leaving out undefined values (NaN if all are)."""
        means = {}
        for k in NAMES:
            values = np.array([r[k] for r in self.rows], dtype=np.float64)
            defined = values[~np.isnan(values)]
            means[k] = float(defined.mean()) if defined.size else float("nan")
        return means

    def undefined(self) -> dict[str, int]:
        return {k: int(sum(np.isnan(r[k]) for r in self.rows)) for k in NAMES}


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


def mask_error_bands(pred_mask: np.ndarray, gt_depth: np.ndarray) -> dict[str, float]:
    """Where a mask's errors lie, as shares of the image's union |A ∪ Â| (so that the three
    ``miss_*`` terms add up to 1 - IOU), by each pixel's distance in pixels to the nearest
    pixel of the other class in the ground truth: ``edge`` <= 1.5 px (it touches the outline),
    ``near`` <= 3 px, ``far`` beyond. ``fp_edge`` and ``fn_edge`` split the edge share into
    false foreground and missed foreground; ``IOU_off_edge`` is the IOU with the edge pixels left
    out of intersection and union. NaN where the union is empty."""
    A = gt_depth > 0
    P = pred_mask.astype(bool)
    union = int((A | P).sum())
    if union == 0 or A.all():
        return dict.fromkeys(
            ("miss_edge", "miss_near", "miss_far", "fp_edge", "fn_edge", "IOU_off_edge"), np.nan
        )
    inside = cv2.distanceTransform(A.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    outside = cv2.distanceTransform((~A).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    distance = np.where(A, inside, outside)
    wrong = A ^ P
    edge, near = distance <= EDGE_BANDS_PX[0], distance <= EDGE_BANDS_PX[1]
    off_union = int(((A | P) & ~edge).sum())
    return {
        "miss_edge": float((wrong & edge).sum() / union),
        "miss_near": float((wrong & near & ~edge).sum() / union),
        "miss_far": float((wrong & ~near).sum() / union),
        "fp_edge": float((wrong & edge & P).sum() / union),
        "fn_edge": float((wrong & edge & A).sum() / union),
        "IOU_off_edge": float((A & P & ~edge).sum() / off_union) if off_union else np.nan,
    }
