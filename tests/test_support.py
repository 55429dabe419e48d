"""The helpers the tests and the benchmarks share, where they have behaviour of their own."""

from __future__ import annotations

import threading
import time

from tests.support.background import BackgroundLoop


class Counter(BackgroundLoop):
    def __init__(self, interval_s: float):
        self.interval_s = interval_s
        self.steps = 0

    def loop(self, stop: threading.Event) -> None:
        while not stop.wait(self.interval_s):
            self.steps += 1


def test_a_background_loop_runs_during_the_block_and_has_stopped_after_it():
    with Counter(0.01) as counter:
        time.sleep(0.2)
    steps = counter.steps
    time.sleep(0.05)
    assert steps > 0
    assert counter.steps == steps


def test_leaving_the_block_does_not_wait_out_the_interval():
    start = time.monotonic()
    with Counter(60.0):
        pass
    assert time.monotonic() - start < 5.0
