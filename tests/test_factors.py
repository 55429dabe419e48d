"""``sdc-eval factors``: the mask's IOU grouped by each factor a frame records."""

import json

import pytest

from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.cli import main as eval_main
from sdcnet.evaluation.factors import FACTORS, FrameFactors, bin_order, binned, factor_rows
from sdcnet.evaluation.scoring import classical
from sdcnet.metrics import mask_iou
from sdcnet.training.data.cli import main as data_main
from tests.support.frames import write_dataset


@pytest.mark.parametrize(
    ("value", "label"),
    [(0, "<1"), (1, "1-30"), (29.9, "1-30"), (30, "30-300"), (300, ">=300")],
)
def test_a_value_falls_in_the_bin_its_label_names(value, label):
    assert binned(value, (1, 30, 300)) == label


def test_bins_sort_in_ascending_order_then_names():
    labels = [">=150 m", "stars", "15-50 m", "<5 m", "5-15 m", "earth-limb", "50-150 m"]
    ordered = ["<5 m", "5-15 m", "15-50 m", "50-150 m", ">=150 m", "earth-limb", "stars"]
    assert sorted(labels, key=bin_order) == ordered


def test_each_value_holds_its_share_of_the_first_methods_deficit():
    frames = [
        FrameFactors("a", {"LIDAR": "flash"}, {"model": 0.2, "fill": 0.1}),
        FrameFactors("b", {"LIDAR": "flash"}, {"model": 0.6, "fill": 0.5}),
        FrameFactors("c", {"LIDAR": "scanning"}, {"model": 1.0, "fill": 0.9}),
        FrameFactors("d", {"LIDAR": "scanning"}, {"model": 0.8, "fill": 0.9}),
    ]
    rows = {row["value"]: row for row in factor_rows(frames, "LIDAR")}
    # deficits 0.8 + 0.4 (flash) and 0.0 + 0.2 (scanning), of 1.4 in all
    assert rows["flash"]["deficit_share"] == pytest.approx(100 * 1.2 / 1.4)
    assert rows["scanning"]["deficit_share"] == pytest.approx(100 * 0.2 / 1.4)
    assert rows["flash"]["iou"] == pytest.approx({"model": 40.0, "fill": 30.0})
    assert rows["flash"]["poor"] == 1 and rows["scanning"]["poor"] == 0
    (overall,) = factor_rows(frames, None)
    assert overall["frames"] == 4 and overall["deficit_share"] == pytest.approx(100.0)


def test_rendered_frames_are_grouped_by_what_their_metadata_records(tmp_path):
    data, out = tmp_path / "any", tmp_path / "factors"
    render = ["generate", "--out", str(data), "--models", "6", "--views", "2", "--size", "128"]
    world = ["--world", "any", "--styles", "ours", "pbr", "--only-splits", "test", "--quiet"]
    assert data_main([*render, *world]) == 0
    assert eval_main(["factors", "--floor", "--data", str(data), "--out", str(out)]) == 0

    report = json.loads((out / "factors.json").read_text())
    store = SampleStore(data)
    samples = {r["id"]: store.load(r) for r in store.split("test")}
    assert {f["id"] for f in report["frames"]} == set(samples)
    for frame in report["frames"]:
        sample = samples[frame["id"]]
        assert frame["factors"]["background"] == sample.meta["background"]["kind"]
        assert frame["factors"]["LIDAR"] == sample.meta["lidar"]["kind"]
        assert frame["factors"]["render style"] == sample.meta["render_style"]["kind"]
        fill_mask = classical(sample).mask
        assert frame["iou"]["classical fill"] == pytest.approx(mask_iou(fill_mask, sample.mask))
    for factor in FACTORS:
        assert sum(row["frames"] for row in report["factors"][factor]) == len(samples)
    table = (out / "factors.md").read_text()
    assert all(f"| {factor} |" in table for factor in FACTORS)
    assert (out / "factors.png").stat().st_size > 10_000


def test_frames_that_record_no_factors_are_refused_with_what_they_lack(tmp_path, capsys):
    data = write_dataset(tmp_path / "plain", {"test": 1})
    assert eval_main(["factors", "--floor", "--data", str(data), "--out", str(tmp_path)]) == 2
    assert "records no 'background' in its metadata" in capsys.readouterr().err
