"""Tracking a known target over a sequence of frames with ``Client.pose``: a constant-velocity
motion model picks each frame's ``init``, so that a user tracking a sequence need not write one.

    tracker = Tracker(Client(url), "juno")
    for gray, sparse in frames:  # equally spaced in time (the LIDAR's 10 Hz)
        answer = tracker.pose(gray, sparse)
        if answer.verdict == "reliable":
            use(answer.pose)

The prediction continues the camera-frame motion between the last two usable answers
(``sdcnet.rigid.extrapolate``), once per frame since the latest; after one usable answer it
is that answer. An "unreliable" answer is not used: the next frames coast on the prediction,
up to ``max_coast`` of them, then the search runs from scratch. An answer that left its init
(``tracked`` false) starts the motion afresh: the velocity across a jump means nothing.
"""

from __future__ import annotations

from typing import Any, Protocol

from sdcnet.client.api import PoseAnswer
from sdcnet.rigid import Pose, extrapolate


class PoseClient(Protocol):
    def pose(self, gray: Any, sparse: Any, target: str, **kwargs: Any) -> PoseAnswer: ...


class Tracker:
    """The pose of ``target`` frame after frame, each from the motion model's prediction."""

    def __init__(self, client: PoseClient, target: str, max_coast: int = 3):
        self.client = client
        self.target = target
        self.max_coast = max_coast  # unreliable frames in a row predicted over, at most
        self.history: list[Pose] = []  # the last two usable answers, consecutive frames
        self.coasted = 0  # unusable answers since the latest usable one

    def prediction(self) -> Pose | None:
        """The next frame's ``init``: None (search) before any usable answer, or after more
        than ``max_coast`` unusable ones in a row."""
        if not self.history or self.coasted > self.max_coast:
            return None
        if len(self.history) == 1:
            return self.history[-1]
        previous, latest = self.history
        for _ in range(self.coasted + 1):
            previous, latest = latest, extrapolate(previous, latest)
        return latest

    def pose(self, gray: Any, sparse: Any, **kwargs: Any) -> PoseAnswer:
        """``Client.pose`` of the next frame from the prediction (``kwargs`` as for it); the
        answer updates the motion model (``update``)."""
        answer = self.client.pose(gray, sparse, self.target, init=self.prediction(), **kwargs)
        self.update(answer)
        return answer

    def update(self, answer: PoseAnswer) -> None:
        """Take in the answer of the frame just predicted (see the module docstring)."""
        if answer.verdict == "unreliable":
            self.coasted += 1
            return
        consecutive = self.coasted == 0 and answer.answer.get("tracked")
        self.history = [*self.history[-1:], answer.pose] if consecutive else [answer.pose]
        self.coasted = 0
