"""The FastAPI application: ``POST /complete``, probes, model metadata, metrics.

``create_app(settings)`` builds it; its lifespan loads the model once (unless one is handed
in, as ``sdc-serve`` does to fail fast with a clear message). Inference runs in the threadpool,
never on the event loop. Endpoint names follow KServe's Open Inference Protocol v2 (beside the
short ones operators type) and Triton's metric names; every error has one JSON shape
(``sdcnet.service.errors``).
"""

from __future__ import annotations

import json
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Annotated, Any

from fastapi import APIRouter, Depends, FastAPI, File, Form, Query, Request, UploadFile
from fastapi.responses import Response
from pydantic import WithJsonSchema
from starlette.concurrency import run_in_threadpool

from sdcnet import __version__
from sdcnet.export.runtime import ModelLoadError, OnnxModel
from sdcnet.service.admission import Admission
from sdcnet.service.encode import MEDIA_TYPES
from sdcnet.service.errors import ERROR_RESPONSES, ApiError, install_error_handlers
from sdcnet.service.inference import CompletionRequest, Engine, answer, self_test
from sdcnet.service.metrics import CONTENT_TYPE, ServiceMetrics
from sdcnet.service.schemas import (
    CameraIntrinsics,
    CompletionResponse,
    Liveness,
    ModelMetadata,
    Readiness,
    ResponseFormat,
    TensorMetadata,
)
from sdcnet.service.settings import Settings, get_settings

logger = logging.getLogger("sdcnet.service")

MODEL_NAME = "sdcnet"
_DATATYPES = {"tensor(float)": "FP32", "tensor(float16)": "FP16", "tensor(double)": "FP64"}

DESCRIPTION = """
Dense depth of a spacecraft from a gray image and a very sparse LIDAR depth map (SDCNet).

`POST /complete` takes a multipart form (`gray` image, `sparse` depth map, optional
intrinsics) and answers a dense depth map, a foreground mask and a point cloud.

Every error, whatever its status, is `{"error": {"code": ..., "message": ...}}`
(validation errors add `details`, one per invalid field).
"""


def load_model(settings: Settings) -> OnnxModel:
    """The ONNX model the settings name, checked by one inference on a small frame; raises
    ``ModelLoadError`` with a clear message, so that a file that loads but cannot serve stops
    the start-up rather than failing every request."""
    if settings.model_path.is_dir():
        raise ModelLoadError(f"{settings.model_path} is a directory, not an ONNX model file")
    try:
        model = OnnxModel(settings.model_path, settings.provider, settings.threads)
    except (ValueError, TypeError, KeyError) as exc:  # sdcnet metadata that does not parse
        raise ModelLoadError(
            f"{settings.model_path} is not a usable sdcnet model: its metadata does not parse "
            f"({type(exc).__name__}: {exc})"
        ) from exc
    self_test(model)
    return model


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


async def strict_form(request: Request) -> None:
    """FastAPI dependency: 422 for a form field the endpoint does not take or one sent twice.

    FastAPI would silently ignore the first (a typo such as ``outlier_remova``) and keep only
    the last of the second (two ``gray`` files): both are a client's mistake worth naming.
    The form is the one FastAPI already parsed (Starlette caches it).
    """
    known = {field.alias for field in request.scope["route"].dependant.body_params}
    names = [name for name, _ in (await request.form()).multi_items()]
    unknown = sorted(set(names) - known)
    repeated = sorted({name for name in names if names.count(name) > 1} & known)
    problems = [f"unknown form field {name!r}" for name in unknown]
    problems += [f"form field {name!r} given {names.count(name)} times" for name in repeated]
    if problems:
        raise ApiError(
            422, "invalid_request", "; ".join(problems) + f"; the fields are {sorted(known)}"
        )


SettingsDep = Annotated[Settings, Depends(get_settings)]
EngineDep = Annotated[Engine, Depends(get_engine)]
router = APIRouter()
_NOT_READY: dict[int | str, dict] = {503: ERROR_RESPONSES[503]}


