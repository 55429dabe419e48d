"""The FastAPI application: ``POST /complete``, probes, model metadata, metrics.

``create_app(settings)`` builds it; its lifespan loads the model once (unless one is handed
in, as ``sdc-serve`` does to fail fast with a clear message). Inference runs in the threadpool,
never on the event loop. Endpoint names follow KServe's Open Inference Protocol v2 (beside the
short ones operators type) and Triton's metric names; every error has one JSON shape
(``sdcnet.service.errors``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI

from sdcnet import __version__
from sdcnet.frame_budget import FrameBudget
from sdcnet.runtime.interface import ModelLoadError, Runtime
from sdcnet.runtime.registry import load_runtime
from sdcnet.service.admission import Admission
from sdcnet.service.camera import ServiceCamera, configured_camera
from sdcnet.service.errors import install_error_handlers
from sdcnet.service.inference import (
    SELF_TEST_SIZE,
    Engine,
    choose_frame_budget,
    self_test,
    warm_up,
)
from sdcnet.service.metrics import ServiceMetrics
from sdcnet.service.pose import configured_targets
from sdcnet.service.routes import ROUTERS, v2_infer
from sdcnet.service.settings import Settings
from sdcnet.targets import Target

logger = logging.getLogger("sdcnet.service")


DESCRIPTION = """
Dense depth of a spacecraft from a gray image and a very sparse LIDAR depth map (SDCNet).

`POST /complete` takes a multipart form (`gray` image, `sparse` depth map, optional
intrinsics) and answers a dense depth map, a foreground mask and a point cloud. `POST /pose`
takes the same form plus a known target's name and answers its 6-DoF pose.

Every error, whatever its status, is `{"error": {"code": ..., "message": ...}}`
(validation errors add `details`, one per invalid field).
"""


def load_model(settings: Settings) -> Runtime:
    """The model the settings name under the runtime they choose, checked by one inference on
    a small frame, then warmed up on the largest frame the settings accept; raises
    ``ModelLoadError`` with a clear message, so that a file that loads but cannot serve stops
    the start-up rather than failing every request."""
    if settings.model_path.is_dir():
        raise ModelLoadError(f"{settings.model_path} is a directory, not an ONNX model file")
    model = load_runtime(
        settings.runtime,
        settings.model_path,
        settings.provider,
        settings.threads,
        settings.spin_wait,
    )
    self_test(model)
    warm_up(model, max(SELF_TEST_SIZE, math.isqrt(settings.max_pixels)), settings.max_points)
    return model


def complete_openapi(app: FastAPI) -> None:
    """Two things FastAPI's OpenAPI document lacks: the schema of every multipart body says
    ``additionalProperties: false``, as ``strict_form`` enforces (FastAPI leaves them open), so
    that clients and fuzzers generated from the schema know an unknown field is refused; and
    the components of the v2 inference request, whose body the route parses itself."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = generate()  # FastAPI keeps it in app.openapi_schema
            schema["components"]["schemas"].update(v2_infer.OPENAPI_SCHEMAS)
            for operations in schema["paths"].values():
                for operation in operations.values():
                    body = operation.get("requestBody", {}).get("content", {})
                    ref = body.get("multipart/form-data", {}).get("schema", {}).get("$ref")
                    if ref:
                        schema["components"]["schemas"][ref.rsplit("/", 1)[1]].update(
                            additionalProperties=False
                        )
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def create_app(
    settings: Settings | None = None,
    model: Runtime | None = None,
    targets: dict[str, Target] | None = None,
    camera: ServiceCamera | None = None,
    frame_budget: FrameBudget | None = None,
) -> FastAPI:
    """The service. ``settings`` default to the environment; ``model`` (already loaded)
    defaults to loading ``settings.model_path`` at start-up, ``targets`` (already prepared)
    to preparing those of ``settings.targets``, ``camera`` (already loaded) to loading
    ``settings.camera``, ``frame_budget`` (already chosen) to choosing it by the settings
    (``choose_frame_budget``)."""
    settings = settings or Settings()
    service_metrics = ServiceMetrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        loaded = model or load_model(settings)
        logger.info(
            "model %s from %s on %s, %d intra-op threads; at most %d requests in flight",
            loaded.info.version,
            loaded.path,
            loaded.provider,
            loaded.threads,
            settings.max_in_flight,
        )
        app.state.targets = configured_targets(settings) if targets is None else targets
        app.state.camera = configured_camera(settings) if camera is None else camera
        chosen = frame_budget or choose_frame_budget(
            loaded, settings.work_pixels, settings.frame_ms
        )
        logger.info(
            "frames get %d working pixels at most (the model's %d) and %.2f of their budget "
            "(reference frame %s ms, p95 expected %s ms, --frame-ms %g)",
            chosen.work_pixels,
            chosen.model_work_pixels,
            chosen.frame_share,
            chosen.reference_ms,
            chosen.expected_p95_ms,
            chosen.deadline_ms,
        )
        service_metrics.model.info(
            {
                "version": loaded.info.version,
                "provider": loaded.provider,
                "threads": str(loaded.threads),
                "work_pixels": str(chosen.work_pixels),
            }
        )
        engine = Engine(loaded, settings.max_points, chosen, settings.budget_window)
        service_metrics.frame_share.set_function(lambda: engine.frame_budget.frame_share)
        app.state.engine = engine
        yield
        app.state.engine = None  # not ready while shutting down

    app = FastAPI(
        title="sdcnet",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.metrics = service_metrics
    app.state.engine = None
    app.state.targets = {}
    app.state.camera = None
    install_error_handlers(app)
    app.add_middleware(Admission, metrics=service_metrics, settings=settings, routers=ROUTERS)
    for router in ROUTERS:
        app.include_router(router)
    complete_openapi(app)
    return app
