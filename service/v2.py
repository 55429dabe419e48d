"""The Open Inference Protocol v2 (KServe, Triton) for ``POST /v2/models/sdcnet/infer``, with
its binary tensor data extension: request bytes to a validated ``Frame``, and a completed
frame to answer bytes. Clients such as ``tritonclient.http`` talk to it unmodified.

A request is a JSON header, optionally followed by the raw little-endian bytes of the inputs
that say ``"parameters": {"binary_data_size": n}`` (in the order of ``inputs``); the
``Inference-Header-Content-Length`` HTTP header gives the JSON header's length when binary data
follows. Answers are built the same way: outputs asked with ``binary_data`` (or all of them,
with the request parameter ``binary_data_output``) follow the JSON header as raw bytes.

Inputs: ``gray`` (UINT8 or UINT16, [H, W]) and either ``sparse`` (FP32, [H, W], metres, 0 = no
return) or ``returns`` (FP32, [N, 3]: row, column, Z metres). Request parameters: ``fx``,
``fy``, ``cx``, ``cy`` (pixels), ``outlier_removal`` and ``max_sigma`` (metres). Outputs:
``depth`` (FP32, [H, W]), ``mask`` (UINT8, [H, W]), ``points`` (FP32, [N, 3]), ``normals``
(FP32, [N, 3], each point's unit surface normal) and ``sigma`` (FP32, [H, W], metres).
sdcnet's own output parameters ask for the compact layouts of ``sdcnet.compact``: ``region``
(depth, mask, sigma: only the spacecraft's region, the smallest window holding the mask; the
answer says where), ``bits`` (mask: 8 pixels a byte) and ``fp16`` (depth: float16 residuals
above ``depth_offset``).

The protocol's data models are in ``sdcnet.service.v2_schemas``, request bytes become a frame
in ``sdcnet.service.v2_decode`` and a completed frame becomes answer bytes in
``sdcnet.service.v2_encode``; ``answer`` runs the three phases on one request, as
``sdcnet.service.inference.answer`` does for ``POST /complete``.
"""

from __future__ import annotations

from typing import Any

from sdcnet.formats.v2 import HEADER_LENGTH
from sdcnet.service.camera import ServiceCamera, camera_frame
from sdcnet.service.decode import InputLimits
from sdcnet.service.deps import MODEL_NAME
from sdcnet.service.inference import Answer, Engine, PhaseTimer, complete_frame
from sdcnet.service.spool import Spool
from sdcnet.service.v2_decode import frame_of_request, parse_request, requested_outputs, split_body
from sdcnet.service.v2_encode import encode_outputs, summary_parameters, write_answer
from sdcnet.service.v2_schemas import InferParameters


def answer(
    engine: Engine,
    body: bytes | bytearray,
    header_length: str | None,
    limits: InputLimits,
    camera: ServiceCamera | None = None,
) -> Answer:
    """Parse (into the ``camera``'s frame), complete, encode one inference request; raises
    ``ApiError`` for bad input. The encode phase times the outputs' layouts; their bytes are
    written with the header, which carries the timings."""
    timer = PhaseTimer()
    with timer("decode"):
        header, binary = split_body(body, header_length)
        parsed = parse_request(header)
        outputs = requested_outputs(parsed.request)
        frame = camera_frame(frame_of_request(parsed, binary, limits), camera)
    done = complete_frame(engine, frame, timer)
    request = parsed.request
    parameters = request.parameters or InferParameters()
    with timer("encode"):
        encoded = encode_outputs(outputs, done, parameters.binary_data_output)
    document: dict[str, Any] = {
        "model_name": MODEL_NAME,
        "model_version": engine.model.info.version,
    }
    if request.id is not None:
        document["id"] = request.id
    document["parameters"] = summary_parameters(done.summary(engine.model, timer))
    spool = Spool()
    try:
        length = write_answer(spool, document, encoded)
    except BaseException:
        spool.close()
        raise
    if not any(output.binary for output in encoded):
        return Answer(spool, timer, media_type="application/json")
    return Answer(
        spool,
        timer,
        headers={HEADER_LENGTH: str(length)},
        media_type="application/octet-stream",
    )
