"""Where the LIDAR's field ended and the spacecraft did not: a flash array or a multi-beam
LIDAR often sees a fraction of the camera's field, and the parts of the spacecraft beyond it
have no return.

The returns then stop along a straight line (a side of their bounding box that they follow
closely, or for a long run) with the image bright beyond it (``field_cuts``). The pipeline
uses such a *cut* twice: the crop grows past it (``sdcnet.pipeline.past_field_edges``), and,
beyond it, the image decides what the returns cannot (``grown_past_field``): the network,
which learned that the spacecraft is where its returns are, stops at the field's edge even in
the larger crop, while the part beyond it is in plain sight, brighter than the sky it is seen
against. Inside the field, where the LIDAR would have answered from any surface, nothing
without a return is added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: A side of the returns' bounding box is the LIDAR field's edge when returns lie within one
#: spacing of it along more than this share of its length, or along at least
#: ``FIELD_EDGE_RUN_SPACINGS`` return spacings of it (a straight cut across the spacecraft,
#: which may cross only part of the field: the outline of a spacecraft meets its box in a few
#: points) ...
FIELD_EDGE_COVER = 0.7
FIELD_EDGE_RUN_SPACINGS = 15
#: ... and the image between one return spacing beyond it (where a spacecraft that ends
#: there can still reach, between two rows of returns) and this many, alongside those
#: returns, is brighter, on average, than this share of the median gray at the returns: the
#: spacecraft goes on past the field's edge (a straight panel edge against the black sky
#: does not). Beyond a cut, a pixel this bright is the spacecraft's where it joins the mask.
FIELD_EDGE_BAND_SPACINGS = 3.0
FIELD_EDGE_BRIGHTNESS = 0.25
#: The mask grows past a cut only from this many return spacings beyond the returns' box (the
#: blurred rim of what the field saw is the network's to outline) ...
GROWTH_MARGIN_SPACINGS = 0.5
#: ... and only when, after growing, at most this share of the frame's background is that
#: bright: the sky behind is dark. A bright Earth, Moon or glare beside the spacecraft would
#: be glued to it (docs/development.md, "Measurements").
LOOSE_BRIGHT_SHARE = 0.02


@dataclass(frozen=True)
class FieldCuts:
    """The returns' bounding box (frame pixels: rows ``y0:y1``, columns ``x0:x1``), their
    ``spacing`` (pixels), the gray level (the frame's units) above which the image is
    ``bright`` (``FIELD_EDGE_BRIGHTNESS`` of the median at the returns) and the sides of the
    box along which the LIDAR's field cut the spacecraft."""

    y0: int
    y1: int
    x0: int
    x1: int
    spacing: float
    bright: float
    top: bool
    bottom: bool
    left: bool
    right: bool

    def beyond(
        self, origin: tuple[int, int], scale: tuple[float, float], shape: tuple[int, int]
    ) -> np.ndarray:
        """Bool (h, w): the pixels of a grid of ``shape`` (its pixel (0, 0) at frame pixel
        ``origin`` = (row, column), ``scale`` grid pixels per frame pixel along rows and
        columns) beyond the cut sides by ``GROWTH_MARGIN_SPACINGS``."""
        (oy, ox), (sy, sx) = origin, scale
        margin = GROWTH_MARGIN_SPACINGS * self.spacing
        zone = np.zeros(shape, bool)
        if self.top:
            zone[: max(round((self.y0 - margin - oy) * sy), 0)] = True
        if self.bottom:
            zone[max(round((self.y1 + margin - oy) * sy), 0) :] = True
        if self.left:
            zone[:, : max(round((self.x0 - margin - ox) * sx), 0)] = True
        if self.right:
            zone[:, max(round((self.x1 + margin - ox) * sx), 0) :] = True
        return zone


def _covered(along: np.ndarray, spacing: float, length: int) -> float:
    """Share of a side ``length`` pixels long that returns at positions ``along`` it (pixels)
    cover, each one return ``spacing`` long."""
    return np.unique((along // spacing).astype(np.intp)).size * spacing / length


def bright_level(gray: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> float:
    """The gray level (``gray``'s units) above which the frame ``gray`` is as bright as a part
    of the spacecraft may be: ``FIELD_EDGE_BRIGHTNESS`` of the median at its returns (pixel
    ``rows``, ``cols``; at least one)."""
    return FIELD_EDGE_BRIGHTNESS * float(np.median(gray[rows, cols]))


def field_cuts(
    rows: np.ndarray, cols: np.ndarray, gray: np.ndarray, spacing: float
) -> FieldCuts | None:
    """The sides where the LIDAR's field cut the spacecraft whose returns (pixel ``rows``,
    ``cols``, ``spacing`` pixels apart) lie in the frame ``gray`` (any dtype): returns along
    the side (``FIELD_EDGE_COVER``, ``FIELD_EDGE_RUN_SPACINGS``) and the image bright beyond
    it (``FIELD_EDGE_BRIGHTNESS``); None where there is none."""
    y0, y1, x0, x1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
    h, w = y1 - y0, x1 - x0
    if min(h, w) <= 2 * spacing:
        return None
    threshold = bright_level(gray, rows, cols)
    near, far = round(spacing), max(round(FIELD_EDGE_BAND_SPACINGS * spacing), round(spacing) + 2)

    def cut(along: np.ndarray, length: int, beyond) -> bool:
        """Whether returns at positions ``along`` a side ``length`` pixels long cut the
        spacecraft there; ``beyond(lo, hi)``: the band past the side alongside [lo, hi)."""
        if along.size == 0:
            return False
        covered = _covered(along, spacing, length)
        if covered <= FIELD_EDGE_COVER and covered * length < FIELD_EDGE_RUN_SPACINGS * spacing:
            return False
        band = beyond(int(along.min()), int(along.max()) + 1)
        return band.size > 0 and float(band.mean()) > threshold

    above, below = gray[max(y0 - far, 0) : max(y0 - near, 0)], gray[y1 + near : y1 + far]
    before, after = gray[:, max(x0 - far, 0) : max(x0 - near, 0)], gray[:, x1 + near : x1 + far]
    sides = (
        cut(cols[rows < y0 + spacing], w, lambda lo, hi: above[:, lo:hi]),
        cut(cols[rows >= y1 - spacing], w, lambda lo, hi: below[:, lo:hi]),
        cut(rows[cols < x0 + spacing], h, lambda lo, hi: before[lo:hi]),
        cut(rows[cols >= x1 - spacing], h, lambda lo, hi: after[lo:hi]),
    )
    return FieldCuts(y0, y1, x0, x1, spacing, threshold, *sides) if any(sides) else None


def grown_past_field(
    mask: np.ndarray, gray: np.ndarray, bright: float, beyond: np.ndarray
) -> np.ndarray:
    """``mask`` (bool (h, w)) grown by the pixels ``beyond`` the field's cut sides (bool (h,
    w): ``FieldCuts.beyond``) where ``gray`` (h, w) is above ``bright`` (``FieldCuts.bright``
    in ``gray``'s units), joined to the mask through such pixels (8-connected); ``mask``
    itself where nothing joins it."""
    grown = joined_to(mask, (gray > bright) & beyond)
    return mask if np.count_nonzero(grown) == np.count_nonzero(mask) else grown


def joined_to(mask: np.ndarray, candidates: np.ndarray) -> np.ndarray:
    """``mask`` (bool (h, w)) with the ``candidates`` (bool (h, w)) joined to it through
    candidates (8-connected)."""
    count, labels = cv2.connectedComponents((candidates | mask).view(np.uint8), connectivity=8)
    joined = np.zeros(count, bool)
    joined[labels[mask]] = True
    joined[0] = False
    return joined[labels]


#: ``sky_is_dark`` reads a regular sample of about this many of the frame's pixels: a share of
#: the frame needs no more, whatever its size.
SKY_SAMPLES = 256 * 256


def sky_is_dark(
    gray: np.ndarray, cuts: FieldCuts, grown: np.ndarray, box: tuple[int, int, int, int]
) -> bool:
    """Whether at most ``LOOSE_BRIGHT_SHARE`` of the frame ``gray`` (H, W) is brighter than
    ``cuts.bright`` and not joined to the mask ``grown`` (bool, the frame's rows ``y0:y1``
    and columns ``x0:x1`` of ``box`` at any resolution) past the field's cut sides: the sky
    behind is dark, whatever else of the spacecraft lies bright beyond the crop there. On a
    regular sample of about ``SKY_SAMPLES`` of the frame's pixels."""
    H, W = gray.shape
    step = max(1, math.ceil(math.sqrt(H * W / SKY_SAMPLES)))
    bright = cv2.compare(gray[::step, ::step], cuts.bright, cv2.CMP_GT) > 0
    y0, y1, x0, x1 = (-(-v // step) for v in box)  # the samples within the box
    mask = np.zeros(bright.shape, bool)
    if y1 > y0 and x1 > x0:
        small = cv2.resize(
            grown.view(np.uint8), (x1 - x0, y1 - y0), interpolation=cv2.INTER_NEAREST
        )
        mask[y0:y1, x0:x1] = small.view(bool)
    beyond = cuts.beyond((0, 0), (1 / step, 1 / step), bright.shape)
    background = ~joined_to(mask, bright & beyond)
    loose = np.count_nonzero(bright & background)
    return loose <= LOOSE_BRIGHT_SHARE * np.count_nonzero(background)
