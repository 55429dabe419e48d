"""Checkpoints: weights, architecture, provenance and the trainer's state, in one file."""

from __future__ import annotations

from pathlib import Path

import torch

from sdcnet.training.model.sdcnet import ModelConfig, SDCNet


def save_checkpoint(path: Path, model: SDCNet, **extra) -> None:
    """Atomic save of the model's weights and config plus any ``extra`` (JSON-able or tensors)."""
    path = Path(path)
    tmp = path.with_suffix(".tmp")
    torch.save({"model": model.state_dict(), "model_config": model.config.to_dict(), **extra}, tmp)
    tmp.replace(path)


def load_checkpoint(
    path: str | Path, map_location: str | torch.device = "cpu"
) -> tuple[SDCNet, dict]:
    """The model (eval mode) and the whole checkpoint dict. Clear errors for bad files."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:
        raise ValueError(f"cannot read checkpoint {path}: {exc}") from exc
    if not isinstance(state, dict) or "model" not in state or "model_config" not in state:
        raise ValueError(f"{path} is not an sdcnet checkpoint")
    model = SDCNet(ModelConfig.from_dict(state["model_config"]))
    model.load_state_dict(state["model"])
    return model.eval(), state
