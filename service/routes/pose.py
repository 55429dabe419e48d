"""``POST /pose``: the form of ``POST /complete`` plus a known target's name (and, to track,
the previous answer's pose); the target's 6-DoF pose in the camera frame out."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, Form, Request
from starlette.concurrency import run_in_threadpool

from sdcnet.service.admission import TAKES_SLOT
from sdcnet.service.deps import CameraDep, EngineDep, SettingsDep, TargetsDep, input_limits
from sdcnet.service.errors import ERROR_RESPONSES
from sdcnet.service.forms import FrameForm, strict_form
from sdcnet.service.inference import SERVER_TIMING_HEADER
from sdcnet.service.pose import POSE_PHASES, PoseRequest, answer_pose, find_target
from sdcnet.service.pose_schemas import PoseResponse, TargetGeometry
from sdcnet.service.schemas import ErrorBody
from sdcnet.service.spool import SpooledResponse

router = APIRouter(tags=["pose"])
POSE_ERRORS: dict[int | str, dict] = {
    **ERROR_RESPONSES,
    404: {"model": ErrorBody, "description": "unknown_target: no target of that name here"},
    422: {
        **ERROR_RESPONSES[422],
        "description": ERROR_RESPONSES[422]["description"] + "; invalid_init (init is not a "
        "pose), too_few_points / too_large (the completed cloud is too small, or spans far "
        "more than the target, to register)",
    },
}


@router.post(
    "/pose",
    response_model=PoseResponse,
    responses={
        200: {
            "headers": {
                "Server-Timing": {
                    **SERVER_TIMING_HEADER["Server-Timing"],
                    "description": "milliseconds per phase: "
                    + ", ".join(POSE_PHASES)
                    + ", and wait (for an in-flight place, before decode)",
                }
            },
        },
        **POSE_ERRORS,
    },
    dependencies=[TAKES_SLOT, Depends(strict_form)],
)
async def pose(
    request: Request,
    engine: EngineDep,
    settings: SettingsDep,
    targets: TargetsDep,
    camera: CameraDep,
    frame: FrameForm,
    target: Annotated[str, Form(description="a known target's name (GET /model lists them)")],
    init: Annotated[
        str | None,
        Form(
            description='to track: a previous answer\'s `pose` as JSON, {"R": 3 x 3, "t": '
            '3} or {"quaternion_wxyz": 4, "t": 3}; without it the pose is found from scratch'
        ),
    ] = None,
) -> SpooledResponse:
    """The pose of a known target, p_camera = R p_target + t (camera x right, y down,
    z forward; metres), from one frame: completed as by `POST /complete`, then registered.

    Without `init` the pose is searched from scratch; with it, refined from it (tracking at
    the LIDAR's 10 Hz), falling back to the search when the refinement explains the frame
    poorly; the answer stays near `init` unless the frame clearly contradicts it. Every
    answer carries a `verdict` (reliable, ambiguous, unreliable) and its `reasons`; a
    symmetric target's answer says `ambiguous` and lists the alternatives.
    """
    req = PoseRequest(frame=frame, target=target, init=init)
    answer = await run_in_threadpool(
        answer_pose, engine, targets, req, input_limits(settings), camera
    )
    request.app.state.metrics.observe_phases(answer.timer.seconds)
    return answer.response()


#: Surface samples ``GET /targets/{name}`` sends, at most: enough to draw the target, ~100 kB.
DRAWING_POINTS = 4000


@router.get(
    "/targets/{name}",
    response_model=TargetGeometry,
    responses={404: POSE_ERRORS[404]},
)
async def target_geometry(name: str, targets: TargetsDep) -> TargetGeometry:
    """Samples of a known target's surface in its frame (metres), to draw it at a pose."""
    target = find_target(targets, name)
    points = target.model.render_points
    step = -(-len(points) // DRAWING_POINTS)  # at most DRAWING_POINTS of them
    return TargetGeometry(
        name=target.name,
        longest_m=target.longest_m,
        points=np.round(points[::step], 4).tolist(),
    )
