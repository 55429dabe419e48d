"""ONNX export: one self-contained graph, metadata, and a parity check that can fail."""

import json
import math

import numpy as np
import onnx
import pytest
import torch

from sdcnet.export import onnx_export
from sdcnet.export.cli import main as export_main
from sdcnet.export.cli import parity_frames
from sdcnet.export.onnx_export import (
    compare_outputs,
    export_onnx,
    network_metadata_props,
    parity_check,
)
from sdcnet.export.variants import float_nodes, to_fp16, to_int8
from sdcnet.pipeline import complete
from sdcnet.runtime.interface import ModelLoadError
from sdcnet.runtime.onnx import OnnxModel
from sdcnet.training.checkpoint import save_checkpoint
from sdcnet.training.model.sdcnet import VARIANTS, SDCNet, build_model, local_depth_spread


@pytest.fixture(scope="module")
def frames():
    return parity_frames(seed=7)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """Random weights with FSNet's bias raised: every pixel is foreground, so the parity check
    compares depth on all of them (a model that predicts no foreground compares none)."""
    torch.manual_seed(0)
    model = SDCNet().eval()
    with torch.no_grad():
        model.fsnet.head.bias += 3.0
    path = tmp_path_factory.mktemp("onnx") / "m.onnx"
    export_onnx(model, path, network_metadata_props(model, "test", {"MAEI": 0.1}))
    return model, path


def test_exported_graph_is_checked_and_carries_its_metadata(exported):
    _, path = exported
    graph = onnx.load(str(path))
    onnx.checker.check_model(graph)
    meta = {p.key: p.value for p in graph.metadata_props}
    assert json.loads(meta["intrinsics"])["fx"] == pytest.approx(7939.2, abs=0.1)
    assert json.loads(meta["metrics"]) == {"MAEI": 0.1}
    loaded = OnnxModel(path, provider="cpu")
    assert loaded.info.stride == 64 and loaded.provider == "CPUExecutionProvider"
    dims = [d.dim_param for d in graph.graph.input[0].type.tensor_type.shape.dim]
    assert dims == ["batch", "", "height", "width"]


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_every_variant_exports_with_parity_at_two_sizes_and_batches(variant, frames, tmp_path):
    torch.manual_seed(0)
    model = build_model(variant).eval()
    with torch.no_grad():  # a residual head that is not zero, so the whole graph is compared
        torch.nn.init.normal_(model.fdcnet.head.weight, std=0.05)
        if model.fsnet is not None:  # and foreground everywhere, so every pixel's depth is
            model.fsnet.head.bias += 6.0
    path = export_onnx(model, tmp_path / f"{variant}.onnx", network_metadata_props(model, "test"))
    sizes = (256, 512) if variant == "sdcnet" else (256,)  # the shipped design at two sizes
    cases = parity_check(model, path, frames, sizes=sizes, batches=(1, 2))
    assert [(c.size, c.batch) for c in cases] == [(s, b) for s in sizes for b in (1, 2)]
    assert all(c.passed for c in cases), cases
    assert all(c.max_depth_error_m < onnx_export.MAX_DEPTH_ERROR_M for c in cases)
    assert all(c.mask_agreement == 1.0 for c in cases)
    assert [c.compared_px for c in cases] == [c.batch * c.size**2 for c in cases]


def perturbed(model: SDCNet, depth_bias: float = 0.0, mask_bias: float = 0.0) -> SDCNet:
    copy = SDCNet().eval()
    copy.load_state_dict(model.state_dict())
    with torch.no_grad():
        copy.fdcnet.head.bias += depth_bias
        copy.fsnet.head.bias += mask_bias
    return copy


def test_parity_rejects_a_model_whose_depth_differs(exported, frames):
    model, path = exported
    (case,) = parity_check(perturbed(model, depth_bias=0.1), path, frames, (256,), (1,))
    assert not case.passed and case.mask_agreement == 1.0 and case.compared_px == 256**2
    _, sparse, fx = frames[0]
    crop = torch.from_numpy(onnx_export._centre(sparse, 256).copy())[None, None]
    unit = model.residual_unit(crop, torch.full((1, 1, 1, 1), fx)).item()  # metres
    assert case.max_depth_error_m == pytest.approx(0.1 * unit, rel=5e-3)  # the bias x the unit


