"""The methods an evaluation compares, from what its command was given: checkpoints,
exported ONNX models, answers stored by another system, the classical fill."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sdcnet.evaluation.scoring import (
    FILL,
    Method,
    StoredAnswers,
    classical,
    network,
    torch_model_fn,
    torch_segmentation_fn,
)
from sdcnet.training.checkpoint import load_checkpoint


def methods_from(
    checkpoints: list[str],
    names: list[str] | None = None,
    onnx: Sequence[str] = (),
    answers: list[str] | None = None,
    floor: bool = False,
    segmentation_only: bool = False,
) -> dict[str, Method]:
    """Table label -> method, in this order: each checkpoint (labelled by ``names``, else its
    training variant, else its file name), each ONNX model (``onnx:<file name>``), each
    ``NAME=FOLDER`` of stored answers, and the classical fill when ``floor``.
    ``segmentation_only`` runs only the checkpoints' foreground path."""
    if names and len(names) != len(checkpoints):
        raise ValueError(f"--names gives {len(names)} names for {len(checkpoints)} checkpoints")
    methods: dict[str, Method] = {}
    for i, path in enumerate(checkpoints):
        model, state = load_checkpoint(path)
        name = names[i] if names else state.get("train_config", {}).get("variant", Path(path).stem)
        if name in methods:
            raise ValueError(f"two checkpoints are both called {name!r}: give --names")
        fn = torch_segmentation_fn(model) if segmentation_only else torch_model_fn(model)
        methods[name] = network(fn, model.config.stride)
    for path in onnx:
        from sdcnet.runtime.onnx import OnnxModel

        name = f"onnx:{Path(path).name}"
        if name in methods:
            raise ValueError(f"two ONNX models are both called {name!r}: rename one file")
        onnx_model = OnnxModel(path)
        methods[name] = network(onnx_model.run, onnx_model.stride, onnx_model.info.work_pixels)
    for entry in answers or []:
        name, sep, folder = entry.partition("=")
        if not sep or not name or not folder:
            raise ValueError(f"--answers takes NAME=FOLDER, got {entry!r}")
        methods[name] = StoredAnswers(folder)
    if floor:
        methods[FILL] = classical
    if not methods:
        raise ValueError("nothing to evaluate: give --checkpoint, --onnx or --floor")
    return methods
