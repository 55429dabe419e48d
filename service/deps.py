"""FastAPI dependencies the routers share: the settings, the loaded model, the targets, the
camera."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from sdcnet.service.camera import ServiceCamera
from sdcnet.service.decode import InputLimits
from sdcnet.service.errors import ApiError
from sdcnet.service.inference import Engine
from sdcnet.service.settings import Settings, get_settings
from sdcnet.targets import Target

MODEL_NAME = "sdcnet"


async def get_engine(request: Request) -> Engine:
    """FastAPI dependency: the loaded model, or 503 while there is none."""
    engine = request.app.state.engine
    if engine is None:
        settings: Settings = request.app.state.settings
        raise ApiError(
            503,
            "not_ready",
            "the model is not loaded (starting or stopping)",
            headers={"Retry-After": str(settings.retry_after_s)},
        )
    return engine


def input_limits(settings: Settings) -> InputLimits:
    """How large the inputs of a request may be, from the settings."""
    return InputLimits(settings.max_pixels, settings.max_returns)


async def get_targets(request: Request) -> dict[str, Target]:
    """FastAPI dependency: the known targets by name (``sdc-serve --targets``), maybe none."""
    return request.app.state.targets


async def get_camera(request: Request) -> ServiceCamera | None:
    """FastAPI dependency: the camera of ``sdc-serve --camera``, or None."""
    return request.app.state.camera


SettingsDep = Annotated[Settings, Depends(get_settings)]
TargetsDep = Annotated[dict[str, Target], Depends(get_targets)]
EngineDep = Annotated[Engine, Depends(get_engine)]
CameraDep = Annotated[ServiceCamera | None, Depends(get_camera)]
