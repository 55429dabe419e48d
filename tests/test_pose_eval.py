"""The pose evaluation's bookkeeping: success, frames without a pose, the tables."""

import math

import pytest

from sdcnet.training.pose_eval import FrameResult, report, summary


def _frame(rotation_deg: float, translation_m: float, cloud: str = "completed", **kw):
    fields = dict(
        spacecraft="a",
        cloud=cloud,
        mode="scratch",
        frame="m0000_v000",
        trajectory="",
        range_m=100.0,
        returns=50,
        rotation_deg=rotation_deg,
        translation_m=translation_m,
        ambiguous=False,
        among_answers=rotation_deg <= 2,
        registration_ms=10.0,
        cloud_ms=5.0,
    )
    return FrameResult(**{**fields, **kw})


def test_success_needs_both_errors_within_bounds_and_a_missing_pose_fails():
    frames = [_frame(1.0, 0.1), _frame(3.0, 0.1), _frame(1.0, 0.3), _frame(math.nan, math.nan)]
    s = summary(frames)
    assert s["frames"] == 4 and s["no_pose"] == 1
    assert s["success_pct"] == 25.0
    assert s["rotation_mean_deg"] == (1.0 + 3.0 + 1.0) / 3
    assert s["translation_mean_pct_range"] == pytest.approx(100 * (0.1 + 0.1 + 0.3) / 3 / 100.0)


def test_the_report_separates_clouds_modes_and_spacecraft():
    frames = [
        _frame(0.5, 0.01),
        _frame(0.4, 0.01, cloud="raw returns"),
        _frame(0.3, 0.01, mode="tracking", trajectory="tumble", spacecraft="b"),
    ]
    text, data = report({"run": frames}, ["completed", "raw returns"])
    assert list(data["run"]["overall"]) == ["completed", "completed, tracking", "raw returns"]
    assert "tumble, completed" in data["run"]["per_trajectory"]
    assert "b, completed, tracking" in data["run"]["per_spacecraft"]
    assert "### run" in text