def test_parity_rejects_a_model_whose_mask_differs(exported, frames):
    model, path = exported
    (case,) = parity_check(perturbed(model, mask_bias=-6.0), path, frames, (256,), (1,))
    assert not case.passed and case.mask_agreement == 0.0  # PyTorch: all background now
    assert case.compared_px == 256**2  # onnxruntime's foreground, compared all the same


def outputs_with_mask(depth: np.ndarray, prob: np.ndarray) -> tuple:
    """(depth, prob, sigma) as the network forms them: a constant scale head's 0.05 m and
    the depth-edge term (weight 0.5) over ``prob``'s foreground, added in quadrature."""
    spread = local_depth_spread(torch.from_numpy(depth), torch.from_numpy(prob) > 0.5).numpy()
    return depth, prob, np.sqrt(0.05**2 + (0.5 * spread) ** 2)


def test_parity_tolerates_a_probability_rounded_across_the_threshold_but_no_sigma_beside():
    """One pixel at 0.5 within a float's last bits: its decision flips between runtimes and the
    sigma of its neighbours' depth-edge term with it (the stop-67 soup's export failed on
    exactly that); sigma anywhere else must still match."""
    rng = np.random.default_rng(0)
    depth = (10.0 + rng.normal(0, 0.2, (1, 1, 128, 128))).astype(np.float32)
    prob = np.full((1, 1, 128, 128), 0.9, np.float32)
    prob[..., 30, 30] = 0.4999996
    flipped = prob.copy()
    flipped[..., 30, 30] = 0.5000008
    reference, candidate = outputs_with_mask(depth, prob), outputs_with_mask(depth, flipped)
    beside = np.abs(candidate[2] - reference[2]) / reference[2]
    assert beside[..., 28:33, 28:33].max() > 1e-3  # what the old check compared and failed on
    case = compare_outputs(128, 1, reference, candidate)
    assert case.passed and case.mask_agreement == 1 - 1 / 128**2
    assert case.compared_px == 128**2 and case.max_sigma_error == 0.0

    off = candidate[2].copy()
    off[..., 30, 33] *= 1.01  # one pixel past the window's reach
    case = compare_outputs(128, 1, reference, (candidate[0], candidate[1], off))
    assert not case.passed and case.max_sigma_error == pytest.approx(0.01, rel=1e-4)


def test_sdc_export_replaces_its_output_only_after_the_parity_check(tmp_path, capsys, monkeypatch):
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    out = tmp_path / "model.onnx"
    assert export_main(["--checkpoint", str(tmp_path / "bad.pt"), "--out", str(out)]) == 2
    assert capsys.readouterr().err.startswith("sdc-export: error: cannot read checkpoint")
    torch.manual_seed(3)
    save_checkpoint(tmp_path / "good.pt", SDCNet().eval())
    args = ["--checkpoint", str(tmp_path / "good.pt"), "--out", str(out)]

    out.write_bytes(b"the model in service")
    monkeypatch.setattr(onnx_export, "MAX_DEPTH_ERROR_M", -math.inf)  # no graph can pass
    assert export_main(args) == 1
    assert "parity check FAILED" in capsys.readouterr().err
    assert out.read_bytes() == b"the model in service"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pt", "good.pt", "model.onnx"]

    monkeypatch.undo()
    assert export_main(args) == 0
    printed = capsys.readouterr().out
    assert "1024 px, batch 2" in printed and "FAILED" not in printed
    assert OnnxModel(out, provider="cpu").info.version.startswith("sdcnet-model-")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.pt", "good.pt", "model.onnx"]


