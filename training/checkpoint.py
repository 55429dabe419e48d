"""Checkpoints: weights, architecture, provenance and the trainer's state, in one file.

``read_checkpoint`` is the one reader: every checkpoint the project opens (``--checkpoint``,
``--init-weights``, ``--init-segmentation``, a run's own ``last.pt``) goes through it, so a
missing, corrupt or foreign file is one clear ``ValueError`` / ``FileNotFoundError``.
"""

from __future__ import annotations

import json
import pickle
import zipfile
from collections.abc import Sequence
from pathlib import Path

import torch

from sdcnet.training.model.fsnet import WIDTHS, FSNet
from sdcnet.training.model.sdcnet import ModelConfig, SDCNet

#: The keys of a checkpoint that tell how it was made (a fine-tuned run keeps its parent's, an
#: average its members').
PROVENANCE = (
    "hardware",
    "train_config",
    "dataset",
    "history",
    "parent",
    "segmentation_parent",
    "averaged",
)


def provenance_key(record: dict) -> str:
    """One text per provenance record, its ``file`` left out: two records of one run compare
    equal by it (their histories hold NaN, which never equals itself)."""
    return json.dumps({k: v for k, v in record.items() if k != "file"}, sort_keys=True, default=str)


def _shared(tree: object, seen: dict[str, object]) -> object:
    """``tree`` (plain data) with each set of equal dicts and lists made one object, bottom up,
    so that ``torch.save`` (pickle, which writes an object once and refers to it after) stores
    it once. A soup of a model and a fine-tune of it holds that model's record twice (a member,
    and the fine-tune's parent): without this the file doubled with every such round."""
    if isinstance(tree, dict):
        tree = {k: _shared(v, seen) for k, v in tree.items()}
    elif isinstance(tree, list):
        tree = [_shared(v, seen) for v in tree]
    else:
        return tree
    return seen.setdefault(json.dumps(tree, sort_keys=True, default=str), tree)


def save_checkpoint(path: Path, model: SDCNet, **extra) -> None:
    """Atomic save of the model's weights and config plus any ``extra`` (JSON-able or tensors)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save({"model": model.state_dict(), "model_config": model.config.to_dict(), **extra}, tmp)
    tmp.replace(path)


def read_checkpoint(
    path: str | Path, map_location: str | torch.device = "cpu", check_config: bool = True
) -> dict:
    """The checkpoint dict (weights never unpickled as code: ``weights_only``), with its
    ``model`` weights and (unless ``check_config`` is off: a checkpoint of an earlier design to
    warm-start from) a ``model_config`` that parses. Clear errors for bad files."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint not found: {path}")
    if not zipfile.is_zipfile(path):
        raise ValueError(
            f"cannot read checkpoint {path}: not a PyTorch checkpoint (torch.save writes a zip "
            "archive), or a truncated one"
        )
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        raise ValueError(
            f"cannot read checkpoint {path}: it holds Python objects besides tensors and plain "
            "data, which are never unpickled"
        ) from exc
    except Exception as exc:  # torch raises zip and runtime errors of many kinds
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        raise ValueError(
            f"cannot read checkpoint {path}: {type(exc).__name__}: {first_line}"
        ) from exc
    if not isinstance(state, dict) or "model" not in state or "model_config" not in state:
        raise ValueError(f"{path} is not an sdcnet checkpoint")
    if not check_config:
        return state
    try:
        ModelConfig.from_dict(state["model_config"])
    except (TypeError, ValueError, KeyError, AttributeError) as exc:
        raise ValueError(f"{path} holds an architecture this version cannot build: {exc}") from exc
    return state


def load_weights(model: SDCNet, weights: dict, path: str | Path) -> None:
    """``model.load_state_dict(weights)``, a mismatch (weights of another architecture) being
    a ``ValueError`` that names ``path``."""
    try:
        model.load_state_dict(weights)
    except RuntimeError as exc:
        raise ValueError(f"the weights in {path} do not fit this architecture: {exc}") from exc


