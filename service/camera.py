"""The camera of ``sdc-serve --camera FILE`` (``sdcnet.calibration``): the intrinsics requests
default to, and the lens distortion taken out of every frame before completion.

Without a camera nothing changes: intrinsics not given are the model's (the paper's camera)
scaled to the image. With one, a frame passes through ``camera_frame`` in the decode phase,
whatever protocol brought it (``POST /complete`` and ``POST /pose``'s form, the Open Inference
Protocol's tensors): the camera applies at the frame's size (``CameraCalibration.at_size``),
a camera with distortion has the image and the returns undistorted into the pinhole frame of
its own K, and intrinsics the request does not give are the camera's. Values a request gives
still win, one by one.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import replace
from typing import Any

from sdcnet.calibration import CalibrationError, CameraCalibration, Undistorter, load_camera_file
from sdcnet.pointcloud import mask_pixels
from sdcnet.returns import scatter_nearest
from sdcnet.service.decode import Frame
from sdcnet.service.errors import ApiError
from sdcnet.service.settings import Settings

logger = logging.getLogger("sdcnet.service")

#: What GET /model says of the answers under a camera.
ANSWER_FRAME = (
    "Answers (depth, mask, points) are in the undistorted pinhole frame of this camera: "
    "its fx, fy, cx, cy (scaled to the frame's size), no lens distortion."
)
#: Frame sizes whose undistortion maps are kept (the camera's own and resampled ones); the
#: maps of a frame take 8 bytes a pixel and 5 to 20 ms to build for 1024 x 1024.
UNDISTORTER_SIZES = 3


class ServiceCamera:
    """The configured camera: its calibration, and its undistorters for the frame sizes last
    seen (built once per size; its own size's at start-up)."""

    def __init__(self, calibration: CameraCalibration):
        self.calibration = calibration
        self.undistorter = functools.lru_cache(maxsize=UNDISTORTER_SIZES)(Undistorter)
        if calibration.distortion:
            self.undistorter(calibration)

    def describe(self) -> dict[str, Any]:
        """GET /model's ``camera``: the calibration and the frame answers are in."""
        return {**self.calibration.describe(), "frame": ANSWER_FRAME}


def configured_camera(settings: Settings) -> ServiceCamera | None:
    """The camera of ``settings.camera`` (None when unset), loaded and logged; raises
    ``sdcnet.calibration.CalibrationError`` with the reason."""
    if settings.camera is None:
        return None
    calibration = load_camera_file(settings.camera)
    K = calibration.intrinsics
    logger.info(
        "camera %s: %d x %d, %s px, %s%s",
        calibration.source,
        K.width,
        K.height,
        K.describe(decimals=2),
        calibration.model,
        f" {list(calibration.distortion)} (frames are undistorted)"
        if calibration.distortion
        else "",
    )
    return ServiceCamera(calibration)


def camera_frame(frame: Frame, camera: ServiceCamera | None) -> Frame:
    """``frame`` in the configured camera's pinhole frame: undistorted when the camera has
    distortion, ``frame.camera`` set to its intrinsics at the frame's size. Unchanged without
    a camera, and for a frame of another aspect ratio that gives fx, fy, cx and cy (another
    camera's); another aspect ratio without them is 422 ``camera_mismatch``."""
    if camera is None:
        return frame
    height, width = frame.gray.shape
    try:
        calibration = camera.calibration.at_size(width, height)
    except CalibrationError as exc:
        if frame.intrinsics.whole:
            return frame
        raise ApiError(
            422,
            "camera_mismatch",
            f"{exc}: send fx, fy, cx and cy with this frame, or serve with its camera's file "
            "(sdc-serve --camera)",
        ) from None
    if calibration.distortion:
        frame = undistorted(frame, camera.undistorter(calibration))
    return replace(frame, camera=calibration.intrinsics)


def undistorted(frame: Frame, undistorter: Undistorter) -> Frame:
    """The frame with its image undistorted and its returns moved along (the nearest wins a
    pixel two land on; those that land outside the frame are dropped); 422 ``no_returns``
    when none is left."""
    rows, cols = mask_pixels(frame.sparse > 0)
    new_rows, new_cols, kept = undistorter.returns(rows, cols)
    if not kept.any():
        raise ApiError(
            422,
            "no_returns",
            f"all {len(rows)} LIDAR returns fall outside the frame once the lens distortion is "
            "removed: returns are pixels of the image as the lens sees it",
        )
    z = frame.sparse[rows[kept], cols[kept]]
    sparse = scatter_nearest(new_rows, new_cols, z, frame.sparse.shape)
    return replace(frame, gray=undistorter.image(frame.gray), sparse=sparse)
