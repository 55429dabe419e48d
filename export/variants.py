"""Lighter variants of an exported model for weak onboard processors: FP16 and INT8.

- FP16: weights and activations in half precision, inputs and outputs kept float32.
- INT8: static quantisation (QDQ, per-channel weights) of the convolutions, calibrated on
  spacecraft regions of training frames. Layers that carry metres or decide the mask at full
  resolution stay in float: the model names them (``SDCNet.float_modules``).
Each variant is only worth keeping if its accuracy (``sdc-eval evaluate --onnx``) and speed
(``benchmarks/model_latency.py``) beat FP32 for the user's processor.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import onnx
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
from onnxruntime.quantization.shape_inference import quant_pre_process
from onnxruntime.transformers.float16 import convert_float_to_float16

from sdcnet.pipeline import in_top_bits, working_inputs


def to_fp16(source: str | Path, target: str | Path) -> Path:
    model = convert_float_to_float16(onnx.load(str(source)), keep_io_types=True)
    onnx.save(model, str(target))
    return Path(target)


class RegionReader(CalibrationDataReader):
    """Feeds (gray uint8, sparse, fx) frames as the pipeline does: each one's spacecraft region
    on its working grid, one per call."""

    def __init__(self, frames: list[tuple[np.ndarray, np.ndarray]], stride: int):
        self._frames = iter(frames)
        self.stride = stride

    def get_next(self) -> dict[str, np.ndarray] | None:
        frame = next(self._frames, None)
        if frame is None:
            return None
        gray, sparse, focal_px = frame
        inputs = working_inputs(in_top_bits(gray), sparse, focal_px, self.stride)
        return {
            "gray": inputs.gray[None, None],
            "sparse": inputs.sparse[None, None],
            "focal_px": np.full((1, 1, 1, 1), inputs.focal_px, np.float32),
        }


def float_nodes(graph: onnx.ModelProto, modules: Sequence[str]) -> list[str]:
    """Names of the nodes of ``graph`` that the ``modules`` (their names in the network) made:
    the TorchScript exporter names a node after the path of its module ("/fdcnet/head/Conv").
    A ``ValueError`` if one of them made none: INT8 would quantise it quietly."""
    prefixes = {name: f"/{name.replace('.', '/')}/" for name in modules}
    found = {
        name: [n.name for n in graph.graph.node if n.name.startswith(p)]
        for name, p in prefixes.items()
    }
    missing = [name for name, nodes in found.items() if not nodes]
    if missing:
        raise ValueError(f"no node of {missing} in the ONNX graph: they would be quantised")
    return [node for nodes in found.values() for node in nodes]


def to_int8(
    source: str | Path,
    target: str | Path,
    frames: Iterator | list,
    stride: int,
    float_modules: Sequence[str],
) -> Path:
    """Static INT8 quantisation of the convolutions, calibrated on ``frames``, but for those of
    ``float_modules`` (``SDCNet.float_modules()``), which stay in float."""
    target = Path(target)
    prepared = target.with_suffix(".prep.onnx")
    quant_pre_process(str(source), str(prepared), skip_symbolic_shape=True)
    try:
        quantize_static(
            str(prepared),
            str(target),
            RegionReader(list(frames), stride),
            quant_format=QuantFormat.QDQ,
            op_types_to_quantize=["Conv"],
            per_channel=True,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            nodes_to_exclude=float_nodes(onnx.load(str(prepared)), float_modules),
        )
    finally:
        prepared.unlink(missing_ok=True)
    return target
