"""sdc-train end to end on a tiny generated dataset: fit, resume, ship, calibrate; and
``sdc-eval``'s evaluate and card on what it trained."""

import csv
import json
import math
import os
import shutil
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import torch

from sdcnet.dataset_format import SampleStore
from sdcnet.evaluation.card import lineage, model_card
from sdcnet.evaluation.cli import main as eval_main
from sdcnet.training.checkpoint import (
    PROVENANCE,
    average_checkpoints,
    load_checkpoint,
    read_checkpoint,
    save_checkpoint,
    transplant_weights,
)
from sdcnet.training.cli import main as train_main
from sdcnet.training.cli import parser as train_parser
from sdcnet.training.data.cli import main as data_main
from sdcnet.training.data.generate import GenerateConfig, generate
from sdcnet.training.dataset import resample_truth
from sdcnet.training.model.sdcnet import VARIANTS, SDCNet, build_model
from sdcnet.training.train import TrainConfig, config_from_preset
from sdcnet.training.uncertainty import error_ratios, with_sigma


@pytest.fixture(scope="module")
def run(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    code = train_main(
        [
            "fit",
            "--data",
            str(tiny_dataset),
            "--out",
            str(out),
            "--preset",
            "smoke",
            "--fsnet-epochs",
            "2",
        ]
    )
    assert code == 0
    return out


def unchanged(theirs: dict, ours: dict, prefix: str) -> list[bool]:
    """Whether each weight under ``prefix`` is the same in both state dicts; never empty."""
    same = [torch.equal(theirs[k], ours[k]) for k in theirs if k.startswith(prefix)]
    assert same, f"no weights under {prefix!r}"
    return same


def test_fit_runs_both_stages_and_keeps_its_records(run):
    rows = list(csv.DictReader((run / "log.csv").open()))
    assert [(r["stage"], r["epoch"]) for r in rows] == [("1", "1"), ("1", "2"), ("2", "1")]
    for row in rows:
        assert float(row["train_loss"]) > 0 and 0 <= float(row["IOU"]) <= 1
    # stage 1 of a fresh run validates the mask alone; stage 2 all six metrics
    assert all(math.isnan(float(row["MATE"])) for row in rows[:2])
    assert 0 < float(rows[2]["MATE"]) <= 10  # truncated at alpha = 10 m
    assert (run / "learning_curves.png").stat().st_size > 1000
    _, state = load_checkpoint(run / "best.pt")
    assert state["train_config"]["variant"] == "sdcnet"
    assert state["dataset"]["command"].startswith("sdc-data generate")
    assert state["dataset"]["frames"] == {"train": 2, "val": 2}  # 3 models x 2 views, 1:1:1
    assert "torch" in state["hardware"]


def test_fit_resumes_instead_of_starting_over(run, tiny_dataset, tmp_path):
    run = shutil.copytree(run, tmp_path / "run")  # the module's run stays as it was made
    before = (run / "log.csv").read_text()
    assert (
        train_main(
            [
                "fit",
                "--data",
                str(tiny_dataset),
                "--out",
                str(run),
                "--preset",
                "smoke",
                "--fsnet-epochs",
                "2",
                "--epochs",
                "2",
            ]
        )
        == 0
    )
    rows = list(csv.DictReader((run / "log.csv").open()))
    assert (run / "log.csv").read_text().startswith(before)
    assert [(r["stage"], r["epoch"]) for r in rows][-1] == ("2", "2"), (
        "one more epoch, not a restart"
    )


def test_evaluate_prints_the_table_with_the_floor_and_writes_the_card(
    run, tiny_dataset, tmp_path, capsys
):
    report = tmp_path / "test.json"
    assert (
        eval_main(
            [
                "evaluate",
                "--checkpoint",
                str(run / "best.pt"),
                "--data",
                str(tiny_dataset),
                "--split",
                "test",
                "--floor",
                "--out",
                str(report),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "| classical fill |" in out and "| sdcnet |" in out
    assert "| MAE m (fill) | 0-3px m |" in out  # the depth table beside the paper's
    results = json.loads(report.read_text())["results"]
    floor = results["classical fill"]  # 256 px frames: denser returns than the kernels expect
    assert 0.2 < floor["IOU"] <= 1.0 and floor["MAEI"] < 1.0
    assert floor["MAE"] == pytest.approx(floor["fill_MAE"])  # the fill on its own pixels
    assert 0 < floor["normal_mean_deg"] < 90 and 0 <= floor["normal_within_11.25"] <= 1
    assert results["sdcnet"]["specks"] >= 0
    card = tmp_path / "card.md"
    assert (
        eval_main(
            [
                "card",
                "--checkpoint",
                str(run / "best.pt"),
                "--report",
                str(report),
                "--out",
                str(card),
            ]
        )
        == 0
    )
    assert "| classical fill |" in card.read_text()
    assert "frames used {'train': 2, 'val': 2}" in card.read_text()


def test_init_weights_fine_tunes_the_segmentation_alone(run, tiny_dataset, tmp_path):
    """--init-weights X --epochs 0: stage 1 continues from X's FSNet; X's FDCNet is kept."""
    out = tmp_path / "ft"
    fit = ["fit", "--data", str(tiny_dataset), "--out", str(out), "--preset", "smoke"]
    assert train_main([*fit, "--init-weights", str(run / "best.pt"), "--epochs", "0"]) == 0
    assert not (out / "best.pt").exists()
    source, _ = load_checkpoint(run / "best.pt")
    tuned, state = load_checkpoint(out / "best_stage1.pt")
    assert state["train_config"]["init_weights"] == str(run / "best.pt")
    theirs, ours = source.state_dict(), tuned.state_dict()
    assert all(unchanged(theirs, ours, "fdcnet."))
    assert not all(unchanged(theirs, ours, "fsnet."))
    _, source_state = load_checkpoint(run / "best.pt")
    assert state["parent"]["train_config"] == source_state["train_config"]
    epochs = [
        [(r["stage"], r["epoch"], r["IOU"]) for r in s["history"]]
        for s in (state["parent"], source_state)
    ]
    assert epochs[0] == epochs[1]
    card = tmp_path / "card.md"
    assert eval_main(["card", "--checkpoint", str(out / "best_stage1.pt"), "--out", str(card)]) == 0
    text = card.read_text()
    assert "2 run(s)" in text and "| recipe | run 1 | run 2 |" in text
    assert source_state["train_config"]["command"] in text


def test_average_writes_the_mean_of_fine_tuned_weights_and_the_card_lists_their_runs(
    run, tiny_dataset, tmp_path, capsys
):
    fit = ["fit", "--data", str(tiny_dataset), "--out", str(tmp_path / "ft"), "--preset", "smoke"]
    assert train_main([*fit, "--init-weights", str(run / "best.pt"), "--epochs", "0"]) == 0
    members = [run / "best.pt", tmp_path / "ft" / "best_stage1.pt"]
    soup = tmp_path / "soup.pt"
    assert train_main(["average", "--checkpoints", *map(str, members), "--out", str(soup)]) == 0
    (a, _), (b, _) = (load_checkpoint(m) for m in members)
    mean, state = load_checkpoint(soup)
    theirs = [a.state_dict(), b.state_dict()]
    for name, tensor in mean.state_dict().items():
        if tensor.is_floating_point():
            assert torch.allclose(tensor, (theirs[0][name] + theirs[1][name]) / 2, atol=1e-7)
        else:
            assert torch.equal(tensor, theirs[0][name])
    assert not all(unchanged(theirs[0], mean.state_dict(), "fsnet."))
    assert [m["file"] for m in state["averaged"]] == list(map(str, members))
    card = tmp_path / "card.md"
    assert eval_main(["card", "--checkpoint", str(soup), "--out", str(card)]) == 0
    text = card.read_text()
    # the fine-tune's parent is the first member: two runs, not three
    assert "2 run(s)" in text and "from run 1's weights" in text
    assert "the mean of runs 1, 2's" in text
    # a run fine-tuned from the average: its members' runs, then it, started from their mean
    tuned = {"train_config": {"command": "sdc-train fit --init-weights soup.pt"}, "history": []}
    tuned["parent"] = {k: state[k] for k in PROVENANCE if k in state}
    text = model_card(tuned, mean, [], "tuned")
    assert "3 run(s)" in text and "from the mean of runs 1, 2's weights" in text
    # an average of that average and the run tuned from it
    tuned = {**tuned, "file": "tuned.pt"}
    nested = {"averaged": [{k: state[k] for k in PROVENANCE if k in state}, tuned]}
    text = model_card(nested, mean, [], "nested")
    assert "The weights are the mean of (the mean of runs 1, 2) and run 3's" in text
    other = tmp_path / "baseline.pt"
    save_checkpoint(other, build_model("baseline"))
    refused = ["--out", str(tmp_path / "refused.pt")]
    assert train_main(["average", "--checkpoints", str(soup), str(other), *refused]) == 2
    assert "another architecture" in capsys.readouterr().err
    assert train_main(["average", "--checkpoints", str(soup), *refused]) == 2
    assert "at least two" in capsys.readouterr().err
    assert not (tmp_path / "refused.pt").exists()


def test_rounds_of_soups_store_each_run_once(tmp_path):
    """The shipped model's recipe, round after round: average the model with a fine-tune of
    it. The fine-tune's parent is the model, a member of the same soup; stored once, the file
    grows by about one run's record a round instead of doubling."""
    model = build_model("sdcnet")

    def fine_tune(number: int, parent: dict | None) -> dict:
        history = [
            {"stage": 1, "epoch": e, "IOU": 0.8 + e / 1000, "MAEI": math.nan} for e in range(40)
        ]
        record = {"train_config": {"command": f"run {number}"}, "history": history}
        if parent is not None:
            record["parent"] = {k: parent[k] for k in PROVENANCE if k in parent}
        return record

    shipped = tmp_path / "round0.pt"
    save_checkpoint(shipped, model, **fine_tune(0, None))
    sizes = []
    for number in range(1, 7):
        tuned = tmp_path / f"tuned{number}.pt"
        save_checkpoint(tuned, model, **fine_tune(number, read_checkpoint(shipped)))
        soup = tmp_path / f"round{number}.pt"
        average_checkpoints([shipped, tuned], soup)
        shipped = soup
        sizes.append(soup.stat().st_size)
    growth = np.diff(sizes)
    assert growth.max() < 1.5 * growth.min(), sizes
    runs = lineage(read_checkpoint(shipped))
    assert [r["train_config"]["command"] for r in runs] == [f"run {n}" for n in range(7)]


def test_a_run_on_merged_datasets_names_each_source_in_its_card(tiny_dataset, tmp_path):
    other = tmp_path / "other"
    generate(GenerateConfig(models=3, views=1, size=128, seed=1), other, progress=False)
    merged = tmp_path / "both"
    assert data_main(["merge", "--out", str(merged), str(tiny_dataset), str(other)]) == 0
    out = tmp_path / "r"
    fit = ["fit", "--data", str(merged), "--out", str(out), "--preset", "smoke"]
    assert train_main([*fit, "--fsnet-epochs", "1", "--epochs", "0"]) == 0
    _, state = load_checkpoint(out / "best_stage1.pt")
    assert state["dataset"]["command"].startswith("sdc-data merge --out")
    assert [m["frames"] for m in state["dataset"]["merged_from"]] == [6, 3]
    card = tmp_path / "card.md"
    assert eval_main(["card", "--checkpoint", str(out / "best_stage1.pt"), "--out", str(card)]) == 0
    (data,) = [line for line in card.read_text().splitlines() if line.startswith("- Data:")]
    assert "--seed 0` (6 frames)" in data and "--seed 1` (3 frames)" in data
    assert "None" not in data


def test_init_weights_of_another_variant_is_refused(run, tiny_dataset, tmp_path, capsys):
    fit = ["fit", "--data", str(tiny_dataset), "--out", str(tmp_path / "r"), "--preset", "smoke"]
    assert train_main([*fit, "--variant", "baseline", "--init-weights", str(run / "best.pt")]) == 2
    assert "another architecture" in capsys.readouterr().err


def test_a_calibrated_wide_model_fine_tunes_with_its_own_flags_and_calibration(
    run, tiny_dataset, tmp_path, capsys
):
    """The shipped model is calibrated (sigma's coefficients) and has a wide FSNet: fine-tuning
    it needs --fsnet-growth (a clear refusal without) and keeps its calibration."""
    source, _ = load_checkpoint(run / "best.pt")
    wide = build_model("sdcnet", fsnet_growth=2)
    transplant_weights(wide, source.state_dict())
    shipped = with_sigma(wide, 0.4, 0.3)
    save_checkpoint(tmp_path / "shipped.pt", shipped)
    fit = ["fit", "--data", str(tiny_dataset), "--preset", "smoke", "--epochs", "0"]
    fit += ["--init-weights", str(tmp_path / "shipped.pt")]
    assert train_main([*fit, "--out", str(tmp_path / "narrow")]) == 2
    assert "fsnet_growth 2 (this run: 1)" in capsys.readouterr().err
    assert train_main([*fit, "--out", str(tmp_path / "ft"), "--fsnet-growth", "2"]) == 0
    tuned, _ = load_checkpoint(tmp_path / "ft" / "best_stage1.pt")
    assert tuned.config.fsnet_growth == 2
    assert (tuned.config.sigma_per_scale, tuned.config.sigma_edge_weight) == (0.4, 0.3)


def test_a_warm_start_that_keeps_the_depth_networks_keeps_their_sigma_calibration(
    run, tiny_dataset, tmp_path
):
    """``--warm-start`` into an FSNet with the context branch (``--fsnet-context``, a switch):
    FDCNet's weights come over whole, so sigma's calibration comes with them; ``--no-fsnet-
    context`` builds the plain network."""
    source, _ = load_checkpoint(run / "best.pt")
    save_checkpoint(tmp_path / "calibrated.pt", with_sigma(source, 0.4, 0.3))
    fit = ["fit", "--data", str(tiny_dataset), "--preset", "smoke", "--epochs", "0"]
    fit += ["--warm-start", str(tmp_path / "calibrated.pt")]
    assert train_main([*fit, "--out", str(tmp_path / "ctx"), "--fsnet-context"]) == 0
    tuned, _ = load_checkpoint(tmp_path / "ctx" / "best_stage1.pt")
    assert tuned.config.fsnet_context and tuned.fsnet.context is not None
    assert (tuned.config.sigma_per_scale, tuned.config.sigma_edge_weight) == (0.4, 0.3)
    assert train_main([*fit, "--out", str(tmp_path / "plain"), "--no-fsnet-context"]) == 0
    plain, _ = load_checkpoint(tmp_path / "plain" / "best_stage1.pt")
    assert not plain.config.fsnet_context and plain.fsnet.context is None


def test_segmentation_only_evaluation_reports_the_mask_alone(run, tiny_dataset, tmp_path, capsys):
    report = tmp_path / "seg.json"
    args = ["evaluate", "--data", str(tiny_dataset), "--split", "test", "--out", str(report)]
    best = str(run / "best.pt")
    assert eval_main([*args, "--checkpoint", best, best]) == 2
    assert "--names" in capsys.readouterr().err
    names = ["--names", "first", "second", "--segmentation-only"]
    assert eval_main([*args, "--checkpoint", best, best, *names]) == 0
    table = capsys.readouterr().out
    assert "| first |" in table and "| n/a |" in table
    first, second = json.loads(report.read_text())["results"].values()
    assert first == second and 0.0 < first["IOU"] <= 1.0
    assert math.isnan(first["MAEI"]) and math.isnan(first["RMSTE"])


def test_evaluate_appends_rows_made_on_the_same_frames(run, tiny_dataset, tmp_path, capsys):
    report = tmp_path / "table.json"
    args = ["evaluate", "--data", str(tiny_dataset), "--split", "test", "--out", str(report)]
    best = ["--checkpoint", str(run / "best.pt"), "--segmentation-only"]
    assert eval_main([*args, *best, "--names", "(b) second"]) == 0
    assert eval_main([*args, "--floor", "--append"]) == 0
    assert eval_main([*args, *best, "--names", "(a) first", "--append"]) == 0
    rows = json.loads(report.read_text())["results"]
    assert list(rows) == ["(a) first", "(b) second", "classical fill"]
    assert rows["(a) first"]["IOU"] == rows["(b) second"]["IOU"]
    assert eval_main([*args, "--floor", "--append", "--limit", "1"]) == 2
    assert "other frames" in capsys.readouterr().err
    assert list(json.loads(report.read_text())["results"]) == list(rows), "left untouched"


def one_line(err: str) -> str:
    """The one line a user error prints on stderr (never a traceback)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_fit_has_a_flag_of_each_train_config_field_of_its_type(capsys):
    """``sdc-train fit``'s flags are made from ``TrainConfig``'s fields: each one's name,
    type and choices; those not given are the preset's."""
    argv = ["fit", "--data", "d", "--out", "o", "--lr", "5e-4", "--samples-per-epoch", "3"]
    argv += ["--variant", "fsnet", "--warm-start", "w.pt"]
    args = train_parser().parse_args(argv)
    given = {"data": "d", "out": "o", "lr": 5e-4, "samples_per_epoch": 3, "variant": "fsnet"}
    given["warm_start"] = "w.pt"
    flags = {f.name for f in fields(TrainConfig)} - {"command"}
    assert {name: getattr(args, name) for name in flags} == {
        name: given.get(name) for name in flags
    }
    config = config_from_preset(args.preset, **{name: getattr(args, name) for name in flags})
    assert (config.lr, config.samples_per_epoch, config.epochs) == (5e-4, 3, 16)  # cpu preset
    for bad in (["--variant", "nope"], ["--epochs", "1.5"]):
        with pytest.raises(SystemExit):
            train_parser().parse_args([*argv, *bad])
    with pytest.raises(SystemExit):  # --data is required: TrainConfig has no default for it
        train_parser().parse_args(["fit", "--out", "o"])
    capsys.readouterr()
    with pytest.raises(SystemExit):
        train_parser().parse_args(["fit", "--help"])
    shown = " ".join(capsys.readouterr().out.split())
    assert "--fsnet-inputs {both,gray,sparse} what FSNet sees" in shown
    assert "--data DATA dataset directory (sdc-data generate)" in shown


def test_bad_arguments_give_clear_errors(tmp_path, capsys):
    assert train_main(["fit", "--data", str(tmp_path), "--out", str(tmp_path / "r")]) == 2
    assert "not an sdcnet dataset" in one_line(capsys.readouterr().err)


@pytest.mark.parametrize("flag", ["--init-weights", "--init-segmentation"])
def test_a_bad_checkpoint_to_start_from_is_one_line(flag, tiny_dataset, tmp_path, capsys):
    fit = ["fit", "--data", str(tiny_dataset), "--out", str(tmp_path / "r"), "--preset", "smoke"]
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint")
    assert train_main([*fit, flag, str(tmp_path / "garbage.pt")]) == 2
    assert one_line(capsys.readouterr().err).startswith(
        f"sdc-train: error: cannot read checkpoint {tmp_path / 'garbage.pt'}"
    )
    assert train_main([*fit, flag, str(tmp_path / "absent.pt")]) == 2
    assert one_line(capsys.readouterr().err) == (
        f"sdc-train: error: checkpoint not found: {tmp_path / 'absent.pt'}"
    )
    assert train_main(["--debug", *fit, flag, str(tmp_path / "garbage.pt")]) == 2
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "cannot read checkpoint" in err


def test_init_segmentation_from_a_checkpoint_without_fsnet_is_refused(
    tiny_dataset, tmp_path, capsys
):
    save_checkpoint(tmp_path / "baseline.pt", SDCNet(VARIANTS["baseline"]))
    fit = ["fit", "--data", str(tiny_dataset), "--out", str(tmp_path / "r"), "--preset", "smoke"]
    assert train_main([*fit, "--init-segmentation", str(tmp_path / "baseline.pt")]) == 2
    assert "holds no FSNet weights" in one_line(capsys.readouterr().err)


def test_fsnet_epochs_0_needs_a_trained_segmentation(run, tiny_dataset, tmp_path, capsys):
    fit = ["fit", "--data", str(tiny_dataset), "--preset", "smoke", "--fsnet-epochs", "0"]
    assert train_main([*fit, "--out", str(tmp_path / "fresh")]) == 2
    assert "--fsnet-epochs 0 on a fresh run" in one_line(capsys.readouterr().err)
    # from trained weights, it fine-tunes the depth networks alone
    tuned = tmp_path / "depth-only"
    assert train_main([*fit, "--out", str(tuned), "--init-weights", str(run / "best.pt")]) == 0
    rows = list(csv.DictReader((tuned / "log.csv").open()))
    assert [(r["stage"], r["epoch"]) for r in rows] == [("2", "1")]
    source, _ = load_checkpoint(run / "best.pt")
    model, _ = load_checkpoint(tuned / "best.pt")
    theirs, ours = source.state_dict(), model.state_dict()
    assert all(unchanged(theirs, ours, "fsnet."))
    assert not all(unchanged(theirs, ours, "fdcnet."))


def test_fit_runs_unchanged_under_torchrun(tiny_dataset, tmp_path):
    """Two processes, gloo on the CPU: DistributedDataParallel through both stages."""
    torchrun = Path(sys.executable).with_name("torchrun")
    out = tmp_path / "ddp"
    cmd = [
        str(torchrun),
        "--nproc-per-node",
        "2",
        "-m",
        "sdcnet.training.cli",
        "fit",
        "--data",
        str(tiny_dataset),
        "--out",
        str(out),
        "--preset",
        "smoke",
        "--samples-per-epoch",
        "4",
    ]
    done = subprocess.run(
        cmd, capture_output=True, text=True, timeout=300, env={**os.environ, "OMP_NUM_THREADS": "1"}
    )
    assert done.returncode == 0, done.stderr[-2000:]
    rows = list(csv.DictReader((out / "log.csv").open()))
    assert [r["stage"] for r in rows] == ["1", "2"], "one log, written by rank 0 only"
    assert (out / "best.pt").exists()


def test_train_samples_trains_on_that_many_frames_evenly_spread(tiny_dataset, tmp_path):
    from sdcnet.dataset_format import SampleStore
    from sdcnet.training.train import Trainer, config_from_preset

    every = SampleStore(tiny_dataset).split("train")
    assert len(every) == 2
    config = config_from_preset("smoke", data=str(tiny_dataset), out=str(tmp_path / "r"))
    assert Trainer(config).train_set.records == every
    config = config_from_preset(
        "smoke", data=str(tiny_dataset), out=str(tmp_path / "s"), train_samples=1
    )
    assert Trainer(config).train_set.records == every[:1]


def test_ship_zero_makes_an_ablation_copy(run, tmp_path, capsys):
    out = tmp_path / "new-folder" / "plane-alone.pt"  # made if missing
    best = str(run / "best.pt")
    assert (
        train_main(["ship", "--checkpoint", best, "--out", str(out), "--zero", "fdcnet.head"]) == 0
    )
    source, _ = load_checkpoint(run / "best.pt")
    ablated, state = load_checkpoint(out)
    theirs, ours = source.state_dict(), ablated.state_dict()
    head = [k for k in ours if k.startswith("fdcnet.head.")]
    assert head and all(not ours[k].any() for k in head)
    assert any(theirs[k].any() for k in head)
    assert all(torch.equal(theirs[k], ours[k]) for k in ours if k not in head)
    assert state["zeroed"] == ["fdcnet.head"]
    bad = ["ship", "--checkpoint", best, "--out", str(tmp_path / "x.pt"), "--zero", "no.such"]
    assert train_main(bad) == 2
    assert "no weights under that prefix" in capsys.readouterr().err
    assert not (tmp_path / "x.pt").exists()


def test_calibrate_scales_sigma_to_cover_68_percent_of_the_errors(
    run, tiny_dataset, tmp_path, capsys
):
    out = tmp_path / "calibrated.pt"
    args = ["calibrate", "--checkpoint", str(run / "best.pt"), "--data", str(tiny_dataset)]
    assert train_main([*args, "--split", "train", "--limit", "4", "--out", str(out)]) == 0
    assert "within 1 / 2 sigma" in capsys.readouterr().out
    before, _ = load_checkpoint(run / "best.pt")
    after, state = load_checkpoint(out)
    report = state["sigma_calibration"]
    assert report["within_1_after"] == pytest.approx(0.68, abs=0.01)
    assert report["within_2_after"] >= report["within_1_after"]
    # and what the scaled model's sigma covers through the pipeline, measured, not assumed
    store = SampleStore(tiny_dataset)
    served = error_ratios(after, store, store.split("train", 4))
    assert report["within_1_served"] == pytest.approx(np.mean(served <= 1))
    assert report["within_2_served"] == pytest.approx(np.mean(served <= 2))
    factor = after.config.sigma_per_scale / before.config.sigma_per_scale
    assert factor == pytest.approx(report["factor"])
    # the default depth-edge weight (0.5) joined the scale head's sigma, then both were scaled
    assert after.config.sigma_edge_weight == pytest.approx(0.5 * factor)
    measured = with_sigma(before, before.config.sigma_per_scale, 0.5)
    gray, sparse = torch.rand(1, 1, 64, 64), torch.zeros(1, 1, 64, 64)
    sparse[..., ::9, ::6] = 80.0
    focal = torch.full((1, 1, 1, 1), 2000.0)
    with torch.no_grad():
        d0, p0, s0 = measured(gray, sparse, focal)
        d1, p1, s1 = after(gray, sparse, focal)
    torch.testing.assert_close(d1, d0)  # only sigma changes, by the factor
    torch.testing.assert_close(p1, p0)
    torch.testing.assert_close(s1, factor * s0)
    assert state["train_config"] == load_checkpoint(run / "best.pt")[1]["train_config"]


def test_the_truth_on_the_working_grid_is_the_depth_under_each_pixels_centre():
    """The target is aligned with the inputs (the returns are placed at their pixel's centre):
    4 columns to 2 take columns 1 and 3, 2 to 5 take 0, 0, 1, 1, 1 (OpenCV's nearest took
    0 and 2, and 0, 0, 0, 1, 1: half a working pixel to the left)."""
    depth = np.repeat(np.array([[11, 12, 13, 14]], np.float32), 2, axis=0)
    np.testing.assert_array_equal(resample_truth(depth, (1, 2)), [[12, 14]])
    np.testing.assert_array_equal(resample_truth(depth[:, :2], (2, 5))[0], [11, 11, 12, 12, 12])