@router.get("/health", response_model=Liveness, tags=["probes"])
@router.get("/v2/health/live", response_model=Liveness, tags=["probes"])
async def live() -> Liveness:
    """The process answers (liveness). Probes run on the event loop: never queued."""
    return Liveness(live=True)


@router.get("/ready", response_model=Readiness, tags=["probes"], responses=_NOT_READY)
@router.get("/v2/health/ready", response_model=Readiness, tags=["probes"], responses=_NOT_READY)
@router.get(
    f"/v2/models/{MODEL_NAME}/ready",
    response_model=Readiness,
    tags=["probes"],
    responses=_NOT_READY,
)
async def ready(engine: EngineDep) -> Readiness:
    """The model is loaded and requests are served (readiness); 503 otherwise."""
    return Readiness(ready=True)


@router.get("/model", response_model=ModelMetadata, tags=["model"])
@router.get(f"/v2/models/{MODEL_NAME}", response_model=ModelMetadata, tags=["model"])
async def model_metadata(engine: EngineDep, settings: SettingsDep) -> ModelMetadata:
    """What the loaded model is: version, tensors, default intrinsics, metrics, limits."""
    model = engine.model
    info = model.info
    described = {
        **json.loads(info.raw.get("inputs", "{}")),
        **json.loads(info.raw.get("outputs", "{}")),
    }

    def tensors(args) -> list[TensorMetadata]:
        return [
            TensorMetadata(
                name=a.name,
                datatype=_DATATYPES.get(a.type, a.type),
                shape=[d if isinstance(d, int) else -1 for d in a.shape],
                description=described.get(a.name, ""),
            )
            for a in args
        ]

    K = info.intrinsics
    return ModelMetadata(
        name=MODEL_NAME,
        versions=[info.version],
        platform="onnxruntime_onnx",
        inputs=tensors(model.session.get_inputs()),
        outputs=tensors(model.session.get_outputs()),
        version=info.version,
        provider=model.provider,
        threads=model.threads,
        stride=info.stride,
        training_size=info.training_size,
        intrinsics=CameraIntrinsics(fx=K.fx, fy=K.fy, cx=K.cx, cy=K.cy),
        metrics=info.metrics,
        limits={
            "max_pixels": settings.max_pixels,
            "max_upload_bytes": settings.max_upload_bytes,
            "max_in_flight": settings.max_in_flight,
        },
    )


