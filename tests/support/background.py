"""Work that runs beside a test or a benchmark while it sends its requests: a loop in a
daemon thread for the length of a ``with`` block."""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from typing import Self


class BackgroundLoop(ABC):
    """Runs ``loop(stop)`` in a daemon thread from entering a ``with`` block to leaving it.

    Leaving sets ``stop`` and waits for ``loop`` to return, so whatever it recorded is complete
    once the block has ended. ``loop`` waits between its steps with ``stop.wait(seconds)``
    rather than sleeping, so that leaving the block does not wait out an interval."""

    @abstractmethod
    def loop(self, stop: threading.Event) -> None: ...

    def __enter__(self) -> Self:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self.loop, args=(self._stop,), daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
