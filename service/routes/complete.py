"""``POST /complete``: a multipart form in, dense depth, mask and point cloud out."""

from __future__ import annotations

from dataclasses import replace
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request
from starlette.concurrency import run_in_threadpool

from sdcnet.service.admission import TAKES_SLOT
from sdcnet.service.deps import CameraDep, EngineDep, SettingsDep, input_limits
from sdcnet.service.errors import ERROR_RESPONSES
from sdcnet.service.forms import FrameForm, strict_form
from sdcnet.service.inference import SERVER_TIMING_HEADER, answer
from sdcnet.service.schemas import CompletionResponse, ResponseFormat
from sdcnet.service.spool import SpooledResponse

router = APIRouter(tags=["inference"])


@router.post(
    "/complete",
    response_model=CompletionResponse,
    responses={
        200: {
            "description": "format=json: this document; format=npz: a zip of depth.npy, "
            "mask.npy, points.npy, sigma.npy and meta.json; format=ply: the point cloud as "
            "binary PLY, each vertex x, y, z and sigma (float32, metres)",
            "content": {"application/octet-stream": {}},
            "headers": SERVER_TIMING_HEADER,
        },
        **ERROR_RESPONSES,
    },
    dependencies=[TAKES_SLOT, Depends(strict_form)],
)
async def complete(
    request: Request,
    engine: EngineDep,
    settings: SettingsDep,
    camera: CameraDep,
    frame: FrameForm,
    response_format: Annotated[
        ResponseFormat, Query(alias="format", description="json, npz or ply")
    ] = ResponseFormat.json,
) -> SpooledResponse:
    """Complete one frame: dense depth (metres, 0 off the mask), its 1-sigma uncertainty
    `sigma` (metres, 0 off the mask), mask and point cloud (without the points whose sigma is
    above `max_sigma`, when given).

    The LIDAR returns come as a dense map (`sparse`) or as a list (`returns`: a few hundred
    returns in a few kilobytes instead of a 4 MiB map for a 1024 x 1024 frame; the answers
    are identical). Intrinsics (pixels) not given are the camera's (`sdc-serve --camera`; the
    frame is then undistorted if it has lens distortion), else the model's, scaled to the
    image size.
    """
    req = replace(frame, format=response_format)
    result = await run_in_threadpool(answer, engine, req, input_limits(settings), camera)
    request.app.state.metrics.observe_phases(result.timer.seconds)
    return result.response()
