"""One JSON error shape for every failure: ``{"error": {"code", "message", "details"?}}``;
under ``/v2/`` the Open Inference Protocol's: ``{"error": "message"}``.

``ApiError`` is raised by our code with a stable ``code``; FastAPI's own validation errors,
Starlette's 404/405 and anything unexpected are turned into the same shape. Each handler
records the code in the request state, where the admission middleware reads it for the
failure counter. On the v2 routes the code travels in the ``Sdcnet-Error-Code`` header, since
the protocol's body has room for a message only (tritonclient reads ``error`` alone).
"""

from __future__ import annotations

from collections.abc import Mapping

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

from sdcnet.formats import FormatError
from sdcnet.service.schemas import ErrorBody, ErrorDetail, ErrorInfo, V2ErrorBody

#: Paths under this prefix are the Open Inference Protocol's: its error shape.
V2_PREFIX = "/v2/"
#: The stable error code of a v2 error answer.
CODE_HEADER = "Sdcnet-Error-Code"

#: Codes for HTTP errors raised by the framework rather than by us.
_STATUS_CODES = {
    400: "bad_request",
    404: "not_found",
    405: "method_not_allowed",
    408: "request_timeout",
    413: "too_large",
    415: "unsupported_media_type",
}
#: Status of each code of ``sdcnet.formats.FormatError``.
_FORMAT_STATUS = {
    "unsupported_media_type": 415,
    "unreadable_file": 400,
    "pickle_not_allowed": 400,
    "wrong_dtype": 422,
    "wrong_shape": 422,
    "invalid_request": 422,
}
_LOCATIONS = {"body": "form", "query": "query", "path": "path", "header": "header"}
_LOCATION_NAMES = {"form": "form field", "query": "query parameter", "path": "path parameter"}


class ApiError(HTTPException):
    """An answer other than 2xx, with a stable machine-readable ``code``.

    A Starlette ``HTTPException`` so that FastAPI passes it through untouched even when it is
    raised while the request body is being read.
    """

    def __init__(
        self,
        status: int,
        code: str,
        message: str,
        headers: Mapping[str, str] | None = None,
    ):
        super().__init__(status_code=status, detail=message, headers=dict(headers or {}))
        self.code = code
        self.message = message


def format_error(exc: FormatError, field: str | None = None) -> ApiError:
    """The answer to bytes that are not their format (4xx, the error's code); its message
    starts with ``field`` when given."""
    message = str(exc) if field is None else f"{field}: {exc}"
    return ApiError(_FORMAT_STATUS[exc.code], exc.code, message)


def error_response(
    status: int,
    code: str,
    message: str,
    headers: Mapping[str, str] | None = None,
    details: list[ErrorDetail] | None = None,
    v2: bool = False,
) -> JSONResponse:
    """The JSON answer for an error; ``v2``: the Open Inference Protocol's shape."""
    if v2:
        headers = {**(headers or {}), CODE_HEADER: code}
        return JSONResponse(V2ErrorBody(error=message).model_dump(), status, headers=headers)
    body = ErrorBody(error=ErrorInfo(code=code, message=message, details=details))
    return JSONResponse(body.model_dump(exclude_none=True), status, headers=headers)


def route_path(scope: Mapping) -> str:
    """The request's path within the application (its root path left out)."""
    return scope["path"].removeprefix(scope.get("root_path", ""))


def is_v2(scope: Mapping) -> bool:
    """Whether the request is for an Open Inference Protocol route, whose errors take that
    protocol's shape."""
    return route_path(scope).startswith(V2_PREFIX)


def _answer(request: Request, status: int, code: str, message: str, **kwargs) -> JSONResponse:
    request.state.error_code = code
    return error_response(status, code, message, v2=is_v2(request.scope), **kwargs)


async def _api_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ApiError)
    return _answer(request, exc.status_code, exc.code, exc.message, headers=exc.headers)


async def _http_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, HTTPException)
    code = _STATUS_CODES.get(exc.status_code, f"http_{exc.status_code}")
    message = {
        404: f"no endpoint {request.url.path}; the API is listed at /docs",
        405: f"{request.method} is not allowed on {request.url.path}",
    }.get(exc.status_code, str(exc.detail))
    return _answer(request, exc.status_code, code, message, headers=exc.headers)


def _detail(error: dict) -> ErrorDetail:
    where, *path = (str(part) for part in error.get("loc", ("request",)))
    return ErrorDetail(
        location=_LOCATIONS.get(where, where), field=".".join(path), message=error["msg"]
    )


async def _validation_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    details = [_detail(error) for error in exc.errors()]
    message = "; ".join(
        f"{_LOCATION_NAMES.get(d.location, d.location)} '{d.field}': {d.message}"
        if d.field
        else f"{d.location}: {d.message}"
        for d in details
    )
    return _answer(request, 422, "invalid_request", message, details=details)


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    # Starlette re-raises the exception after this answer, and uvicorn logs its traceback.
    return _answer(request, 500, "internal_error", "internal error; the server log has details")


def install_error_handlers(app: FastAPI) -> None:
    """Route every error of ``app`` through the one JSON shape."""
    app.add_exception_handler(ApiError, _api_error)
    app.add_exception_handler(HTTPException, _http_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(Exception, _unexpected)


RETRY_AFTER_HEADER = {
    "Retry-After": {
        "description": "seconds to wait before retrying",
        "required": True,
        "schema": {"type": "integer", "minimum": 0},
    }
}

#: For route declarations: the error answers /docs lists.
ERROR_RESPONSES: dict[int | str, dict] = {
    status: {"model": ErrorBody, "description": description}
    for status, description in {
        400: "unreadable file, pickled .npy or malformed body",
        408: "the request body stalled (less data than its Content-Length)",
        413: "image above the pixel limit or body above the byte limit",
        415: "file type not accepted",
        422: "invalid, unknown or repeated field: dtype, shape, depth values, missing field, "
        "unknown format, a frame that does not fit the camera",
        503: "overloaded or not ready; Retry-After says when to retry",
    }.items()
}
ERROR_RESPONSES[503]["headers"] = RETRY_AFTER_HEADER

_CODE_HEADER_DOC = {
    CODE_HEADER: {
        "description": "stable, machine-readable reason, e.g. 'no_returns'",
        "required": True,
        "schema": {"type": "string"},
    }
}

#: For the v2 routes' declarations: the same answers in the protocol's shape.
V2_ERROR_RESPONSES: dict[int | str, dict] = {
    status: {
        "model": V2ErrorBody,
        "description": response["description"],
        "headers": {**response.get("headers", {}), **_CODE_HEADER_DOC},
    }
    for status, response in ERROR_RESPONSES.items()
}
