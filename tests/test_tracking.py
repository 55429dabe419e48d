"""The client's tracker: each frame's init from the constant-velocity motion of the last two
usable answers, coasting over unreliable ones, starting afresh after a jump."""

from __future__ import annotations

import numpy as np

from sdcnet.client.api import PoseAnswer
from sdcnet.client.tracking import Tracker
from sdcnet.rigid import Pose, axis_angle, pose_errors


def steady(frame: int) -> Pose:
    """A target moving steadily: the same camera-frame motion (2 degrees, 0.5 m) per frame."""
    step = Pose(axis_angle([0.2, 1.0, 0.1], np.radians(2)), np.array([0.1, 0, -0.5])).matrix()
    start = Pose(axis_angle([1.0, 0, 0], 0.5), np.array([0.3, 0, 80.0])).matrix()
    return Pose.from_matrix(np.linalg.matrix_power(step, frame) @ start)


class Scripted:
    """A stand-in for ``Client``: answers frame k with ``steady(k)`` and the scripted verdict,
    and records the inits it was sent."""

    def __init__(self, verdicts: list[str], tracked: list[bool] | None = None):
        self.verdicts, self.tracked, self.inits = verdicts, tracked, []

    def pose(self, gray, sparse, target, init=None):
        k = len(self.inits)
        self.inits.append(init)
        tracked = init is not None if self.tracked is None else self.tracked[k]
        answer = {"verdict": self.verdicts[k], "tracked": tracked}
        return PoseAnswer(steady(k), answer)


def close(a: Pose | None, b: Pose) -> bool:
    rotation_deg, translation_m = pose_errors(a, b)
    return rotation_deg < 1e-6 and translation_m < 1e-9


def test_the_init_continues_a_steady_motion():
    client = Scripted(["reliable"] * 4)
    tracker = Tracker(client, "probe")
    for _ in range(4):
        tracker.pose(None, None)
    assert client.inits[0] is None  # from scratch
    assert close(client.inits[1], steady(0))  # one answer: itself
    assert close(client.inits[2], steady(2)) and close(client.inits[3], steady(3))


def test_unreliable_frames_are_coasted_over_then_the_search_runs():
    verdicts = ["reliable", "reliable", "unreliable", "unreliable", "reliable"]
    client = Scripted([*verdicts, "reliable"])
    tracker = Tracker(client, "probe", max_coast=1)
    for _ in range(6):
        tracker.pose(None, None)
    assert close(client.inits[2], steady(2)) and close(client.inits[3], steady(3))
    assert client.inits[4] is None  # two unreliable answers in a row: more than max_coast
    assert close(client.inits[5], steady(4))  # history restarted from frame 4


def test_an_answer_that_left_its_init_starts_the_motion_afresh():
    client = Scripted(["reliable"] * 4, tracked=[False, True, False, True])
    tracker = Tracker(client, "probe")
    for _ in range(4):
        tracker.pose(None, None)
    assert close(client.inits[2], steady(2))
    assert close(client.inits[3], steady(2))  # frame 2 left its init: no velocity across it
