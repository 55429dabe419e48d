"""Response bodies of ``POST /pose`` (pydantic)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

from sdcnet.registration import REASONS
from sdcnet.service.schemas import FrameSummary, FrameTimings


class PoseValue(BaseModel):
    """p_camera = R p_target + t; camera frame x right, y down, z forward (metres). Send it
    back as ``init`` to track."""

    R: list[list[float]] = Field(description="3 x 3 rotation, target frame -> camera frame")
    t: list[float] = Field(description="3 numbers, metres: the target frame's origin in the camera")
    quaternion_wxyz: list[float] = Field(description="the rotation R as (w, x, y, z), w >= 0")


class PoseAlternative(BaseModel):
    """Another pose that explains the frame about as well (a symmetric target)."""

    pose: PoseValue
    consistency: float = Field(description="0..1, as the answer's")
    returns_error_m: float | None = Field(
        description="mean distance of the LIDAR returns to the target at this pose, truncated"
    )


class PoseTimings(FrameTimings):
    """Server-side time per phase, milliseconds: the frame's completion, then the pose's."""

    cloud_ms: float = Field(description="back-projection of the completed depth and the returns")
    registration_ms: float = Field(description="the pose from the clouds, all of it")
    search_ms: float = Field(description="of which the global search (0 when tracking held)")
    registration_cpu_ms: float = Field(
        description="CPU time of the registration's thread (its cost on a busy machine)"
    )


class PoseResponse(BaseModel):
    """``POST /pose``: the target's pose in the camera frame and how sure it is."""

    target: str
    pose: PoseValue
    tracked: bool = Field(
        description="refined from `init` and still in its basin (false: found from scratch, "
        "or the answer left `init`: see `reasons`)"
    )
    verdict: Literal["reliable", "ambiguous", "unreliable"] = Field(
        description="reliable: use the pose as it is; ambiguous: plausible, but another pose "
        "competes (see `alternatives`, `reasons`); unreliable: the frame does not support it"
    )
    reasons: list[str] = Field(
        description="why the answer is not reliable (empty when it is): "
        + "; ".join(
            f"{code} ({'unreliable' if unreliable else 'ambiguous'}): {meaning}"
            for code, (unreliable, meaning) in REASONS.items()
        )
    )
    fitness: float = Field(
        description="share of the completed cloud within the inlier distance of the target"
    )
    rmse_m: float | None = Field(
        description="RMS distance of those inliers to the target, metres; null: no inlier"
    )
    returns_rmse_m: float | None = Field(
        description="RMS distance of the LIDAR returns to the target (inliers), metres"
    )
    consistency: float = Field(
        description="0..1: share of the view, where the target at this pose or the cloud shows "
        "a surface, where both do at the same depth"
    )
    converged: bool = Field(description="the last GICP refinement met its criteria")
    covariance: list[list[float]] | None = Field(
        description="6 x 6 from the registration's Hessian: rotation vector (rad, camera "
        "frame, R -> exp(w) R), then t (metres); null when singular"
    )
    rotation_sigma_deg: float | None = Field(description="rotation std along its worst axis")
    translation_sigma_m: float | None = Field(description="t std along its worst axis")
    ambiguous: bool = Field(
        description="other poses explain the frame about as well (symmetric target): see "
        "`alternatives` (the reason symmetric_twins)"
    )
    alternatives: list[PoseAlternative]
    hypotheses: int = Field(description="poses refined to reach this answer")
    sigma_limit_m: float | None = Field(
        description="the completed points registered are those of sigma up to this, metres: "
        "the request's max_sigma, else the frame's 90th percentile of sigma; null: no point"
    )
    completion: FrameSummary = Field(description="the completed frame the pose comes from")
    timings: PoseTimings


class TargetGeometry(BaseModel):
    """``GET /targets/{name}``: what a client needs to draw the target at a pose."""

    name: str
    longest_m: float
    points: list[list[float]] = Field(
        description="N x 3 samples of its surface, target frame, metres (for drawing)"
    )
