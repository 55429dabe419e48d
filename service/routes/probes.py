"""Liveness, readiness and Prometheus metrics: short names and the Open Inference Protocol v2
ones. Probes run on the event loop and never count against the in-flight limit."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import Response

from sdcnet.service.deps import MODEL_NAME, EngineDep
from sdcnet.service.errors import ERROR_RESPONSES, V2_ERROR_RESPONSES
from sdcnet.service.metrics import CONTENT_TYPE
from sdcnet.service.schemas import Liveness, Readiness

router = APIRouter(tags=["probes"])
_NOT_READY: dict[int | str, dict] = {503: ERROR_RESPONSES[503]}
_V2_NOT_READY: dict[int | str, dict] = {503: V2_ERROR_RESPONSES[503]}


@router.get("/health", response_model=Liveness)
@router.get("/v2/health/live", response_model=Liveness)
async def live() -> Liveness:
    """The process answers (liveness). Probes run on the event loop: never queued."""
    return Liveness(live=True)


@router.get("/ready", response_model=Readiness, responses=_NOT_READY)
@router.get("/v2/health/ready", response_model=Readiness, responses=_V2_NOT_READY)
@router.get(
    f"/v2/models/{MODEL_NAME}/ready",
    response_model=Readiness,
    responses=_V2_NOT_READY,
)
async def ready(engine: EngineDep) -> Readiness:
    """The model is loaded and requests are served (readiness); 503 otherwise."""
    return Readiness(ready=True)


@router.get(
    "/metrics",
    response_class=Response,
    responses={
        200: {
            "description": "Prometheus text exposition format 0.0.4",
            "content": {CONTENT_TYPE.split(";")[0]: {"schema": {"type": "string"}}},
        }
    },
)
async def metrics(request: Request) -> Response:
    """Prometheus text exposition."""
    return Response(request.app.state.metrics.render(), media_type=CONTENT_TYPE)
