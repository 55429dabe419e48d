"""The multipart form of one frame that ``POST /complete`` and ``POST /pose`` take (``gray``,
``sparse`` or ``returns``, ``depth_scale``, the intrinsics, ``outlier_removal``,
``max_sigma``): ``FrameForm``, the FastAPI dependency that reads it, and ``strict_form``,
which refuses a field the endpoint does not take."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import Depends, File, Form, Request, UploadFile
from fastapi.dependencies.models import Dependant
from pydantic import WithJsonSchema

from sdcnet.camera import MAX_FIELD_OF_VIEW_DEG, MAX_FOCAL_PX, GivenIntrinsics
from sdcnet.formats.sparse import described
from sdcnet.service.decode import CompletionRequest
from sdcnet.service.errors import ApiError


def _form_fields(dependant: Dependant) -> set[str]:
    """Names of the form fields an endpoint takes, its dependencies' included."""
    own = {field.alias for field in dependant.body_params}
    return own.union(*(_form_fields(sub) for sub in dependant.dependencies))


async def strict_form(request: Request) -> None:
    """FastAPI dependency: 422 for a form field the endpoint does not take or one sent twice.

    FastAPI would silently ignore the first (a typo such as ``outlier_remova``) and keep only
    the last of the second (two ``gray`` files): both are a client's mistake worth naming.
    The form is the one FastAPI already parsed (Starlette caches it).
    """
    known = _form_fields(request.scope["route"].dependant)
    names = [name for name, _ in (await request.form()).multi_items()]
    unknown = sorted(set(names) - known)
    repeated = sorted({name for name in names if names.count(name) > 1} & known)
    problems = [f"unknown form field {name!r}" for name in unknown]
    problems += [f"form field {name!r} given {names.count(name)} times" for name in repeated]
    if problems:
        raise ApiError(
            422, "invalid_request", "; ".join(problems) + f"; the fields are {sorted(known)}"
        )


_JSON_SCHEMA_BOUNDS = {"gt": "exclusiveMinimum", "ge": "minimum", "le": "maximum"}


def optional_number(
    description: str, documented: dict[str, float] | None = None, **bounds: float
) -> Any:
    """The type of an optional, finite numeric form field within ``bounds`` (gt, ge, le);
    ``documented``: bounds the schema states that a later check enforces.

    A form leaves such a field out, it cannot send null: the OpenAPI schema says a plain
    number with its bounds (not "number or null"), so that clients and fuzzers generated from
    the schema never send the string "null".
    """
    stated = {**(documented or {}), **bounds}
    schema = {"type": "number", **{_JSON_SCHEMA_BOUNDS[k]: v for k, v in stated.items()}}
    return Annotated[
        float | None,
        Form(allow_inf_nan=False, description=description, **bounds),
        WithJsonSchema(schema),
    ]


def optional_file(description: str) -> Any:
    """The type of an optional file field: the OpenAPI schema says a file (not "file or
    null": a form cannot send null), as ``optional_number`` does for numbers."""
    return Annotated[
        UploadFile | None,
        File(description=description),
        WithJsonSchema({"type": "string", "format": "binary", "description": description}),
    ]


_DEFAULT_K = "default: the camera's (sdc-serve --camera), else the model's; scaled to the image"
#: Intrinsics are checked once the image's size is known, alike on every route
#: (``sdcnet.camera.check_intrinsics``: 422 invalid_intrinsics); the schema states the part of
#: it that does not depend on the size.
FocalLength = optional_number(
    f"pixels, of a field of view under {MAX_FIELD_OF_VIEW_DEG:g} degrees; {_DEFAULT_K}",
    documented={"gt": 0, "le": MAX_FOCAL_PX},
)
PrincipalPoint = optional_number(f"pixels, within half an image of the image; {_DEFAULT_K}")
#: Metres per unit of a 16-bit PNG sparse map, bounded so that every depth stays finite and
#: non-zero in float32 (65535 units x 1000 m; 1 unit x 1 micrometre).
DepthScale = optional_number("metres per unit of a 16-bit PNG sparse", ge=1e-6, le=1e3)
#: Checked by ``sdcnet.service.decode.check_max_sigma`` (422 invalid_max_sigma), alike on
#: every route.
MaxSigma = optional_number(
    "metres: points whose depth's 1-sigma uncertainty is above it are left out of the point "
    "cloud (counted as uncertain_removed); depth, mask and sigma stay whole",
    documented={"gt": 0},
)
GrayFile = Annotated[
    UploadFile,
    File(description="PNG, TIFF, JPEG or BMP; 8- or 16-bit; colour is converted to gray"),
]
SparseFile = optional_file(
    f"the LIDAR returns as a dense map (H x W, 0 = no return): {described('map')}. Send "
    "this or returns"
)
ReturnsFile = optional_file(
    "the LIDAR returns as a list, one per row: row, column (whole pixel indices) and Z "
    f"(metres > 0); {described('list')}. Where several fall on one pixel the nearest wins. "
    "Send this or sparse"
)


async def frame_form(
    gray: GrayFile,
    sparse: SparseFile = None,
    returns: ReturnsFile = None,
    depth_scale: DepthScale = None,
    fx: FocalLength = None,
    fy: FocalLength = None,
    cx: PrincipalPoint = None,
    cy: PrincipalPoint = None,
    outlier_removal: Annotated[
        bool, Form(description="statistical outlier removal on the point cloud (Fig. 7)")
    ] = False,
    max_sigma: MaxSigma = None,
) -> CompletionRequest:
    """FastAPI dependency: one frame's form fields (``POST /complete`` and ``POST /pose``),
    the uploaded files read, as ``decode_form`` takes them."""
    return CompletionRequest(
        gray=await gray.read(),
        sparse=None if sparse is None else await sparse.read(),
        returns=None if returns is None else await returns.read(),
        depth_scale=depth_scale,
        intrinsics=GivenIntrinsics(fx, fy, cx, cy),
        outlier_removal=outlier_removal,
        max_sigma=max_sigma,
    )


FrameForm = Annotated[CompletionRequest, Depends(frame_form)]
