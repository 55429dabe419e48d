"""From a camera frame and its LIDAR map to dense depth, the same way everywhere, at a fixed cost.

The service, the evaluation, the training tiles and the benchmarks all go through this module:

1. **crop**: the spacecraft's region, bounded by its LIDAR returns with a margin that follows
   their spacing (``region_of_interest``); the LIDAR never reaches the Earth or the stars.
   Where the returns end along a straight line with the image going on beyond it, the LIDAR's
   field (narrower than the camera's) ended there, not the spacecraft: the crop grows past it
   (``sdcnet.field_edges``);
2. **resample** the crop to the working grid: about ``work_pixels`` pixels whatever the
   camera, the range and the size of the spacecraft in the frame (``working_grid``): a large
   crop is shrunk, a small one enlarged up to ``MAX_UPSAMPLE`` times, so every frame costs the
   network about the same and the network always sees the spacecraft a few hundred pixels
   across; fewer (down to half) where the frame's own work at its resolution, which grows
   with its crop and its points, would take the whole frame past its budget
   (``frame_work_pixels``; on a slow CPU a share of that budget: ``sdcnet.frame_budget``);
3. **infer**: the model, told the focal length in working pixels so that it can put its depths
   in units of the pixel footprint;
4. **anchor** the depth to the returns it should agree with (``sdcnet.anchoring``), and
   smooth the surface between them, edge-aware, for its normals (``sdcnet.surface``);
5. **paste back** at the frame's resolution: stars and noise dropped (``drop_specks``), the
   mask grown past the LIDAR field's edge into what the image shows beyond it
   (``grown_past_field``), the probability resampled (onto a shrunk crop guided by the
   frame's own gray image:
   ``guided_probability``) and thresholded, the returns a pixel off the mask joined to it
   (``join_returns_beside``), the depth resampled without blending across
   depth edges (``resample_depth``; along them, on a shrunk crop, each frame pixel takes one
   side's depth by its own gray and the returns nearby: ``sdcnet.edge_paste``), within the
   box holding the mask alone (``mask_box``). Outside the crop the answer is background;
6. **look again** where the mask reached a side of the crop inside the frame (the spacecraft
   goes on where no return reached) and the frame's budget has room left after the first
   look (``second_look_pixels``): the crop grown past those sides, on a coarser grid, answers
   beyond the first crop (``with_second_look``).

The model is any callable ``(gray, sparse, focal_px) -> (depth, probability[, sigma])`` on
(B, 1, h, w) float32 arrays and a (B, 1, 1, 1) focal length: onnxruntime in the service,
PyTorch in evaluation; sigma, the depth's uncertainty in metres, where the model has it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from sdcnet.anchoring import Anchored, anchor_to_returns, anchored_sigma, spreading_sigma_px
from sdcnet.caveats import crop_sides_reached, mask_iou_estimate, reaches_crop_side
from sdcnet.edge_paste import paste_across_edges
from sdcnet.field_edges import FieldCuts, field_cuts, grown_past_field, sky_is_dark
from sdcnet.lit_extent import lit_box
from sdcnet.returns import return_pixels, return_spacing, scatter_nearest
from sdcnet.stray_returns import without_strays
from sdcnet.surface import smoothed_between_returns

ModelFn = Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, ...]]

#: Pixels the network sees per frame, padding included: set by the 100 ms budget of one frame
#: on two cores (docs/benchmarks.md), and carried by each model file (``work_pixels``).
WORK_PIXELS = 512 * 512
#: A frame's work at its own resolution, each in the time one working pixel takes (the whole
#: working grid's work: the network, anchoring, the normals' fits), fitted over the robustness
#: suite's frames on two cores (docs/development.md, "Measurements"): a pixel of the crop
#: (resampling it, the guided paste-back, the components that vouch for its mask) ...
CROP_PIXEL_COST = 0.025
#: ... and a pixel of the returns' convex hull, about 0.6 of which the answer's points fill
#: (each point's depth, sigma, back-projection and normal).
HULL_PIXEL_COST = 0.08
#: The whole frame's budget, in working pixels' time, as a multiple of the model's
#: ``work_pixels`` (about 80 ms on two cores by the fit above): a frame whose crop and hull
#: cost more than the rest of it gets fewer working pixels (``frame_work_pixels``), so that
#: frames of large crops and many points cost near what the others do ...
FRAME_BUDGET = 1.4
#: ... but never fewer than this share of ``work_pixels`` (the least the shipped network was
#: trained at: ``training.dataset.BUDGET_JITTER``).
MIN_WORK_SHARE = 0.5
#: The most a 12-bit camera's pixel reads (``in_top_bits``).
TWELVE_BIT_MAX = 4095
#: Most a small crop is enlarged: more would spend the budget on interpolated pixels.
MAX_UPSAMPLE = 4.0
#: Margin around the LIDAR returns' bounding box: this many return spacings (a part of the
#: spacecraft can stick out beyond the outermost row of returns by up to one spacing) ...
MARGIN_SPACINGS = 3.0
#: ... plus this fraction of the box itself.
MARGIN_OF_BOX = 0.15


@dataclass(frozen=True)
class Region:
    """Rows y0:y1 and columns x0:x1 of a frame, in pixels."""

    y0: int
    y1: int
    x0: int
    x1: int

    @property
    def slices(self) -> tuple[slice, slice]:
        return slice(self.y0, self.y1), slice(self.x0, self.x1)

    @property
    def shape(self) -> tuple[int, int]:
        return self.y1 - self.y0, self.x1 - self.x0

    def within(self, outer: Region) -> Region:
        """This region, given from ``outer``'s top-left pixel, in the pixels ``outer`` is in."""
        dy, dx = outer.y0, outer.x0
        return Region(self.y0 + dy, self.y1 + dy, self.x0 + dx, self.x1 + dx)

    def relative_to(self, outer: Region) -> Region:
        """This region, in the pixels ``outer`` is in, given from ``outer``'s top-left pixel
        (the inverse of ``within``)."""
        dy, dx = outer.y0, outer.x0
        return Region(self.y0 - dy, self.y1 - dy, self.x0 - dx, self.x1 - dx)

    def holds(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """bool: whether each pixel (``rows``, ``cols``) lies inside this region."""
        return (rows >= self.y0) & (rows < self.y1) & (cols >= self.x0) & (cols < self.x1)


@dataclass(frozen=True)
class WorkingGrid:
    """The crop of a frame (``region``, frame pixels) and the grid the network sees it on
    (``shape``, working pixels): ``scale`` working pixels per frame pixel along (rows,
    columns)."""

    region: Region
    shape: tuple[int, int]

    @property
    def scale(self) -> tuple[float, float]:
        (h, w), (hw, ww) = self.region.shape, self.shape
        return hw / h, ww / w

    @property
    def identity(self) -> bool:
        """Whether the network sees the crop's own pixels."""
        return self.shape == self.region.shape


#: Margin around returns without a spacing (fewer than ``sdcnet.returns.MIN_RETURNS_FOR_SPACING``
#: or on one line): this fraction of the frame's longer side, since they cannot tell how large
#: the spacecraft is.
FEW_RETURNS_MARGIN = 0.15


def region_of_interest(gray: np.ndarray, sparse: np.ndarray) -> Region:
    """Region holding the spacecraft of a frame (gray (H, W) of any dtype, sparse (H, W)
    metres): ``spacecraft_region`` of its LIDAR returns."""
    rows, cols = return_pixels(sparse)
    return spacecraft_region(rows, cols, gray, return_spacing(rows, cols))[0]


def spacecraft_region(
    rows: np.ndarray, cols: np.ndarray, gray: np.ndarray, spacing: float | None
) -> tuple[Region, FieldCuts | None]:
    """Region holding the spacecraft whose returns lie at pixel ``rows``, ``cols`` of the frame
    ``gray``, ``spacing`` pixels apart (``return_spacing``): ``region_around`` them, grown
    ``past_field_edges`` where the LIDAR's field cut the spacecraft and to the bright region
    joined to them under a dark sky (``sdcnet.lit_extent``); and those cuts (None where there
    is none)."""
    region = region_around(rows, cols, gray.shape, spacing)
    cuts = None if spacing is None else field_cuts(rows, cols, gray, spacing)
    if cuts is not None:
        region = past_field_edges(region, cuts, gray.shape)
    lit = lit_box(rows, cols, gray, (region.y0, region.y1, region.x0, region.x1))
    if lit is not None:
        y0, y1, x0, x1 = lit
        region = Region(
            min(region.y0, y0), max(region.y1, y1), min(region.x0, x0), max(region.x1, x1)
        )
    return region, cuts


def region_around(
    rows: np.ndarray, cols: np.ndarray, frame_shape: tuple[int, int], spacing: float | None
) -> Region:
    """The returns' (pixel ``rows``, ``cols``, ``spacing`` pixels apart: ``return_spacing``)
    bounding box grown by ``MARGIN_SPACINGS`` return spacings and ``MARGIN_OF_BOX`` of the box,
    inside the frame; the whole frame if there is no return."""
    H, W = frame_shape
    if len(rows) == 0:
        return Region(0, H, 0, W)
    box = max(np.ptp(rows), np.ptp(cols)) + 1
    if spacing is None:
        margin = FEW_RETURNS_MARGIN * max(H, W)
    else:
        margin = MARGIN_SPACINGS * min(spacing, box) + MARGIN_OF_BOX * box + 2
    y0, y1 = int(max(rows.min() - margin, 0)), int(min(math.ceil(rows.max() + 1 + margin), H))
    x0, x1 = int(max(cols.min() - margin, 0)), int(min(math.ceil(cols.max() + 1 + margin), W))
    return Region(y0, y1, x0, x1)


#: Where the LIDAR's field cut the spacecraft (``sdcnet.field_edges``), the crop grows on that
#: side by this share of the returns' extent across it.
FIELD_EDGE_GROWTH = 2.0


def past_field_edges(region: Region, cuts: FieldCuts, frame_shape: tuple[int, int]) -> Region:
    """``region`` grown by ``FIELD_EDGE_GROWTH`` of the returns' extent on each side where the
    LIDAR's field ended and the spacecraft did not (``cuts``: ``sdcnet.field_edges``), within
    the frame (``frame_shape``). A flash array's field is often a fraction of the camera's;
    the mask must still hold the parts it did not reach. On the robustness suite this bought
    0.2-0.8 points of IOU where the LIDAR's field is narrower than the camera's and changed no
    frame of the paper's LIDAR; counting a cut across part of the field too, 1.2 more on flash
    frames (docs/development.md, "Measurements"). The cost per frame stays the budget's, a
    larger crop being seen at a coarser scale."""
    H, W = frame_shape
    h, w = cuts.y1 - cuts.y0, cuts.x1 - cuts.x0
    top = max(0, round(region.y0 - FIELD_EDGE_GROWTH * h)) if cuts.top else region.y0
    bottom = min(H, round(region.y1 + FIELD_EDGE_GROWTH * h)) if cuts.bottom else region.y1
    left = max(0, round(region.x0 - FIELD_EDGE_GROWTH * w)) if cuts.left else region.x0
    right = min(W, round(region.x1 + FIELD_EDGE_GROWTH * w)) if cuts.right else region.x1
    return Region(top, bottom, left, right)


def _grow(lo: int, hi: int, length: int, size: int) -> tuple[int, int]:
    """[lo, hi) grown (centred) to ``length`` pixels where the frame of ``size`` allows."""
    length = min(max(length, hi - lo), size)
    lo = min(max(lo - (length - (hi - lo)) // 2, 0), size - length)
    return lo, lo + length


def own_work(crop_pixels: float, hull_pixels: float) -> float:
    """A frame's work at its own resolution, in working pixels' time: ``CROP_PIXEL_COST`` for
    each of its crop's ``crop_pixels`` and ``HULL_PIXEL_COST`` for each of the ``hull_pixels``
    where its points will be."""
    return CROP_PIXEL_COST * crop_pixels + HULL_PIXEL_COST * hull_pixels


def frame_work_pixels(
    work_pixels: int, crop_pixels: int, hull_pixels: float, frame_share: float = 1.0
) -> int:
    """The working pixels one frame gets: what the frame's budget (``FRAME_BUDGET`` times
    ``work_pixels``, in working pixels' time) leaves beside its work at its own resolution,
    ``CROP_PIXEL_COST`` for each of its crop's ``crop_pixels`` and ``HULL_PIXEL_COST`` for each
    of the ``hull_pixels`` within its returns' convex hull (where its points will be), between
    ``MIN_WORK_SHARE`` of ``work_pixels`` and all of them. The network's pixels are most of a
    frame's cost, but not all of it: without this, a 2048 x 2048 crop holding a million points
    took twice a paper frame's milliseconds at the same working pixels.

    ``frame_share`` (at most 1) scales the frame's budget and that floor, not the network's
    ``work_pixels``: on a CPU slower than the one the budget was timed on
    (``sdcnet.frame_budget``), a frame whose own work is small still gets all the network's
    pixels while the frames of large crops and many points get fewer."""
    own = own_work(crop_pixels, hull_pixels)
    floor = MIN_WORK_SHARE * frame_share * work_pixels
    return int(min(work_pixels, max(floor, FRAME_BUDGET * frame_share * work_pixels - own)))


def working_grid(
    region: Region,
    frame_shape: tuple[int, int],
    stride: int,
    work_pixels: int = WORK_PIXELS,
    max_upsample: float = MAX_UPSAMPLE,
) -> WorkingGrid:
    """The grid the network sees ``region`` on: one scale for both axes, the largest (up to
    ``max_upsample``) at which the network's input, padded to multiples of ``stride``, holds
    at most ``work_pixels`` pixels. The region grows, where the frame allows, to fill that
    padded input with real pixels rather than padding."""
    h, w = region.shape
    scale = min(max_upsample, math.sqrt(work_pixels / (h * w)))
    if 1.0 <= scale < 1.02:  # the crop fits as it is: no resampling for 2 % more pixels
        scale = 1.0
    for _ in range(50):  # rounding up to the stride can overshoot the budget: shrink a little
        padded = (-(-h * scale // stride) * stride, -(-w * scale // stride) * stride)
        if padded[0] * padded[1] <= work_pixels or padded == (stride, stride):
            break
        scale *= 0.99 * math.sqrt(work_pixels / (padded[0] * padded[1]))
    y0, y1 = _grow(region.y0, region.y1, int(padded[0] / scale), frame_shape[0])
    x0, x1 = _grow(region.x0, region.x1, int(padded[1] / scale), frame_shape[1])
    grown = Region(y0, y1, x0, x1)
    if scale == 1.0:
        return WorkingGrid(grown, grown.shape)
    shape = tuple(
        max(1, min(int(p), round(n * scale))) for p, n in zip(padded, grown.shape, strict=True)
    )
    return WorkingGrid(grown, shape)


def to_gray(image: np.ndarray) -> np.ndarray:
    """An image as OpenCV decodes it (IMREAD_UNCHANGED: gray, BGR or BGRA) -> gray (H, W) of
    the same dtype; the one conversion the service and the client apply to user images."""
    if image.ndim == 3:
        conversion = {3: cv2.COLOR_BGR2GRAY, 4: cv2.COLOR_BGRA2GRAY}.get(image.shape[2])
        image = cv2.cvtColor(image, conversion) if conversion is not None else image[..., 0]
    return np.ascontiguousarray(image)


def gray_full_scale(dtype: np.dtype) -> float:
    """The gray level of a full-scale pixel of a uint8 or uint16 image."""
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    raise TypeError(f"gray must be uint8 or uint16, got {dtype}")


def in_top_bits(gray: np.ndarray) -> np.ndarray:
    """A 16-bit frame none of whose pixels exceeds ``TWELVE_BIT_MAX`` holds a 12-bit camera's
    values in its low bits (as many such cameras and their PNGs deliver them): those values
    moved to the top bits (x 16), the form the other 12-bit cameras send; any other frame as it
    is. The network's gain at the returns makes a dim frame's two forms look alike only up to
    its bound of 16: on 12-bit frames in the low bits the mask's IOU rose 76.2 -> 79.1 %
    (docs/development.md, "Measurements")."""
    if gray.dtype == np.uint16 and int(gray.max()) <= TWELVE_BIT_MAX:
        return np.left_shift(gray, 4)
    return gray


def normalise_gray(gray: np.ndarray) -> np.ndarray:
    """uint8 or uint16 gray image -> float32 in [0, 1] (the model's input convention)."""
    return gray.astype(np.float32) / gray_full_scale(gray.dtype)


def resample_sparse(sparse: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Move every LIDAR return to its pixel in a grid of ``shape`` (``place_returns``)."""
    rows, cols = return_pixels(sparse)
    return place_returns(rows, cols, sparse[rows, cols], sparse.shape, shape)


def place_returns(
    rows: np.ndarray,
    cols: np.ndarray,
    z: np.ndarray,
    source: tuple[int, int],
    shape: tuple[int, int],
) -> np.ndarray:
    """The sparse map (``shape``, metres, 0 = none) of returns at pixel ``rows``, ``cols`` of
    a grid of shape ``source``, each moved to its scaled position (pixel centres at integer
    coordinates), the nearest winning a pixel. Interpolating a sparse map would invent depths
    between returns; this keeps each return once."""
    sy, sx = shape[0] / source[0], shape[1] / source[1]
    r = np.clip(np.round((rows + 0.5) * sy - 0.5).astype(int), 0, shape[0] - 1)
    c = np.clip(np.round((cols + 0.5) * sx - 0.5).astype(int), 0, shape[1] - 1)
    return scatter_nearest(r, c, z, shape)


def resample_image(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """An image (gray of any dtype, probability) resampled to ``shape``: area averaging to
    shrink (no aliasing of the outline), bilinear to enlarge."""
    if image.shape == shape:
        return image
    shrink = shape[0] * shape[1] < image.shape[0] * image.shape[1]
    method = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return cv2.resize(image, (shape[1], shape[0]), interpolation=method)


#: Neighbouring working pixels whose depths differ by more than this many footprints (range /
#: focal length) lie on two surfaces: the depth is not interpolated between them.
DEPTH_EDGE_FOOTPRINTS = 4.0


def resample_depth(
    depth: np.ndarray,
    shape: tuple[int, int],
    footprint_m: float,
    window: Region | None = None,
) -> np.ndarray:
    """A depth map (metres) resampled to ``shape``, or the ``window`` of it (pixels of
    ``shape``): bilinear on surfaces, nearest across depth edges (``DEPTH_EDGE_FOOTPRINTS``),
    so no point is invented between a panel and the bus behind it; nearest when shrinking. An
    infinite ``footprint_m`` has no edges: bilinear everywhere, without looking for them (0.5
    against 2.4 ms for a 2048 x 2048 crop). The bilinear map is OpenCV's over the whole of
    ``shape`` (the window's pixels as they would be without it); the nearest pixels
    (``nearest_resampled``) are gathered within the window only."""
    window = Region(0, shape[0], 0, shape[1]) if window is None else window
    if depth.shape == shape:
        return depth[window.slices]
    if shape[0] * shape[1] < depth.shape[0] * depth.shape[1]:
        return nearest_resampled(depth, shape, window)
    linear = cv2.resize(depth, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    linear = linear[window.slices]
    if not math.isfinite(footprint_m):
        return linear
    kernel = np.ones((3, 3), np.uint8)
    spread = cv2.dilate(depth, kernel) - cv2.erode(depth, kernel)
    edge = (spread > DEPTH_EDGE_FOOTPRINTS * footprint_m).astype(np.uint8)
    # the whole window gathered and copied under the edge mask (indexing the edge pixels
    # alone took up to 13 ms a frame)
    nearest = nearest_resampled(depth, shape, window)
    cv2.copyTo(nearest, nearest_resampled(edge, shape, window), linear)
    return linear


def nearest_resampled(
    image: np.ndarray, shape: tuple[int, int], window: Region | None = None
) -> np.ndarray:
    """``image`` (h, w) resampled to ``shape`` by nearest neighbour, or the ``window`` of it:
    each pixel takes the source pixel under its centre, (2 i + 1) h // (2 H) along each axis
    (gathered along one axis, then the other), as the returns are placed (``place_returns``)
    and OpenCV's bilinear map samples. OpenCV's own nearest takes i h // H, up to a source
    pixel before it: on a crop the working grid enlarged 2.5 times, half a frame pixel, 0.17 m
    on a panel seen edge-on.

    The source pixels under a window are a run of rows and of columns, each repeated as many
    times as pixels take it: ``np.repeat`` of the run, columns then rows, gives the gather's
    pixels at a third of its time (1.0 against 3.2 ms for 300 x 300 -> 2048 x 2048)."""
    window = Region(0, shape[0], 0, shape[1]) if window is None else window
    rows = source_indices(window.y0, window.y1, shape[0], image.shape[0])
    cols = source_indices(window.x0, window.x1, shape[1], image.shape[1])
    if not (len(rows) and len(cols)):  # an empty window
        return np.empty((len(rows), len(cols)), image.dtype)
    run = image[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    widened = np.repeat(run, np.bincount(cols - cols[0]), axis=1)
    return np.repeat(widened, np.bincount(rows - rows[0]), axis=0)


def source_indices(start: int, stop: int, size: int, source_size: int) -> np.ndarray:
    """The source pixels under the centres of pixels ``start:stop`` along an axis of ``size``
    pixels resampled from ``source_size`` (``nearest_resampled``)."""
    return (2 * np.arange(start, stop) + 1) * source_size // (2 * size)


#: A crop the working grid shrank gets its outline back from the frame's own gray image: the
#: probability is pasted back through a fast guided filter (He and Sun, 2015) whose windows are
#: this many working pixels from their centre ...
GUIDE_RADIUS = 4
#: ... and whose regularisation is this variance of the guide (the gray image scaled to 0.5
#: at the returns' median, so that an 8-bit, a 12-bit and a dim frame are guided alike).
GUIDE_EPS = 1e-3


def guide_gain(gray: np.ndarray, sparse: np.ndarray) -> np.float32:
    """What the working grid's ``gray`` (h, w) in [0, 1] is multiplied by to guide the paste
    back: 0.5 at the median gray of its returns (``sparse`` (h, w) metres), so that an 8-bit,
    a 12-bit and a dim frame are guided alike."""
    returns = sparse > 0
    reference = float(np.median(gray[returns])) if returns.any() else 0.5
    return np.float32(0.5 / max(reference, 1e-3))


def guided_probability(
    prob: np.ndarray, gray: np.ndarray, gain: np.float32, gray_crop: np.ndarray
) -> np.ndarray:
    """The working grid's foreground probability (``prob`` (h, w), beside its ``gray`` in
    [0, 1], which ``gain`` makes the guide: ``guide_gain``) on the crop's own grid
    (``gray_crop``: the frame's pixels, uint8 or uint16, (H, W)), its outline drawn where the
    crop's gray image has it.

    Each working pixel's probability is fit as a linear function of the gray image over its
    window (``GUIDE_RADIUS``, ``GUIDE_EPS``); the fit's coefficients, averaged and resampled
    to the crop, apply to the crop's own gray values. Where the gray image is flat (inside
    the spacecraft, the black sky) this is the resampled probability; across an outline the
    edge moves to where the image has it, to the frame's pixel, which the shrunk grid lost;
    but a star or a noisy pixel beside the outline can cross the threshold too, so the mask is
    vouched for again by the returns at the frame's resolution (``complete``). Both bought
    0.2-1.9 points of IOU per condition of the robustness suite, with 0.3 false specks per
    frame or fewer (docs/development.md, "Measurements")."""
    guide = gray * gain
    size = (2 * GUIDE_RADIUS + 1, 2 * GUIDE_RADIUS + 1)

    def mean(x: np.ndarray) -> np.ndarray:
        return cv2.boxFilter(x, -1, size)

    mean_guide, mean_prob = mean(guide), mean(prob)
    variance = mean(guide * guide) - mean_guide * mean_guide
    slope = (mean(guide * prob) - mean_guide * mean_prob) / (variance + np.float32(GUIDE_EPS))
    offset = mean_prob - slope * mean_guide
    shape = gray_crop.shape
    full_scale = float(gain) / gray_full_scale(gray_crop.dtype)
    out = cv2.multiply(
        resample_image(mean(slope), shape), gray_crop, dtype=cv2.CV_32F, scale=full_scale
    )
    out += resample_image(mean(offset), shape)
    cv2.threshold(out, 1.0, 1.0, cv2.THRESH_TRUNC, dst=out)  # clipped to [0, 1] in place
    return cv2.max(out, 0.0, dst=out)


@dataclass
class Completion:
    """The answer on the whole frame, zero outside the spacecraft's crop (``grid.region``):
    depth in metres and sigma (0 off the mask), mask; the foreground probability on the crop,
    the whole frame on demand; on the working grid the surface, mask, image and sigma the
    normals of the answer's points are taken from (``sdcnet.normals``); where the LIDAR's
    field cut the spacecraft, if it did, and the IOU its mask is likely to score
    (``sdcnet.caveats``)."""

    depth: np.ndarray  # (H, W) float32 metres, 0 off the mask
    mask: np.ndarray  # (H, W) bool
    probability_crop: np.ndarray  # (h, w) float32
    grid: WorkingGrid
    surface: np.ndarray  # (h', w') float32 metres on the working grid: what depth resamples
    working_mask: np.ndarray  # (h', w') bool: the mask on the working grid
    working_gray: np.ndarray  # (h', w') float32 in [0, 1]: the image the network saw
    sigma: np.ndarray | None = None  # (H, W) float32 metres, 0 off the mask; None: model has none
    working_sigma: np.ndarray | None = None  # (h', w') float32 metres: what sigma resamples
    cuts: FieldCuts | None = None  # where the LIDAR's field cut the spacecraft (frame pixels)
    #: the IOU the mask is likely to score, from the network's own foreground probability on
    #: the working grid (``sdcnet.caveats.mask_iou_estimate``)
    mask_iou_estimate: float = 1.0
    #: whether the mask reached a side of the crop inside the frame: the spacecraft goes on
    #: beyond what the network saw (``sdcnet.caveats.reaches_crop_side``)
    crop_cut: bool = False
    #: the second look at a crop grown past the sides the mask reached (``with_second_look``),
    #: whose working grid answers outside ``grid``'s crop (its frame-wide maps are this
    #: answer's); None where there was none
    beyond: Completion | None = None
    #: the returns left out as strays, alone far from the rest (``sdcnet.stray_returns``)
    stray_returns: int = 0
    #: (H, W) float32 metres, 0 where none: the frame's returns the answer used, its strays
    #: left out (the frame's own map where there were none); None only for an answer made
    #: outside ``complete_on``
    used_returns: np.ndarray | None = None

    @property
    def region(self) -> Region:
        """The crop the answer covers: the second look's where there is one, else the first's
        (``grid``'s). Outside it the answer is background."""
        return self.grid.region if self.beyond is None else self.beyond.region

    @property
    def frame_shape(self) -> tuple[int, int]:
        return self.mask.shape

    @property
    def depth_crop(self) -> np.ndarray:
        """(h, w) float32 metres, 0 off the mask: a view of ``depth``."""
        return self.depth[self.region.slices]

    @property
    def mask_crop(self) -> np.ndarray:
        """(h, w) bool: a view of ``mask``."""
        return self.mask[self.region.slices]

    @property
    def sigma_crop(self) -> np.ndarray | None:
        """(h, w) float32 metres, 0 off the mask: a view of ``sigma``."""
        return None if self.sigma is None else self.sigma[self.region.slices]

    @property
    def probability(self) -> np.ndarray:
        """(H, W) float32."""
        full = np.zeros(self.frame_shape, self.probability_crop.dtype)
        full[self.region.slices] = self.probability_crop
        return full


#: A foreground component is the spacecraft's when a LIDAR return lies on it or this close to
#: it (working pixels, Chebyshev): a return just off the predicted outline (rounded onto the
#: working grid, or seen from the LIDAR's own viewpoint, offset from the camera's)
#: still vouches for the part it hit.
RETURN_REACH_PX = 1


def drop_specks(mask: np.ndarray, sparse: np.ndarray, reach_px: int) -> np.ndarray:
    """``mask`` without the components that cannot be the spacecraft: stars, the Earth, glare
    (``mask`` itself when every component is vouched for).

    The LIDAR answers from the target and never from the sky behind it, so a component
    (8-connected) with a return on it, or within ``reach_px``, is the spacecraft, and one
    without is not, however close: a bright patch of cloud or limb beside the target is glued
    to it only through the network's mask, never through a return. A part of the spacecraft
    the beams all missed and the mask shows detached from the rest (a thin boom between scan
    lines) goes with them: on the robustness suite that cost 0.4 points of IOU at most and cut
    the false specks per frame by two thirds or more in every condition (docs/development.md,
    "Measurements"). ``sparse``: the returns' depths (metres, 0 = none), or any map positive
    where a pixel vouches (``cut_off_beyond`` adds a first look's answer to the returns).
    """
    if mask.size == 0:
        return mask
    image = mask.astype(np.uint8)
    count, labels = cv2.connectedComponents(image, connectivity=8)
    returns = cv2.compare(sparse, 0, cv2.CMP_GT)
    reach = np.ones((2 * reach_px + 1, 2 * reach_px + 1), np.uint8)
    if count <= 256:
        # the usual frame: a histogram of the labels under the returns says which components
        # hold one, and an 8-bit table lookup keeps them (a dense LIDAR's 0.9M dilated return
        # pixels found and gathered one by one took 8.4 of 12 ms on a 1536 x 1608 crop; the
        # histogram takes 1.2)
        if reach_px > 0:
            returns = cv2.dilate(returns, reach)
        small = labels.astype(np.uint8)
        vouched = cv2.calcHist([small], [0], returns, [256], [0, 256]).ravel()[:count] > 0
        if vouched[1:].all():  # nothing to drop, no pass over the labels
            return mask
        vouched[0] = False
        table = np.zeros(256, np.uint8)
        table[:count] = vouched
        return cv2.LUT(small, table).view(bool)
    # more (the specks of a guided paste-back beside a textured outline: up to 9,000 on a
    # 2048 x 2048 crop, mostly single pixels): the vouched components flood-filled 1 -> 2
    # over their own pixels alone, first those a return lies on, then those still 1 within
    # reach of one, each from one of its pixels. The second search finds few pixels: those
    # of a dense LIDAR's reach over the first's components (0.55M on a 2048 x 2048 crop,
    # 14-18 ms where all were gathered at once) are 2 by then.
    _fill_hit_components(image, labels, count, cv2.bitwise_and(returns, image))
    if reach_px > 0:
        near = cv2.bitwise_and(cv2.dilate(returns, reach), cv2.compare(image, 1, cv2.CMP_EQ))
        _fill_hit_components(image, labels, count, near)
    if not cv2.countNonZero(cv2.compare(image, 1, cv2.CMP_EQ)):
        return mask  # every component vouched for
    return (image >> 1).view(bool)


def _fill_hit_components(
    image: np.ndarray, labels: np.ndarray, count: int, hits: np.ndarray
) -> None:
    """Flood-fill with 2 (8-connected, in place) each component of ``image`` (uint8, 1 on
    the mask) that holds a nonzero pixel of ``hits`` (uint8, on the mask), from one of them;
    ``labels`` (int32) the components' labels, ``count`` of them."""
    found = cv2.findNonZero(hits)
    if found is None:
        return
    xy = found.reshape(-1, 2)
    one = np.full(count, -1, np.intp)  # one hit pixel of each component hit
    one[labels[xy[:, 1], xy[:, 0]]] = np.arange(len(xy))
    for x, y in xy[one[one >= 0]]:
        cv2.floodFill(image, None, (int(x), int(y)), 2, flags=8)


def mask_box(mask: np.ndarray, margin: int = 0) -> Region:
    """The smallest region of ``mask`` (bool (h, w)) holding all its pixels, grown by
    ``margin`` pixels on each side within the mask's bounds; 0 x 0 for an empty mask."""
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    if w == 0:
        return Region(0, 0, 0, 0)
    rows, cols = mask.shape
    return Region(
        max(y - margin, 0), min(y + h + margin, rows), max(x - margin, 0), min(x + w + margin, cols)
    )


def vouched_mask(prob: np.ndarray, sparse: np.ndarray, threshold: float) -> np.ndarray:
    """The pixels of ``prob`` (float32 (h, w), the crop's pasted-back probability) above
    ``threshold`` that ``drop_specks`` keeps, vouched for by the returns of ``sparse`` (metres,
    (h, w)) at the crop's own resolution; ``prob`` is set to 0 on the pixels dropped. Only the
    window holding those pixels, grown by the returns' reach (``RETURN_REACH_PX``), is searched:
    the same components and returns as the whole crop's, at a fraction of a 2048 x 2048 crop's
    cost."""
    mask = prob > threshold
    box = mask_box(mask, RETURN_REACH_PX).slices
    inside = mask[box]
    kept = drop_specks(inside, sparse[box], RETURN_REACH_PX)
    if kept is not inside:
        np.copyto(prob[box], 0.0, where=inside ^ kept)
        inside[...] = kept
    return mask


def join_returns_beside(
    mask: np.ndarray, prob: np.ndarray, rows: np.ndarray, cols: np.ndarray, threshold: float
) -> None:
    """``mask`` (bool (h, w), a crop's answer at the frame's resolution) with the returns at
    pixels ``rows``, ``cols`` of the crop that lie within ``RETURN_REACH_PX`` of it joined to
    it, and ``prob`` (float32 (h, w)) just above ``threshold`` on them, so that the mask stays
    ``prob > threshold``; both changed in place.

    Such a return vouched for the part beside it (``drop_specks``) and lies on the spacecraft,
    where the mask missed its pixel by one: a truss member, a boom's edge. Without it the part
    is a fragment holding no return; with it, the part holds the return that vouched for it.
    On the robustness suite 79-89 % of the pixels joined were the spacecraft's, their depth
    5.2 cm from the truth (mean, docking); the false specks a frame fell from as many as 0.33
    to at most 0.04 in every condition, and from 0.68 to 0.01 on 100 new docking frames
    (docs/development.md, "Measurements"). Only the returns off the mask are looked at, and
    only their neighbours: a 2048 x 2048 crop's maps are not passed over again."""
    off = ~mask[rows, cols]
    rows, cols = rows[off], cols[off]
    (h, w), reach = mask.shape, RETURN_REACH_PX
    beside = np.zeros(len(rows), bool)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            beside |= mask[np.clip(rows + dy, 0, h - 1), np.clip(cols + dx, 0, w - 1)]
    rows, cols = rows[beside], cols[beside]
    mask[rows, cols] = True
    prob[rows, cols] = np.nextafter(np.float32(threshold), np.float32(1))


def on_mask(window: np.ndarray, mask: np.ndarray, box: Region) -> np.ndarray:
    """A map of ``mask``'s shape (the frame's, (H, W)), 0 off the mask, holding ``window`` (the
    map's values within ``box``, which holds all of ``mask``'s pixels) on it."""
    out = np.zeros(mask.shape, window.dtype)
    cv2.copyTo(window, mask[box.slices].view(np.uint8), out[box.slices])
    return out


@dataclass(frozen=True)
class WorkingInputs:
    """One frame's crop on its working grid, as the network takes it: gray float32 (h, w) in
    [0, 1], sparse float32 (h, w) metres, the focal length in working pixels; and where the
    LIDAR's field cut the spacecraft (frame pixels; None where it did not, or where the crop
    was given); the frame pixels of the returns' convex hull, as ``frame_work_pixels`` counts
    them; the pixels (rows, columns) of the returns in the crop, in its own pixels; and the
    returns the depth is anchored to on the working grid, where they are more than ``sparse``'s
    (None: ``sparse``'s)."""

    gray: np.ndarray
    sparse: np.ndarray
    focal_px: float
    grid: WorkingGrid
    cuts: FieldCuts | None = None
    hull_pixels: float = 0.0
    crop_returns: tuple[np.ndarray, np.ndarray] = (np.empty(0, np.intp), np.empty(0, np.intp))
    anchors: np.ndarray | None = None

    @property
    def anchor_returns(self) -> np.ndarray:
        """float32 (h, w) metres on the working grid: the returns the depth is anchored to."""
        return self.sparse if self.anchors is None else self.anchors


def working_inputs(
    gray: np.ndarray,
    sparse: np.ndarray,
    focal_px: float,
    stride: int,
    work_pixels: int = WORK_PIXELS,
    region: Region | None = None,
    frame_share: float = 1.0,
    anchors: np.ndarray | None = None,
) -> WorkingInputs:
    """Crop a frame to the spacecraft's region (or ``region``) and resample it to its working
    grid, of at most ``work_pixels`` pixels, fewer where the frame's own work at its resolution
    would take it past its budget (``frame_work_pixels``, ``frame_share`` of it). gray
    uint8/uint16 (H, W); sparse float32 (H, W) metres, 0 = no return; ``focal_px`` the
    camera's focal length in the frame's pixels (fx); ``anchors`` (H, W) metres, the returns
    the depth is anchored to where they are more than ``sparse``'s (its stray returns too)."""
    if gray.shape != sparse.shape:
        raise ValueError(f"gray {gray.shape} and sparse {sparse.shape} differ in size")
    if not (math.isfinite(focal_px) and focal_px > 0):
        raise ValueError(f"focal_px must be a positive number of pixels, got {focal_px}")
    rows, cols = return_pixels(sparse)
    spacing = return_spacing(rows, cols)
    cuts = None
    if region is None:
        region, cuts = spacecraft_region(rows, cols, gray, spacing)
    hull_pixels = 0.0 if spacing is None else spacing * spacing * len(rows)
    budget = frame_work_pixels(
        work_pixels, region.shape[0] * region.shape[1], hull_pixels, frame_share
    )
    grid = working_grid(region, gray.shape, stride, budget)
    g = grid.region
    inside = g.holds(rows, cols)
    rows, cols = rows[inside], cols[inside]
    return WorkingInputs(
        normalise_gray(resample_image(gray[g.slices], grid.shape)),
        place_returns(rows - g.y0, cols - g.x0, sparse[rows, cols], g.shape, grid.shape),
        focal_px * grid.scale[1],
        grid,
        cuts,
        hull_pixels,
        (rows - g.y0, cols - g.x0),
        None if anchors is None else on_grid(anchors, grid),
    )


def on_grid(sparse: np.ndarray, grid: WorkingGrid) -> np.ndarray:
    """The returns of ``sparse`` (H, W metres) within ``grid``'s crop, placed on its working
    grid (``place_returns``)."""
    g = grid.region
    rows, cols = return_pixels(sparse[g.slices])
    return place_returns(rows, cols, sparse[g.slices][rows, cols], g.shape, grid.shape)


def run_model(model: ModelFn, inputs: WorkingInputs) -> tuple[np.ndarray, ...]:
    """The model's depth (metres), probability and sigma (metres; None when the model has
    none) on one frame's working grid (h, w)."""
    outputs = model(
        inputs.gray[None, None],
        inputs.sparse[None, None],
        np.full((1, 1, 1, 1), inputs.focal_px, np.float32),
    )
    depth, prob, *sigma = (o[0, 0] for o in outputs)
    return depth, prob, (sigma[0] if sigma else None)


def past_the_field(
    kept: np.ndarray, prob: np.ndarray, inputs: WorkingInputs, gray: np.ndarray
) -> np.ndarray:
    """The working grid's mask ``kept`` grown past the sides where the LIDAR's field cut the
    spacecraft (``inputs.cuts``) into what the image shows beyond them (``grown_past_field``),
    where the frame ``gray``'s sky is dark (``sky_is_dark``); the grown pixels' probability
    ``prob`` (h, w) set to 1 in place."""
    grid, cuts = inputs.grid, inputs.cuts
    region = grid.region
    beyond = cuts.beyond((region.y0, region.x0), grid.scale, kept.shape)
    bright = cuts.bright / gray_full_scale(gray.dtype)  # in the working grid's units
    grown = grown_past_field(kept, inputs.gray, bright, beyond)
    if grown is kept or not sky_is_dark(
        gray, cuts, grown, (region.y0, region.y1, region.x0, region.x1)
    ):
        return kept
    prob[grown & ~kept] = 1.0
    return grown


def edges_at_frame(
    depth: np.ndarray,
    box: Region,
    shape: tuple[int, int],
    surface: np.ndarray,
    mask_w: np.ndarray,
    inputs: WorkingInputs,
    anchored: Anchored,
    gray: np.ndarray,
    gain: np.float32,
    footprint: float,
) -> None:
    """``depth``, the window ``box`` of a shrunk crop of ``shape`` pasted by nearest
    neighbour from ``surface`` (metres on the working grid, its mask ``mask_w``), redrawn
    along the grid's depth edges from the frame's ``gray`` (guided as the outline is, by
    ``gain``: ``guide_gain``) and the returns nearest them (``anchored``'s;
    ``sdcnet.edge_paste``), in place; ``footprint`` is a working pixel's footprint in metres.
    Without a return on the mask, left as it is."""
    if not len(anchored.rows):
        return
    frame_gray = gray[inputs.grid.region.slices][box.slices]
    paste_across_edges(
        depth,
        source_indices(box.y0, box.y1, shape[0], surface.shape[0]),
        source_indices(box.x0, box.x1, shape[1], surface.shape[1]),
        frame_gray,
        float(gain) / gray_full_scale(frame_gray.dtype),
        surface,
        mask_w,
        inputs.gray * gain,
        anchored.nearest_m,
        anchored.apart_px,
        footprint,
    )


def complete(
    model: ModelFn,
    gray: np.ndarray,
    sparse: np.ndarray,
    focal_px: float,
    stride: int,
    work_pixels: int = WORK_PIXELS,
    threshold: float = 0.5,
    frame_share: float = 1.0,
) -> Completion:
    """Run ``model`` on the spacecraft's region of one frame, resampled to its working grid
    (``working_inputs``: at most ``work_pixels``, ``frame_share`` of the frame's budget),
    anchor its depth to the returns (``anchor_to_returns``) and its sigma with it
    (``anchored_sigma``), smooth the surface between the returns
    (``smoothed_between_returns``), and paste the answer back at the frame's resolution
    (``complete_on``). Where the mask reached a side of the crop inside the frame, and the
    frame's budget has room left (``second_look_pixels``), look again at the crop grown past
    those sides, on a coarser grid, and answer from that look beyond the first crop
    (``with_second_look``). A 12-bit frame in a 16-bit image's low bits is read as in its top
    bits (``in_top_bits``). Stray returns, alone far from the rest (``sdcnet.stray_returns``),
    are left out of all of it but the anchoring: a stray off the spacecraft lies off the mask
    and anchors nothing, a part's own lone return still anchors the depth the mask holds there
    (on the real spacecraft, the same-pixel MAE 0-3 px from a return 0.072 m with the strays
    left out of the anchoring too, 0.069 without; docs/development.md). The answer counts
    them."""
    gray = in_top_bits(gray)
    kept, strays = without_strays(sparse)
    anchors = sparse if strays else None
    inputs = working_inputs(
        gray, kept, focal_px, stride, work_pixels, frame_share=frame_share, anchors=anchors
    )
    first = replace(complete_on(model, gray, kept, inputs, threshold), stray_returns=strays)
    if not first.crop_cut:
        return first
    sides = crop_sides_reached(first.mask_crop, first.region, gray.shape)
    grown = grown_past_sides(first.region, sides, gray.shape)
    pixels = second_look_pixels(inputs, grown, work_pixels, frame_share)
    if not pixels:
        return first
    again = working_inputs(gray, kept, focal_px, stride, pixels, region=grown, anchors=anchors)
    return with_second_look(first, complete_on(model, gray, kept, again, threshold), kept)


def complete_on(
    model: ModelFn,
    gray: np.ndarray,
    sparse: np.ndarray,
    inputs: WorkingInputs,
    threshold: float = 0.5,
) -> Completion:
    """One look of ``complete``: ``model`` run on a frame's ``inputs`` (``working_inputs``),
    its answer anchored and pasted back at the frame's resolution (``gray`` and ``sparse``
    as ``complete`` reads them)."""
    grid = inputs.grid
    depth_w, prob_w, sigma_w = run_model(model, inputs)
    kept = drop_specks(prob_w > threshold, inputs.sparse, RETURN_REACH_PX)
    prob_w = np.where(kept | (prob_w <= threshold), prob_w, 0.0).astype(np.float32)
    if inputs.cuts is not None:
        kept = past_the_field(kept, prob_w, inputs, gray)
    rows, cols = return_pixels(inputs.sparse)
    spread_px = spreading_sigma_px(return_spacing(rows, cols), 1.0 / grid.scale[1])
    mask_w = prob_w > threshold
    anchored = anchor_to_returns(depth_w, mask_w, inputs.anchor_returns, spread_px, inputs.focal_px)
    returns = inputs.sparse[rows, cols]
    footprint = float(returns.mean()) / inputs.focal_px if returns.size else 1.0
    surface = smoothed_between_returns(
        anchored.depth, mask_w, anchored.rows, anchored.cols, footprint
    )
    shape = grid.region.shape
    # a shrunk crop: its outline and its depth edges from the frame's own gray image
    gain = guide_gain(inputs.gray, inputs.sparse) if grid.scale[0] < 1.0 else None
    if gain is not None:
        crop = grid.region.slices
        prob_crop = guided_probability(prob_w, inputs.gray, gain, gray[crop])
        # the image guides the outline near stars and noise too: vouched for again, in frame px
        mask_crop = vouched_mask(prob_crop, sparse[crop], threshold)
    else:
        prob_crop = resample_image(prob_w, shape)
        # the crop's own probability: the working grid's stays the network's
        prob_crop = prob_crop.copy() if grid.identity else prob_crop
        mask_crop = kept if grid.identity else prob_crop > threshold
    join_returns_beside(mask_crop, prob_crop, *inputs.crop_returns, threshold)
    # The frame's answer, 0 off the mask: depth and sigma resampled within the mask's box alone
    box = mask_box(mask_crop)
    at = box.within(grid.region)
    mask = np.zeros(gray.shape, bool)
    mask[at.slices] = mask_crop[box.slices]
    depth = on_mask(resample_depth(surface, shape, footprint, box), mask, at)
    if gain is not None:
        edges_at_frame(
            depth[at.slices], box, shape, surface, mask_w, inputs, anchored, gray, gain, footprint
        )
    sigma = served_w = None
    if sigma_w is not None:
        served_w = anchored_sigma(sigma_w, anchored, mask_w)
        sigma = on_mask(resample_depth(served_w, shape, math.inf, box), mask, at)
    crop_cut = reaches_crop_side(mask_crop, grid.region, gray.shape)
    return Completion(
        depth,
        mask,
        prob_crop,
        grid,
        surface,
        mask_w,
        inputs.gray,
        sigma,
        served_w,
        inputs.cuts,
        mask_iou_estimate(prob_w, mask_w, crop_cut),
        crop_cut,
        used_returns=sparse,
    )


#: A second look (``complete``) has at most this share of the model's ``work_pixels`` ...
SECOND_LOOK_SHARE = 0.5
#: ... and none is taken with less than this share left in the frame's budget.
MIN_SECOND_LOOK_SHARE = 0.1


def grown_past_sides(
    region: Region, sides: tuple[bool, bool, bool, bool], frame_shape: tuple[int, int]
) -> Region:
    """``region`` grown by its own height or width past each of its ``sides`` (top, bottom,
    left, right) that the mask reached (``sdcnet.caveats.crop_sides_reached``), within the
    frame (``frame_shape``)."""
    (H, W), (h, w) = frame_shape, region.shape
    top, bottom, left, right = sides
    return Region(
        max(0, region.y0 - h) if top else region.y0,
        min(H, region.y1 + h) if bottom else region.y1,
        max(0, region.x0 - w) if left else region.x0,
        min(W, region.x1 + w) if right else region.x1,
    )


def second_look_pixels(
    first: WorkingInputs, grown: Region, work_pixels: int, frame_share: float = 1.0
) -> int:
    """The working pixels a second look at the crop ``grown`` gets: what the frame's budget
    (``frame_work_pixels``' terms) leaves after the first look (``first``: its working pixels,
    its crop's and its hull's work), the grown crop's work at the frame's resolution and the
    points the answer may gain beyond the first crop (its added area, as hull pixels), at
    most ``SECOND_LOOK_SHARE`` of ``work_pixels`` (``working_inputs`` may give it fewer, as
    it does any crop whose own work is large); 0 (no second look) below
    ``MIN_SECOND_LOOK_SHARE`` of it. A frame whose first look took its whole budget (a large
    crop, many points) gets none: the cost of every frame stays within its budget."""
    first_pixels = first.grid.shape[0] * first.grid.shape[1]
    (h, w), (gh, gw) = first.grid.region.shape, grown.shape
    crop_pixels, grown_pixels = h * w, gh * gw
    points = first.hull_pixels + grown_pixels - crop_pixels
    spent = first_pixels + own_work(crop_pixels + grown_pixels, points)
    left = min(FRAME_BUDGET * frame_share * work_pixels - spent, SECOND_LOOK_SHARE * work_pixels)
    return int(left) if left >= MIN_SECOND_LOOK_SHARE * work_pixels else 0


def with_second_look(first: Completion, second: Completion, sparse: np.ndarray) -> Completion:
    """``first``'s answer within its crop and ``second``'s (a look at a crop grown past the
    sides ``first``'s mask reached, on a coarser grid) beyond it: the spacecraft past the
    first crop's sides, at the first look's resolution where it had one. On the robustness
    suite with the twelfth model, IOU flash +1.0 points (9 of its 52 frames looked again),
    `any` +0.4, wide-multibeam +0.1, the rest unchanged; 6 frames better by more than a
    point, 3 worse (docs/development.md, "Measurements"). ``second``'s frame-wide maps become
    the answer's, without the parts beyond the first crop that the join cut off from every
    return of ``sparse`` (``cut_off_beyond``)."""
    inner = first.region.slices
    depth, mask, sigma = second.depth, second.mask, second.sigma
    depth[inner], mask[inner] = first.depth[inner], first.mask[inner]
    if sigma is not None:
        sigma[inner] = first.sigma[inner]
    probability = second.probability_crop
    probability[first.region.relative_to(second.region).slices] = first.probability_crop
    rows, cols = cut_off_beyond(mask, first.region, sparse)
    for values in (mask, depth, sigma):
        if values is not None:
            values[rows, cols] = 0
    probability[rows - second.region.y0, cols - second.region.x0] = 0.0
    return replace(
        first,
        depth=depth,
        mask=mask,
        sigma=sigma,
        probability_crop=probability,
        mask_iou_estimate=second.mask_iou_estimate,
        crop_cut=second.crop_cut,
        beyond=second,
    )


def cut_off_beyond(
    mask: np.ndarray, inner: Region, sparse: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pixels (rows, cols) of ``mask`` (bool (H, W): a first look's answer inside
    ``inner``, its crop, and a second look's beyond it) beyond ``inner`` in parts joined to
    neither the first look's answer nor a return of ``sparse`` (metres, (H, W)) within
    ``RETURN_REACH_PX``. The second look vouched for its parts through its own mask inside
    ``inner`` too; where the first look's finer answer there does not join a part to the rest,
    nothing vouches for it any more: a fragment of a bright edge beside the crop's side, a
    patch of glow (on the robustness suite's docking frames with the fifteenth model, 9 of its
    26 false specks; docs/development.md, "Measurements"). Of ``inner`` only its edge, one
    pixel wide, is labelled: the first look's answer there joins a part to the rest."""
    window = mask_box(mask, RETURN_REACH_PX)
    part = mask[window.slices].copy()
    vouchers = cv2.compare(sparse[window.slices], 0, cv2.CMP_GT)
    y0, x0 = max(inner.y0, window.y0), max(inner.x0, window.x0)
    y1, x1 = min(inner.y1, window.y1), min(inner.x1, window.x1)
    edge = Region(y0, max(y0, y1), x0, max(x0, x1)).relative_to(window)
    on_edge = np.zeros(part.shape, bool)
    on_edge[edge.slices] = part[edge.slices]
    core = Region(
        edge.y0 + 1, max(edge.y0 + 1, edge.y1 - 1), edge.x0 + 1, max(edge.x0 + 1, edge.x1 - 1)
    )
    part[core.slices] = False
    on_edge[core.slices] = False
    vouchers[on_edge] = 255
    kept = drop_specks(part, vouchers, RETURN_REACH_PX)
    if kept is part:
        return np.empty(0, np.intp), np.empty(0, np.intp)
    rows, cols = np.nonzero(part & ~kept)
    return rows + window.y0, cols + window.x0
