"""The baseline and the evaluation tools: the classical fill follows any LIDAR's spacing, answers
made elsewhere are scored like any method, and the robustness suite reports every condition."""

import json

import numpy as np
import pytest

from sdcnet.dataset_format import Sample
from sdcnet.evaluation.classical_fill import classical_fill, return_spacing
from sdcnet.evaluation.robustness import run_suite
from sdcnet.evaluation.scoring import StoredAnswers, network, score_frame
from sdcnet.metrics import uncertainty_metrics
from sdcnet.runtime.onnx import OnnxModel
from tests.support.models import tiny_model


def grid(shape, spacing, box, depth=100.0):
    """Returns on a (rows, columns) spacing inside ``box`` (y0, y1, x0, x1)."""
    sparse = np.zeros(shape, np.float32)
    y0, y1, x0, x1 = box
    sparse[y0 : y1 : spacing[0], x0 : x1 : spacing[1]] = depth
    return sparse


@pytest.mark.parametrize("spacing", [(18, 12), (4, 4), (40, 3)])
def test_the_fill_measures_the_returns_spacing_and_bridges_it(spacing):
    """The paper's scanner, a flash array, a multi-beam sensor's far rows of dense returns."""
    sparse = grid((400, 400), spacing, (100, 300, 100, 300))
    assert return_spacing(*np.nonzero(sparse)) == pytest.approx(spacing, rel=0.01)
    depth, mask = classical_fill(sparse)
    rows, cols = np.nonzero(sparse)
    inner = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    assert mask[inner].all(), "every pixel between the returns is filled"
    np.testing.assert_allclose(depth[inner], 100.0, atol=1e-3)
    reach = 2.5 * max(spacing)  # the holes' kernel: no more than ~3 spacings past the last row
    assert not mask[: int(100 - reach)].any() and not mask[:, : int(100 - reach)].any()


def test_the_fill_keeps_the_nearer_surface_where_two_meet():
    sparse = grid((200, 200), (18, 12), (0, 200, 0, 200), depth=120.0)
    right = sparse[:, 100:]
    right[right > 0] = 80.0  # a panel 40 m nearer on the right half
    depth, _ = classical_fill(sparse)
    np.testing.assert_allclose(depth[40:160, 110:190], 80.0, atol=1e-3)
    np.testing.assert_allclose(depth[40:160, 10:80], 120.0, atol=1e-3)


def frame(sid: str = "f0") -> Sample:
    gray = np.zeros((256, 256), np.uint8)
    gray[80:180, 60:200] = 200
    depth = np.zeros((256, 256), np.float32)
    depth[80:180, 60:200] = 50.0
    sparse = grid((256, 256), (9, 6), (82, 178, 62, 198), depth=50.0)
    meta = {
        "id": sid,
        "intrinsics": {
            "fx": 2000.0,
            "fy": 2000.0,
            "cx": 127.5,
            "cy": 127.5,
            "width": 256,
            "height": 256,
        },
    }
    return Sample(gray, sparse, depth, meta)


def test_stored_answers_are_scored_like_any_method(tmp_path):
    s = frame()
    mask = s.depth > 0
    np.savez(tmp_path / "f0.npz", depth=s.depth, mask=mask, milliseconds=42.0)
    stored = StoredAnswers(tmp_path)
    depth, got, sigma, completion = stored(s)
    assert (depth == s.depth).all() and got.dtype == bool and (got == mask).all()
    assert sigma is None, "answers made without an uncertainty have none"
    assert completion is None, "nor the pipeline's answer (normals from their depth)"
    assert stored.milliseconds(s) == 42.0
    report = score_frame(stored, s)
    assert report["IOU"] == 1.0 and report["MAEI"] == 0.0 and report["specks"] == 0
    with pytest.raises(FileNotFoundError, match="no answer for frame f1"):
        stored(frame("f1"))


def test_the_robustness_suite_reports_every_condition_with_its_cost(tmp_path):
    model = OnnxModel(tiny_model(tmp_path / "model"), provider="cpu", threads=1)
    methods = {"tiny": network(model.run, model.stride, model.info.work_pixels)}
    table = run_suite(
        methods,
        ["paper", "flash"],
        tmp_path / "data",
        (),
        tmp_path / "out",
        views=1,
        seed=0,
        workers=1,
        gallery=1,
        models=6,
    )
    rows = [
        line
        for line in table.splitlines()
        if line.startswith("| paper") or line.startswith("| flash")
    ]
    assert len(rows) == 2 and all("| tiny |" in row for row in rows)
    report = json.loads((tmp_path / "out" / "robustness.json").read_text())
    assert report["frames"] == {"paper": 1, "flash": 1}
    tiny = report["results"]["flash"]["tiny"]
    assert len(tiny["milliseconds"]) == 1 and tiny["latency_ms"]["max"] > 0
    assert 0 <= report["results"]["flash"]["classical fill"]["metrics"]["IOU"] <= 1
    assert (tmp_path / "out" / "gallery_paper.png").stat().st_size > 1000


def test_uncertainty_metrics_measure_coverage_and_what_dropping_the_unsure_buys():
    gt = np.full((10, 10), 100.0, np.float32)
    errors = np.linspace(0.01, 1.0, 100).reshape(10, 10).astype(np.float32)
    depth = gt + errors
    mask = np.ones((10, 10), bool)
    sigma = np.full((10, 10), 0.5, np.float32)
    m = uncertainty_metrics(depth, mask, gt, sigma)
    assert m["sigma_within_1"] == pytest.approx(0.50, abs=0.011)
    assert m["sigma_within_2"] == 1.0
    assert m["sigma_mae_cut_10"] == pytest.approx(0.0, abs=1e-6), "all alike: nothing to drop"
    honest = errors.copy()  # sigma that ranks the errors: the worst 10 % go
    cut = uncertainty_metrics(depth, mask, gt, honest)["sigma_mae_cut_10"]
    kept = np.sort(errors.ravel())[:90]
    assert cut == pytest.approx(1 - kept.mean() / errors.mean(), rel=1e-4)
    assert np.isnan(uncertainty_metrics(depth, mask, gt, None)["sigma_within_1"])
