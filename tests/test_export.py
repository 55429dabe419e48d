"""ONNX export: one self-contained graph, metadata, and a parity check that can fail."""

import json

import onnx
import pytest
import torch

from sdcnet.export.cli import main as export_main
from sdcnet.export.cli import parity_frames
from sdcnet.export.onnx_export import export_onnx, model_metadata, parity_check
from sdcnet.runtime import ModelLoadError, OnnxModel
from sdcnet.training.checkpoint import save_checkpoint
from sdcnet.training.model.sdcnet import VARIANTS, SDCNet, build_model


@pytest.fixture(scope="module")
def frames():
    return parity_frames(seed=7)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    torch.manual_seed(0)
    model = SDCNet().eval()
    path = tmp_path_factory.mktemp("onnx") / "m.onnx"
    export_onnx(model, path, model_metadata(model, "test", {"MAEI": 0.1}))
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
    path = export_onnx(model, tmp_path / f"{variant}.onnx", model_metadata(model, "test"))
    sizes = (256, 512) if variant == "sdcnet" else (256,)  # the shipped design at two sizes
    cases = parity_check(model, path, frames, sizes=sizes, batches=(1, 2))
    assert [(c.size, c.batch) for c in cases] == [(s, b) for s in sizes for b in (1, 2)]
    assert all(c.passed for c in cases), cases
    assert all(c.max_depth_error_m < 5e-4 for c in cases)  # metres; the export's bar is 1 mm


def test_parity_rejects_a_perturbed_model(exported, frames):
    model, path = exported
    perturbed = SDCNet().eval()
    perturbed.load_state_dict(model.state_dict())
    with torch.no_grad():
        perturbed.fdcnet.head.bias += 0.1  # 10 cm in depth: the graph no longer matches
        perturbed.fsnet.head.bias += 3.0  # and the mask flips
    cases = parity_check(perturbed, path, frames, sizes=(256,), batches=(1,))
    assert not cases[0].passed
    assert cases[0].max_depth_error_m == pytest.approx(0.1, rel=1e-3)


def test_sdc_export_command_fails_on_a_bad_checkpoint_and_passes_on_a_good_one(tmp_path, capsys):
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    assert (
        export_main(["--checkpoint", str(tmp_path / "bad.pt"), "--out", str(tmp_path / "x.onnx")])
        == 2
    )
    assert "cannot read checkpoint" in capsys.readouterr().err
    torch.manual_seed(3)
    save_checkpoint(tmp_path / "good.pt", SDCNet().eval())
    assert (
        export_main(["--checkpoint", str(tmp_path / "good.pt"), "--out", str(tmp_path / "g.onnx")])
        == 0
    )
    out = capsys.readouterr().out
    assert "1024 px, batch 2" in out and "FAILED" not in out


def test_loading_a_bad_model_file_says_why(tmp_path):
    with pytest.raises(ModelLoadError, match="not found"):
        OnnxModel(tmp_path / "none.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"\x00" * 64)
    with pytest.raises(ModelLoadError, match="cannot load"):
        OnnxModel(tmp_path / "junk.onnx")
    with pytest.raises(ModelLoadError, match="not available"):
        OnnxModel(tmp_path / "junk.onnx", provider="TensorrtExecutionProvider")
