"""A frame's budget on this CPU (``sdcnet.frame_budget``), and the service's ``--frame-ms`` /
``--work-pixels``: a share of the frames' budget on a CPU too slow for the deadline (the
frames of large crops get fewer working pixels, the others keep them), all of it on one fast
enough, never less than half."""

import time
from dataclasses import replace

import httpx
import numpy as np
import pytest

from sdcnet.frame_budget import (
    DEADLINE_SHARE,
    MAX_RISE,
    MIN_SHARE,
    REFERENCE_MS,
    FrameBudget,
    ServedBudget,
    budget_at,
    calibrate,
    expected_p95_ms,
    fixed,
    reference_frame,
    share_within,
)
from sdcnet.pipeline import MIN_WORK_SHARE, complete, frame_work_pixels
from sdcnet.runtime.onnx import OnnxModel
from tests.support.serving import running_service
from tests.test_service import decoded, frame, frame_files, post

WORK = 512 * 512


def sleeping_model(seconds_per_budget: float, seen: list[int]):
    """A stand-in network that takes ``seconds_per_budget`` for every ``WORK`` pixels it is
    given: foreground where the gray image is lit, depth 20 m, sigma 0.1 m."""

    def run(gray: np.ndarray, sparse: np.ndarray, focal_px: np.ndarray):
        seen.append(gray.shape[2] * gray.shape[3])
        time.sleep(seconds_per_budget * seen[-1] / WORK)
        depth = np.full_like(gray, 20.0)
        return depth, (gray > 0.2).astype(np.float32), np.full_like(gray, 0.1)

    return run


def test_the_share_keeps_the_expected_p95_within_the_deadline_between_half_and_all():
    """A slower CPU gets a smaller share, down to ``MIN_SHARE``; a faster one all of it."""
    deadline = 100.0
    at_reference = share_within(REFERENCE_MS, deadline)
    assert MIN_SHARE < at_reference < 1.0
    assert expected_p95_ms(REFERENCE_MS, at_reference) == pytest.approx(DEADLINE_SHARE * deadline)
    slower = share_within(1.2 * REFERENCE_MS, deadline)
    assert MIN_SHARE < slower < at_reference, "a slower CPU gets fewer pixels"
    assert expected_p95_ms(1.2 * REFERENCE_MS, slower) == pytest.approx(DEADLINE_SHARE * deadline)
    assert share_within(0.5 * REFERENCE_MS, deadline) == 1.0, "never more than the whole"
    assert share_within(5 * REFERENCE_MS, deadline) == MIN_SHARE, "never less than half"
    assert share_within(REFERENCE_MS, 2 * deadline) > at_reference


def test_the_reference_frame_is_a_lit_disc_with_returns_on_it_and_gets_the_whole_budget():
    gray, sparse, K = reference_frame()
    assert gray.shape == sparse.shape == (K.height, K.width)
    returns = sparse > 0
    assert returns.sum() > 4000 and (gray[returns] > 0).all()
    seen: list[int] = []
    result = complete(sleeping_model(0.0, seen), gray, sparse, K.fx, 64, WORK)
    assert seen == [WORK], "its crop is resampled to the whole budget"
    assert result.mask.sum() == pytest.approx((gray > 0).sum(), rel=0.05)


def test_a_cpu_too_slow_gets_half_the_budget_and_says_it_misses_the_deadline():
    seen: list[int] = []
    budget = calibrate(sleeping_model(0.5, seen), 64, WORK, deadline_ms=100.0)
    assert max(seen) == WORK, "timed at the whole budget"
    assert budget.frame_share == MIN_SHARE
    assert budget.work_pixels == budget.model_work_pixels == WORK, "the network's cap stays"
    assert budget.reference_ms >= 500 and budget.met is False
    assert budget.expected_p95_ms > 100.0


def test_a_cpu_fast_enough_keeps_the_whole_budget():
    budget = calibrate(sleeping_model(0.0, []), 64, WORK, deadline_ms=60_000.0)
    assert budget.work_pixels == WORK and budget.frame_share == 1.0 and budget.met is True
    assert budget.reference_ms > 0 and budget.expected_p95_ms < 60_000.0


