"""What a completed frame's mask may not capture, said with the answer.

Sigma says how far each pixel's depth can be trusted; a frame can also be one whose mask as a
whole is less sure, and the answer says so: by the IOU its mask can expect from the network's
own foreground probability (``mask_iou_estimate``), and by code (``POST /complete``'s
``caveats``). Each code marks frames the robustness suite's masks scored markedly lower on
(docs/service.md, "Caveats"): fewer than ``FEW_RETURNS`` returns, where the image alone must
say how far the spacecraft reaches; a LIDAR field that ended across the spacecraft, where what
lies beyond its edge comes from the image alone (most of the masks' misses on the other
LIDARs); a mask that reaches the side of the region the network was shown, where the
spacecraft goes on beyond the LIDAR's returns and out of the network's sight; and a mask whose
estimate is below ``UNCERTAIN_MASK_IOU``, whatever the reason.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:  # the client prints the codes' meanings without the pipeline's imports
    from sdcnet.pipeline import Completion, Region

#: A frame with fewer LIDAR returns than this gets the caveat ``few_returns``.
FEW_RETURNS = 20
#: The network is surer of its outline than it is right (and a part of the spacecraft beyond
#: the crop counts as sky): ``expected_iou`` raised to this power is the estimate an answer
#: carries, the least-squares fit to the IOU measured on the 114 validation frames of the
#: ``any`` world (docs/service.md, "Caveats": how it compares on frames never fitted on).
MASK_IOU_EXPONENT = 1.9
#: A frame whose ``mask_iou_estimate`` is below this gets the caveat ``mask_uncertain``.
UNCERTAIN_MASK_IOU = 0.7
#: A mask with a pixel within this many frame pixels of a side of the network's crop that lies
#: inside the frame gets the caveat ``crop_cut`` ...
CROP_EDGE_PX = 2
#: ... and its estimate times this: what lies beyond the crop the network never saw, and the
#: estimate counted it as sky. The least-squares fit to the IOU measured on the 10 frames of
#: the 114 above that carry the caveat (their estimate 0.75, their IOU 0.62).
CROP_CUT_IOU_FACTOR = 0.84

#: Each caveat's code and what it means for the answer.
CAVEATS = {
    "few_returns": f"fewer than {FEW_RETURNS} LIDAR returns: how far the spacecraft reaches "
    "rests on the image alone; parts may be missing or background taken for it",
    "lidar_field_cut": "the LIDAR's field ended across the spacecraft: the mask past its edge "
    "comes from the image alone, and parts there may be missing",
    "crop_cut": "the mask reaches the side of the region around the LIDAR's returns that the "
    "network was shown, inside the image: the spacecraft goes on beyond it, where parts are "
    "missing from the mask",
    "mask_uncertain": f"the mask's IOU as the network's own foreground probability expects it "
    f"(mask_iou_estimate) is below {UNCERTAIN_MASK_IOU:.2f}: much of its outline is in doubt",
}


def expected_iou(probability: np.ndarray, mask: np.ndarray) -> float:
    """The IOU the mask (bool (h, w)) can expect were each pixel the spacecraft's with the
    network's ``probability`` (float (h, w), the same grid): the expected size of the
    intersection over that of the union, sum(p on the mask) / (mask pixels + sum(p off it)),
    in [0, 1]; 0 for an empty mask. Pixels outside the grid count as background. A mask
    whose outline the network drew with confidence scores near 1; wide bands of doubtful
    probability around it, or doubtful parts left out, lower it. A model whose probability
    leaves [0, 1] has it clipped, a NaN taken as 0 (as by the mask, which leaves it out)."""
    p = cv2.min(cv2.max(probability.astype(np.float32, copy=False), 0.0), 1.0)
    value = _intersection_over_union(p, mask.view(np.uint8))
    if math.isnan(value):  # OpenCV's vector code takes NaN as 0 in max(); its scalar code not
        value = _intersection_over_union(np.nan_to_num(p, nan=0.0), mask.view(np.uint8))
    return value


def _intersection_over_union(p: np.ndarray, mask: np.ndarray) -> float:
    """``expected_iou``'s ratio of a float32 probability in [0, 1] and a uint8 mask, by
    OpenCV's reductions (a third of numpy's boolean indexing's time)."""
    count = cv2.countNonZero(mask)
    inside = cv2.mean(p, mask=mask)[0] * count
    union = count + cv2.sumElems(p)[0] - inside
    return inside / union if union > 0 else 0.0


def mask_iou_estimate(probability: np.ndarray, mask: np.ndarray, crop_cut: bool = False) -> float:
    """What an answer says its mask's IOU is likely to be: ``expected_iou`` of the mask (bool
    (h, w)) under the network's ``probability`` (float (h, w)), raised to
    ``MASK_IOU_EXPONENT``, times ``CROP_CUT_IOU_FACTOR`` where the mask reached its crop's
    side (``crop_cut``: ``reaches_crop_side``), in [0, 1]."""
    estimate = expected_iou(probability, mask) ** MASK_IOU_EXPONENT
    return estimate * CROP_CUT_IOU_FACTOR if crop_cut else estimate


def crop_sides_reached(
    window: np.ndarray, region: Region, frame_shape: tuple[int, int]
) -> tuple[bool, bool, bool, bool]:
    """Which sides of the network's crop ``region`` (top, bottom, left, right) the mask
    ``window`` (bool, the frame's mask on that crop) has a pixel within ``CROP_EDGE_PX`` of,
    among those that are not the border of the frame (``frame_shape``). The crop is the
    returns' box with a margin (grown past a LIDAR field's cut): a mask that fills it to a side
    is a spacecraft that goes on where no return reached and the network did not look, so the
    mask holds nothing of it there."""
    rows, cols = frame_shape
    edge = CROP_EDGE_PX
    return (
        region.y0 > 0 and bool(window[:edge].any()),
        region.y1 < rows and bool(window[-edge:].any()),
        region.x0 > 0 and bool(window[:, :edge].any()),
        region.x1 < cols and bool(window[:, -edge:].any()),
    )


def reaches_crop_side(window: np.ndarray, region: Region, frame_shape: tuple[int, int]) -> bool:
    """Whether the mask ``window`` reaches a side of its crop ``region`` inside the frame
    (``crop_sides_reached``)."""
    return any(crop_sides_reached(window, region, frame_shape))


def frame_caveats(completion: Completion, returns: int) -> list[str]:
    """The codes of ``CAVEATS`` that hold for a completed frame with ``returns`` LIDAR
    returns, in ``CAVEATS``' order; empty when none does."""
    holds = {
        "few_returns": returns < FEW_RETURNS,
        "lidar_field_cut": completion.cuts is not None,
        "crop_cut": completion.crop_cut,
        "mask_uncertain": completion.mask_iou_estimate < UNCERTAIN_MASK_IOU,
    }
    return [code for code in CAVEATS if holds[code]]


def as_text(codes: list[str]) -> str:
    """``codes`` as one text, where only a scalar travels (the Open Inference Protocol's
    parameters, a PLY header's comment): joined by commas, empty for none."""
    return ",".join(codes)


def from_text(text: str) -> list[str]:
    """The codes of an ``as_text``."""
    return [code for code in text.split(",") if code]