def test_loading_a_bad_model_file_says_why(tmp_path):
    with pytest.raises(ModelLoadError, match="not found"):
        OnnxModel(tmp_path / "none.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"\x00" * 64)
    with pytest.raises(ModelLoadError, match="cannot load"):
        OnnxModel(tmp_path / "junk.onnx")
    with pytest.raises(ModelLoadError, match="not available"):
        OnnxModel(tmp_path / "junk.onnx", provider="TensorrtExecutionProvider")


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_every_variant_names_its_float_modules_and_they_are_its_heads(variant):
    """INT8 keeps the modules ``SDCNet.float_modules`` names in float, found by name in the
    exported graph: a head renamed must fail here, not be quantised quietly."""
    model = build_model(variant)
    modules = [model.get_submodule(name) for name in model.float_modules()]  # each one exists
    heads = [model.fdcnet.head] + ([model.fsnet.head] if model.fsnet is not None else [])
    assert modules == heads  # the depth residual, scaled to metres; the mask logits
    assert all(isinstance(m, torch.nn.Conv2d) for m in modules)  # what INT8 would quantise


def test_a_float_module_missing_from_the_graph_is_an_error(exported):
    _, path = exported
    graph = onnx.load(str(path))
    assert float_nodes(graph, ["fdcnet.head"]) == ["/fdcnet/head/Conv"]
    with pytest.raises(ValueError, match="would be quantised"):
        float_nodes(graph, ["fdcnet.head", "fdcnet.renamed_head"])


def test_fp16_and_int8_variants_of_a_tiny_model_run(frames, tmp_path):
    """Both variants of a tiny network export and answer a frame through the pipeline, their
    depth near the float model's (its depth head starts at zero: depth is mostly the plane
    fit, which INT8 leaves nearly whole)."""
    torch.manual_seed(0)
    model = build_model("sdcnet", widths=(4, 4, 4, 4)).eval()
    stride = model.config.stride
    path = export_onnx(model, tmp_path / "m.onnx", network_metadata_props(model, "test"))
    variants = {
        "fp16": to_fp16(path, tmp_path / "m.fp16.onnx"),
        "int8": to_int8(path, tmp_path / "m.int8.onnx", frames[:1], stride, model.float_modules()),
    }
    gray, sparse, fx = frames[0]
    reference = complete(OnnxModel(path, provider="cpu").run, gray, sparse, fx, stride)
    # on the first look's crop: the untrained network's mask reaches its sides, and beyond
    # them each answers from a second look as coarse as the frame's budget left
    first = np.zeros(reference.mask.shape, bool)
    first[reference.grid.region.slices] = True
    for name, variant in variants.items():
        answer = complete(OnnxModel(variant, provider="cpu").run, gray, sparse, fx, stride)
        assert answer.grid.region == reference.grid.region, name
        both = answer.mask & reference.mask & first
        assert both.sum() > 0.5 * (reference.mask & first).sum(), name
        error = np.abs(answer.depth[both] - reference.depth[both]) / reference.depth[both]
        assert np.percentile(error, 99) < 0.02, name


def test_int8_keeps_the_depth_and_mask_heads_in_float(exported, frames, tmp_path):
    """In the quantised graph every convolution of the modules the model names
    (``SDCNet.float_modules``), and only theirs, keeps float weights."""
    model, path = exported
    modules = model.float_modules()
    target = to_int8(path, tmp_path / "m.int8.onnx", frames[:1], model.config.stride, modules)
    graph = onnx.load(str(target)).graph
    dequantized = {n.output[0] for n in graph.node if n.op_type == "DequantizeLinear"}
    convs = [n for n in graph.node if n.op_type == "Conv"]
    in_float = {n.name for n in convs if n.input[1] not in dequantized}
    prefixes = tuple(f"/{name.replace('.', '/')}/" for name in modules)
    for prefix in prefixes:
        assert any(name.startswith(prefix) for name in in_float), f"no float Conv {prefix}*"
    assert all(name.startswith(prefixes) for name in in_float)
    assert len(in_float) < len(convs)  # the rest is quantised