def test_a_share_of_the_budget_cuts_the_frames_of_large_crops_not_the_small():
    """``frame_share`` scales a frame's budget and its floor, not the network's cap."""
    small, large = (700 * 700, 300 * 300), (2048 * 2048, 900 * 900)
    assert frame_work_pixels(WORK, *small, frame_share=0.8) == WORK
    whole, share = (frame_work_pixels(WORK, *large, frame_share=f) for f in (1.0, 0.8))
    assert share < whole < WORK
    every_pixel = (2048 * 2048, 2048 * 2048)
    assert frame_work_pixels(WORK, *every_pixel, frame_share=0.8) == int(
        0.8 * MIN_WORK_SHARE * WORK
    )


def test_complete_takes_the_share_on_a_frame_of_large_own_work():
    """The same 2048 x 2048 frame, its returns across it: fewer working pixels at a share."""
    gray = np.full((2048, 2048), 150, np.uint8)
    sparse = np.zeros(gray.shape, np.float32)
    sparse[::8, ::8] = 20.0
    shapes = {}
    for share in (1.0, 0.6):
        seen: list[int] = []
        complete(sleeping_model(0.0, seen), gray, sparse, 2000.0, 64, WORK, frame_share=share)
        shapes[share] = seen[0]
    assert shapes[0.6] < shapes[1.0] <= MIN_WORK_SHARE * WORK


@pytest.mark.parametrize("pixels", [0, WORK + 1])
def test_a_fixed_budget_is_at_most_the_models(pixels):
    with pytest.raises(ValueError, match="between 1 and the model's 262144"):
        fixed(pixels, WORK)


def test_the_service_answers_at_the_budget_it_chose_and_says_how(tiny_model_path, tmp_path):
    """``--work-pixels`` fixes the budget (GET /model says so) and the answers are the
    in-process pipeline's at that budget, not at the model's own."""
    s = frame()
    model = OnnxModel(tiny_model_path, provider="cpu", threads=1)
    own = model.info.work_pixels
    fewer = own // 16
    with (
        running_service(tiny_model_path, tmp_path / "fixed.log", f"--work-pixels={fewer}") as url,
        httpx.Client(base_url=url, timeout=60) as http,
    ):
        meta = http.get("/model").json()
        answer = post(http, frame_files()).json()
    assert meta["work_pixels"] == fewer
    assert meta["frame_budget"] == {
        "work_pixels": fewer,
        "model_work_pixels": own,
        "frame_share": 1.0,
        "deadline_ms": 0.0,
        "reference_ms": None,
        "expected_p95_ms": None,
        "met": None,
        "served_frames": 0,
        "served_p95_ms": None,
    }
    fx = model.info.intrinsics.scaled(256, 256).fx
    at_fewer = complete(model.run, s.gray, s.sparse, fx, model.stride, fewer)
    at_own = complete(model.run, s.gray, s.sparse, fx, model.stride, own)
    assert at_fewer.grid.shape != at_own.grid.shape
    np.testing.assert_array_equal(decoded(answer["depth"]), at_fewer.depth)
    np.testing.assert_array_equal(decoded(answer["mask"]), at_fewer.mask.astype(np.uint8))


def test_the_service_measures_its_cpu_for_the_deadline_by_default(tiny_model_path, tmp_path):
    """--frame-ms measures the CPU at start-up; the served frames re-read it every quarter
    of --budget-window (here 8 frames: every 2nd), and GET /model tells how many were served
    and their p95."""
    args = ("--frame-ms=60000", "--budget-window=8")
    with (
        running_service(tiny_model_path, tmp_path / "timed.log", *args) as url,
        httpx.Client(base_url=url, timeout=60) as http,
    ):
        chosen = http.get("/model").json()["frame_budget"]
        for _ in range(3):
            assert post(http, frame_files()).status_code == 200
        served = http.get("/model").json()["frame_budget"]
    assert chosen["deadline_ms"] == 60_000 and chosen["met"] is True
    assert chosen["work_pixels"] == chosen["model_work_pixels"] and chosen["frame_share"] == 1.0
    assert chosen["reference_ms"] > 0 and 0 < chosen["expected_p95_ms"] < 60_000
    assert chosen["served_frames"] == 0 and chosen["served_p95_ms"] is None
    assert served["served_frames"] == 3 and 0 < served["served_p95_ms"] < 60_000
    assert served["frame_share"] == 1.0 and served["met"] is True, "fast enough: all of it"
    assert served["reference_ms"] != chosen["reference_ms"], "re-read from the frames served"