@router.get(
    "/metrics",
    tags=["probes"],
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


_JSON_SCHEMA_BOUNDS = {"gt": "exclusiveMinimum", "ge": "minimum", "le": "maximum"}


def optional_number(description: str, **bounds: float) -> Any:
    """The type of an optional, finite numeric form field within ``bounds`` (gt, ge, le).

    A form leaves such a field out, it cannot send null: the OpenAPI schema says a plain
    number with its bounds (not "number or null"), so that clients and fuzzers generated from
    the schema never send the string "null".
    """
    schema = {"type": "number", **{_JSON_SCHEMA_BOUNDS[k]: v for k, v in bounds.items()}}
    return Annotated[
        float | None,
        Form(allow_inf_nan=False, description=description, **bounds),
        WithJsonSchema(schema),
    ]


_DEFAULT_K = "default: the model's, scaled to the image size"
FocalLength = optional_number(f"pixels; {_DEFAULT_K}", gt=0)
PrincipalPoint = optional_number(f"pixels; {_DEFAULT_K}")
#: Metres per unit of a 16-bit PNG sparse map, bounded so that every depth stays finite and
#: non-zero in float32 (65535 units x 1000 m; 1 unit x 1 micrometre).
DepthScale = optional_number("metres per unit of a 16-bit PNG sparse", ge=1e-6, le=1e3)


@router.post(
    "/complete",
    response_model=CompletionResponse,
    tags=["inference"],
    responses={
        200: {
            "description": "format=json: this document; format=npz: a zip of depth.npy, "
            "mask.npy, points.npy and meta.json; format=ply: the point cloud as binary PLY",
            "content": {"application/octet-stream": {}},
            "headers": {
                "Server-Timing": {
                    "description": "milliseconds per phase: decode, queue, inference, encode",
                    "required": True,
                    "schema": {"type": "string"},
                }
            },
        },
        **ERROR_RESPONSES,
    },
    dependencies=[Depends(strict_form)],
)
async def complete(
    request: Request,
    engine: EngineDep,
    settings: SettingsDep,
    gray: Annotated[
        UploadFile,
        File(description="PNG, TIFF, JPEG or BMP; 8- or 16-bit; colour is converted to gray"),
    ],
    sparse: Annotated[
        UploadFile,
        File(
            description=".npy of float32/float64 metres (0 = no return), or a 16-bit PNG "
            "with depth_scale"
        ),
    ],
    depth_scale: DepthScale = None,
    fx: FocalLength = None,
    fy: FocalLength = None,
    cx: PrincipalPoint = None,
    cy: PrincipalPoint = None,
    outlier_removal: Annotated[
        bool, Form(description="statistical outlier removal on the point cloud (Fig. 7)")
    ] = False,
    response_format: Annotated[
        ResponseFormat, Query(alias="format", description="json, npz or ply")
    ] = ResponseFormat.json,
) -> Response:
    """Complete one frame: dense depth (metres, 0 off the mask), mask and point cloud.

    Intrinsics (pixels) not given are the model's, scaled to the image size.
    """
    req = CompletionRequest(
        gray=await gray.read(),
        sparse=await sparse.read(),
        depth_scale=depth_scale,
        fx=fx,
        fy=fy,
        cx=cx,
        cy=cy,
        outlier_removal=outlier_removal,
        format=response_format,
    )
    result = await run_in_threadpool(answer, engine, req, settings.max_pixels)
    request.app.state.metrics.observe_phases(result.timer.seconds)
    headers = {"Server-Timing": result.timer.server_timing()}
    if response_format is not ResponseFormat.json:
        name = f"sdcnet.{response_format.value}"
        headers["Content-Disposition"] = f'attachment; filename="{name}"'
    return Response(result.body, media_type=MEDIA_TYPES[response_format], headers=headers)


def close_form_schemas(app: FastAPI) -> None:
    """Make the OpenAPI schema of every multipart body say ``additionalProperties: false``, as
    ``strict_form`` enforces (FastAPI leaves them open), so that clients and fuzzers generated
    from the schema know an unknown field is refused."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = generate()  # FastAPI keeps it in app.openapi_schema
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


def create_app(settings: Settings | None = None, model: OnnxModel | None = None) -> FastAPI:
    """The service. ``settings`` default to the environment; ``model`` (already loaded)
    defaults to loading ``settings.model_path`` at start-up."""
    settings = settings or Settings()
    service_metrics = ServiceMetrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        loaded = model or load_model(settings)
        service_metrics.model.info(
            {
                "version": loaded.info.version,
                "provider": loaded.provider,
                "threads": str(loaded.threads),
            }
        )
        logger.info(
            "model %s from %s on %s, %d intra-op threads; at most %d requests in flight",
            loaded.info.version,
            loaded.path,
            loaded.provider,
            loaded.threads,
            settings.max_in_flight,
        )
        app.state.engine = Engine(loaded)
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
    install_error_handlers(app)
    app.add_middleware(
        Admission,
        metrics=service_metrics,
        max_in_flight=settings.max_in_flight,
        max_upload_bytes=settings.max_upload_bytes,
        retry_after_s=settings.retry_after_s,
        body_timeout_s=settings.body_timeout_s,
    )
    app.include_router(router)
    close_form_schemas(app)
    return app
