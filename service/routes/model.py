"""Model metadata: ``GET /model`` and the Open Inference Protocol's ``GET /v2/models/sdcnet``."""

from __future__ import annotations

import json

from fastapi import APIRouter

from sdcnet.service.deps import MODEL_NAME, EngineDep, SettingsDep, TargetsDep
from sdcnet.service.schemas import CameraIntrinsics, ModelMetadata, TargetInfo, TensorMetadata

router = APIRouter(tags=["model"])
_DATATYPES = {"tensor(float)": "FP32", "tensor(float16)": "FP16", "tensor(double)": "FP64"}


@router.get("/model", response_model=ModelMetadata)
@router.get(f"/v2/models/{MODEL_NAME}", response_model=ModelMetadata)
async def model_metadata(
    engine: EngineDep, settings: SettingsDep, targets: TargetsDep
) -> ModelMetadata:
    """What the loaded model is: version, tensors, default intrinsics, metrics, limits, and
    the known targets of ``POST /pose``."""
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
        targets=[TargetInfo(**target.describe()) for target in targets.values()],
    )