def calibrated(reference_ms: float, deadline_ms: float = 100.0) -> FrameBudget:
    return budget_at(reference_ms, WORK, deadline_ms)


def serve(served: ServedBudget, milliseconds: float, frames: int) -> None:
    """``frames`` frames of ``milliseconds`` each, at the share of the moment."""
    for _ in range(frames):
        served.observe(milliseconds, served.budget.frame_share)


def test_served_frames_slower_than_expected_lower_the_share():
    """The share follows the served frames' p95 toward DEADLINE_SHARE of the deadline: frames
    slower than the calibration expected lower it, re-read every quarter window."""
    start = calibrated(REFERENCE_MS)
    served = ServedBudget(start, window=16)
    serve(served, start.expected_p95_ms * 1.2, 3)
    assert served.budget.frame_share == start.frame_share, "re-read every 4th frame only"
    serve(served, start.expected_p95_ms * 1.2, 1)
    slower = served.budget
    assert slower.served_frames == 4
    assert slower.served_p95_ms == pytest.approx(start.expected_p95_ms * 1.2, abs=1e-3)
    assert slower.frame_share < start.frame_share
    assert slower.reference_ms == pytest.approx(1.2 * REFERENCE_MS, rel=1e-3)
    assert slower.expected_p95_ms == pytest.approx(DEADLINE_SHARE * 100.0, abs=0.01)


def test_the_share_climbs_by_steps_and_falls_at_once(caplog):
    """Fast frames raise the share by ``MAX_RISE`` a re-reading, up to all of it; frames far
    too slow take it to ``MIN_SHARE`` at the next re-reading, and the move is logged."""
    caplog.set_level("INFO", logger="sdcnet.frame_budget")
    served = ServedBudget(calibrated(5 * REFERENCE_MS), window=8)
    assert served.budget.frame_share == MIN_SHARE
    shares = []
    for _ in range(6):
        serve(served, 1.0, 2)
        shares.append(served.budget.frame_share)
    assert shares == pytest.approx([min(1.0, MIN_SHARE + k * MAX_RISE) for k in range(1, 7)])
    assert served.budget.met is True
    serve(served, 10_000.0, 2)
    assert served.budget.frame_share == MIN_SHARE and served.budget.met is False
    assert "frames now get 0.50 of their budget (was 1.00)" in caplog.text


def test_frames_served_at_a_smaller_share_imply_the_same_cpu():
    """A frame's milliseconds are read at the share it was served at: the p95 the constants
    expect at that share keeps the share where it is."""
    start = calibrated(1.3 * REFERENCE_MS)
    served = ServedBudget(start, window=8)
    serve(served, start.expected_p95_ms, 8)
    assert served.budget.frame_share == pytest.approx(start.frame_share, abs=1e-3)


@pytest.mark.parametrize(
    "budget, window",
    [(fixed(WORK // 4, WORK), 8), (calibrated(REFERENCE_MS), 0)],
    ids=["fixed by the operator", "window 0"],
)
def test_a_budget_not_re_read_only_counts_its_frames(budget, window):
    served = ServedBudget(budget, window=window)
    serve(served, 10_000.0, 20)
    assert served.budget == replace(budget, served_frames=20)


def test_a_negative_window_is_refused():
    with pytest.raises(ValueError, match="window must be 0"):
        ServedBudget(calibrated(REFERENCE_MS), window=-1)
