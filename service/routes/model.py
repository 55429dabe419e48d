"""Model metadata: ``GET /model`` and the Open Inference Protocol's ``GET /v2/models/sdcnet``
(the tensors ``POST /v2/models/sdcnet/infer`` takes and answers) and ``GET /v2`` (the server)."""

from __future__ import annotations

from fastapi import APIRouter

from sdcnet import __version__
from sdcnet.service.deps import MODEL_NAME, CameraDep, EngineDep, SettingsDep, TargetsDep
from sdcnet.service.errors import ERROR_RESPONSES, V2_ERROR_RESPONSES
from sdcnet.service.schemas import (
    CameraInfo,
    CameraIntrinsics,
    FrameBudgetInfo,
    ModelMetadata,
    ServerMetadata,
    SizedIntrinsics,
    TargetInfo,
    TensorMetadata,
)
from sdcnet.service.v2_schemas import PROTOCOL_INPUTS, PROTOCOL_OUTPUTS

router = APIRouter(tags=["model"])

_DESCRIPTIONS = {
    "gray": "camera image, [H, W]; UINT16 is accepted too",
    "sparse": "LIDAR returns as a dense map: Z metres, 0 = no return (or give returns)",
    "returns": "LIDAR returns as a list: row, column (whole pixels), Z metres (or give sparse)",
    "depth": "camera-frame Z, metres, 0 outside the mask",
    "mask": "1 = spacecraft",
    "points": "the mask's pixels back-projected: camera frame (x right, y down, z forward), m",
    "normals": "each point's unit surface normal, camera frame, facing the camera",
    "sigma": "the depth's 1-sigma uncertainty, metres, 0 outside the mask",
}


def _tensors(specs: dict) -> list[TensorMetadata]:
    """Metadata of the protocol's tensors (``sdcnet.service.v2_schemas.PROTOCOL_INPUTS`` /
    ``PROTOCOL_OUTPUTS``)."""
    return [
        TensorMetadata(
            name=name,
            datatype=datatype if isinstance(datatype, str) else datatype[0],
            shape=list(shape),
            description=_DESCRIPTIONS[name],
        )
        for name, (datatype, shape) in specs.items()
    ]


@router.get("/v2", response_model=ServerMetadata)
async def server_metadata() -> ServerMetadata:
    """The server (Open Inference Protocol): name, version and protocol extensions."""
    return ServerMetadata(name="sdcnet", version=__version__, extensions=["binary_tensor_data"])


@router.get("/model", response_model=ModelMetadata, responses={503: ERROR_RESPONSES[503]})
@router.get(
    f"/v2/models/{MODEL_NAME}",
    response_model=ModelMetadata,
    responses={503: V2_ERROR_RESPONSES[503]},
)
async def model_metadata(
    engine: EngineDep, settings: SettingsDep, targets: TargetsDep, camera: CameraDep
) -> ModelMetadata:
    """What the service serves: the v2 inference tensors, the model's version, the camera
    and the default intrinsics, metrics, the limits, and the known targets of ``POST /pose``."""
    model = engine.model
    info = model.info
    K = info.intrinsics
    default = K if camera is None else camera.calibration.intrinsics
    return ModelMetadata(
        name=MODEL_NAME,
        versions=[info.version],
        platform=model.platform,
        inputs=_tensors(PROTOCOL_INPUTS),
        outputs=_tensors(PROTOCOL_OUTPUTS),
        version=info.version,
        provider=model.provider,
        threads=model.threads,
        stride=info.stride,
        work_pixels=engine.frame_budget.work_pixels,
        frame_budget=FrameBudgetInfo(**engine.frame_budget.describe()),
        intrinsics=CameraIntrinsics(**K.pinhole_dict()),
        default_intrinsics=SizedIntrinsics(**default.as_dict()),
        camera=None if camera is None else CameraInfo(**camera.describe()),
        metrics=info.metrics,
        limits={
            "max_pixels": settings.max_pixels,
            "max_returns": settings.max_returns,
            "max_upload_bytes": settings.max_upload_bytes,
            "max_points": settings.max_points,
            "max_in_flight": settings.max_in_flight,
            "max_requests": settings.max_requests,
        },
        targets=[TargetInfo(**target.describe()) for target in targets.values()],
    )
