"""Models to serve in tests: a tiny sdcnet-shaped ONNX graph built with ``onnx.helper`` (no
torch), and the real SDCNet architecture with random weights (torch)."""

from __future__ import annotations

from pathlib import Path

from sdcnet.runtime.interface import INPUTS, OUTPUTS, metadata_props

TINY_VERSION = "test-tiny"
RANDOM_VERSION = "test-random"
#: Side of the tiny model's max filter, pixels: wider than the paper's beam spacing at its
#: training scale (~12.5 x 18 px), so every pixel of a surface gets the depth of a return.
TINY_FILL_PX = 19


def graph_model(
    nodes: list,
    inputs: tuple[str, ...] = INPUTS,
    outputs: tuple[str, ...] = OUTPUTS,
    metadata: dict[str, str] | None = None,
    initializers: tuple = (),
):
    """An ONNX model (opset 17) of ``nodes`` on float tensors (B, 1, H, W) named ``inputs``
    and ``outputs`` (``focal_px``: (B, 1, 1, 1)), carrying ``metadata``. Needs the ``onnx``
    package."""
    from onnx import TensorProto, helper

    def shape(name: str) -> list:
        return ["batch", 1, 1, 1] if name == "focal_px" else ["batch", 1, "height", "width"]

    graph = helper.make_graph(
        nodes,
        "sdcnet-test",
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, shape(n)) for n in inputs],
        [helper.make_tensor_value_info(n, TensorProto.FLOAT, shape(n)) for n in outputs],
        initializer=list(initializers),
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8  # read by every onnxruntime since 1.14
    for key, value in sorted((metadata or {}).items()):
        model.metadata_props.add(key=key, value=value)
    return model


def tiny_model(base: Path, stride: int = 64) -> Path:
    """``base/sdcnet-tiny.onnx``: an ONNX graph with sdcnet's inputs, outputs and metadata and
    two operators, so that the service and the client can be tested without torch and fast:

    - ``depth``: the sparse map under a ``TINY_FILL_PX`` x ``TINY_FILL_PX`` max filter (two
      1-D max pools): each pixel takes the farthest LIDAR return around it, 0 far from any;
    - ``foreground``: the gray image itself (a pixel brighter than mid-gray is spacecraft);
    - ``sigma``: a tenth of the gray image, metres.

    Written once; needs the ``onnx`` package."""
    import onnx
    from onnx import helper

    path = base / "sdcnet-tiny.onnx"
    if path.exists():
        return path
    half = TINY_FILL_PX // 2
    nodes = [
        helper.make_node(
            "MaxPool",
            ["sparse"],
            ["rows_filled"],
            kernel_shape=[TINY_FILL_PX, 1],
            pads=[half, 0, half, 0],
        ),
        helper.make_node(
            "MaxPool",
            ["rows_filled"],
            ["depth"],
            kernel_shape=[1, TINY_FILL_PX],
            pads=[0, half, 0, half],
        ),
        helper.make_node("Identity", ["gray"], ["foreground"]),
        helper.make_node("Constant", [], ["tenth"], value_float=0.1),
        helper.make_node("Mul", ["gray", "tenth"], ["sigma"]),
    ]
    model = graph_model(nodes, metadata=metadata_props(TINY_VERSION, stride))
    onnx.checker.check_model(model, full_check=True)
    base.mkdir(parents=True, exist_ok=True)
    onnx.save(model, path)
    return path


def random_model(base: Path) -> Path:
    """``base/sdcnet-random.onnx``: the real SDCNet graph with random weights, exported once.
    Random weights predict no foreground, so the segmentation head's bias is raised to make
    the whole crop foreground: a non-empty mask and cloud. Needs the ``train`` extra."""
    import torch

    from sdcnet.export.onnx_export import export_onnx, network_metadata_props
    from sdcnet.training.model.sdcnet import SDCNet

    path = base / "sdcnet-random.onnx"
    if not path.exists():
        torch.manual_seed(0)
        model = SDCNet().eval()
        with torch.no_grad():
            model.fsnet.head.bias += 3.0
        export_onnx(model, path, network_metadata_props(model, RANDOM_VERSION))
    return path
