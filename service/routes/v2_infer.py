"""``POST /v2/models/sdcnet/infer``: the Open Inference Protocol v2 with the binary tensor data
extension (``sdcnet.service.v2``), so that ``tritonclient.http`` and KServe clients work as
they are.

The body is read whole and parsed here, not by FastAPI: its binary part is sliced into arrays
without a copy, and its JSON header is validated by ``sdcnet.service.v2_schemas``'s
``InferenceRequest`` (whose schema the OpenAPI document shows), as FastAPI's docs do for a
custom body.
"""

from __future__ import annotations

from fastapi import APIRouter, Request
from starlette.concurrency import run_in_threadpool

from sdcnet.formats.v2 import HEADER_LENGTH
from sdcnet.service import v2
from sdcnet.service.admission import TAKES_SLOT
from sdcnet.service.deps import MODEL_NAME, CameraDep, EngineDep, SettingsDep, input_limits
from sdcnet.service.errors import V2_ERROR_RESPONSES, ApiError
from sdcnet.service.inference import SERVER_TIMING_HEADER
from sdcnet.service.spool import SpooledResponse
from sdcnet.service.v2_schemas import InferenceRequest, InferenceResponse

router = APIRouter(tags=["open inference protocol v2"])

_BINARY_BODY = (
    "the JSON header (this schema), then the raw little-endian bytes of every input that "
    f"gives binary_data_size, in the order of inputs; the {HEADER_LENGTH} "
    "header gives the JSON header's length in bytes"
)
_REQUEST_SCHEMA = InferenceRequest.model_json_schema(ref_template="#/components/schemas/{model}")
#: The request's schema and the models it uses, for the OpenAPI document's components (their
#: references point there); ``sdcnet.service.app`` adds them.
OPENAPI_SCHEMAS = {"InferenceRequest": _REQUEST_SCHEMA, **_REQUEST_SCHEMA.pop("$defs", {})}
_REQUEST_BODY = {
    "required": True,
    "content": {
        "application/json": {"schema": {"$ref": "#/components/schemas/InferenceRequest"}},
        "application/octet-stream": {
            "schema": {"type": "string", "format": "binary", "description": _BINARY_BODY}
        },
    },
}
_HEADER_LENGTH_DOC = {
    HEADER_LENGTH: {
        "description": "length of the JSON header in bytes, when binary data follows it",
        "schema": {"type": "integer", "minimum": 1},
    }
}


@router.post(
    f"/v2/models/{MODEL_NAME}/infer",
    response_model=InferenceResponse,
    responses={
        200: {
            "description": "the JSON header (this schema) alone, or followed by the binary "
            "data of the outputs sent as binary (application/octet-stream)",
            "content": {"application/octet-stream": {}},
            "headers": {**SERVER_TIMING_HEADER, **_HEADER_LENGTH_DOC},
        },
        **V2_ERROR_RESPONSES,
    },
    openapi_extra={"requestBody": _REQUEST_BODY},
    dependencies=[TAKES_SLOT],
)
async def infer(
    request: Request, engine: EngineDep, settings: SettingsDep, camera: CameraDep
) -> SpooledResponse:
    """Complete one frame. Inputs: `gray` (UINT8 or UINT16, [H, W]) and `sparse` (FP32,
    [H, W], metres, 0 = no return) or `returns` (FP32, [N, 3]: row, column, Z metres).
    Parameters: `fx`, `fy`, `cx`, `cy` (pixels; default: the camera's, else the model's),
    `outlier_removal`, `max_sigma` (metres: points of a larger sigma leave the cloud). Outputs:
    `depth` (FP32, [H, W], metres, 0 off the mask), `mask` (UINT8, [H, W]), `points` (FP32,
    [N, 3], camera frame, metres), `sigma` (FP32, [H, W], the depth's 1-sigma uncertainty,
    metres, 0 off the mask); the summary of `POST /complete` is in the answer's parameters.
    Errors: `{"error": "..."}`, the code in `Sdcnet-Error-Code`.
    """
    encoding = request.headers.get("content-encoding", "identity").lower()
    if encoding != "identity":
        raise ApiError(
            415,
            "unsupported_media_type",
            f"Content-Encoding {encoding} is not supported: send the body uncompressed",
        )
    body = bytearray()  # grown in place: Request.body() holds the chunks and their join
    async for chunk in request.stream():
        body += chunk
    header_length = request.headers.get(HEADER_LENGTH)
    answer = await run_in_threadpool(
        v2.answer, engine, body, header_length, input_limits(settings), camera
    )
    request.app.state.metrics.observe_phases(answer.timer.seconds)
    return answer.response()