def transplant_weights(model: SDCNet, weights: dict) -> dict[str, list[str]]:
    """Copy into ``model`` the ``weights`` of another architecture: each tensor whose name and
    shape match, and of a convolution that gained input channels, the channels both have (the
    new ones start at zero, so the layer first computes what it did). For a new design
    warm-started from the shipped model. Returns the names copied, copied in part, left."""
    own = model.state_dict()
    report: dict[str, list[str]] = {"copied": [], "partial": [], "left": []}
    for name, tensor in own.items():
        theirs = weights.get(name)
        if theirs is not None and theirs.shape == tensor.shape:
            tensor.copy_(theirs)
            report["copied"].append(name)
        elif (
            theirs is not None
            and theirs.dim() == 4
            and theirs.shape[0] == tensor.shape[0]
            and theirs.shape[2:] == tensor.shape[2:]
            and theirs.shape[1] < tensor.shape[1]
        ):
            tensor.zero_()
            tensor[:, : theirs.shape[1]] = theirs
            report["partial"].append(name)
        else:
            report["left"].append(name)
    _widen_fsnet(model, weights, report)
    return report


def _widen_fsnet(model: SDCNet, weights: dict, report: dict[str, list[str]]) -> None:
    """A narrower FSNet in ``weights`` (smaller ``fsnet_growth``, same inputs and outputs)
    widened into ``model``'s (``FSNet.widen_from``); its tensors move from "left" to
    "partial" in ``report``."""
    first = weights.get("fsnet.enc1.0.weight")
    head = weights.get("fsnet.head.weight")
    own = model.fsnet
    if own is None or first is None or head is None:
        return
    if first.shape[0] >= own.enc1[0].out_channels or first.shape[1] != own.enc1[0].in_channels:
        return
    narrow = FSNet(
        in_channels=first.shape[1], out_channels=head.shape[0], growth=first.shape[0] // WIDTHS[0]
    )
    narrow.load_state_dict(
        {k[len("fsnet.") :]: v for k, v in weights.items() if k.startswith("fsnet.")}
    )
    own.widen_from(narrow)
    widened = [n for n in report["left"] if n.startswith("fsnet.")]
    report["left"] = [n for n in report["left"] if not n.startswith("fsnet.")]
    report["partial"] += widened


def load_checkpoint(
    path: str | Path, map_location: str | torch.device = "cpu"
) -> tuple[SDCNet, dict]:
    """The model (eval mode) and the whole checkpoint dict (``read_checkpoint``)."""
    state = read_checkpoint(path, map_location)
    model = SDCNet(ModelConfig.from_dict(state["model_config"]))
    load_weights(model, state["model"], path)
    return model.eval(), state


def average_checkpoints(sources: Sequence[str | Path], target: str | Path) -> None:
    """Write to ``target`` the mean of the ``sources``' weights (a "model soup": checkpoints
    fine-tuned from one model on other data or at other learning rates, whose mean keeps what
    each gained and loses less of what each forgot). All must share one architecture; integer
    tensors (batch-norm counters) are the first's. The result records each source's provenance
    under ``averaged`` (the model card lists their runs)."""
    if len(sources) < 2:
        raise ValueError("average needs at least two checkpoints")
    states = [read_checkpoint(path) for path in sources]
    config = states[0]["model_config"]
    for path, state in zip(sources[1:], states[1:], strict=True):
        if state["model_config"] != config:
            raise ValueError(
                f"{path} has another architecture than {sources[0]}: only checkpoints of one "
                "design can be averaged"
            )
    model = SDCNet(ModelConfig.from_dict(config))
    weights = {
        name: torch.stack([s["model"][name] for s in states]).mean(0)
        if tensor.is_floating_point()
        else tensor
        for name, tensor in states[0]["model"].items()
    }
    load_weights(model, weights, sources[0])
    members = [
        {k: state[k] for k in PROVENANCE if k in state} | {"file": str(path)}
        for path, state in zip(sources, states, strict=True)
    ]
    save_checkpoint(Path(target), model, averaged=_shared(members, {}))


def ship_checkpoint(source: str | Path, target: str | Path, zero: Sequence[str] = ()) -> None:
    """Copy the checkpoint at ``source`` to ``target`` without the optimiser's and scheduler's
    state (to commit it). ``zero``: an ablation copy, the weights under these module prefixes
    set to 0 (e.g. ``fdcnet.head``: depth is the plane fit alone), which it records."""
    model, state = load_checkpoint(source)
    weights = model.state_dict()
    for prefix in zero:
        chosen = [k for k in weights if k.startswith(prefix + ".") or k == prefix]
        if not chosen:
            raise ValueError(f"--zero {prefix}: no weights under that prefix in {source}")
        for key in chosen:
            weights[key].zero_()
    keep = {
        k: v
        for k, v in state.items()
        if k not in ("model", "model_config", "optimizer", "scheduler")
    }
    if zero:
        keep["zeroed"] = list(zero)
    save_checkpoint(Path(target), model, **keep)
