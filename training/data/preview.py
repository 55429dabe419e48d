"""Montage of a few samples: gray, dilated LIDAR returns, coloured GT depth, mask."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sdcnet.dataset_format import SampleStore, evenly_spread
from sdcnet.visualize import (
    colorize_depth,
    dilated_returns,
    gray_bgr,
    labelled,
    montage,
    object_crop,
)


def preview(root: str | Path, out: str | Path, count: int = 4, zoom: bool = True) -> Path:
    """Write a PNG montage of the first ``count`` samples, one row each. Returns its path."""
    store = SampleStore(root)
    if len(store) == 0:
        raise ValueError(f"{root} holds no samples")
    rows = []
    for record in evenly_spread(store.records, count):
        s = store.load(record)
        window = object_crop(s.mask) if zoom else (slice(None), slice(None))
        valid = s.depth[s.mask]
        near, far = (float(valid.min()), float(valid.max())) if valid.size else (None, None)
        caption = f"{record['model_name']} {record['distance_m']:.0f} m"
        rows.append(
            [
                labelled(gray_bgr(s.gray[window]), caption),
                labelled(
                    dilated_returns(s.sparse, 3 * s.gray.shape[1] // 1024 + 1, near, far)[window],
                    f"LIDAR {record['returns']} returns",
                ),
                labelled(colorize_depth(s.depth[window], near, far), "GT depth"),
                labelled(gray_bgr((s.mask[window] * 255).astype(np.uint8)), "mask"),
            ]
        )
    out = Path(out)
    cv2.imwrite(str(out), montage(rows))
    return out
