"""glibc malloc settings for a process that completes frames (the service, its benchmarks).

Two costs of the C allocator's defaults show in the cost of every frame, not the median one:

- each thread that allocates gets an arena, up to 8 per core, and every arena keeps the freed
  buffers of the requests it served (tens of MB per 1024 x 1024 frame): without a cap, the
  resident memory climbs for minutes, a step each time another worker thread serves its first
  request (benchmarks.load --soak, random weights: 230 -> 310 MiB in 3 minutes; with 2
  arenas, flat and no slower). One arena: the memory the start-up's warm-up wrote on the main
  thread (``sdcnet.service.inference.warm_up``) is then the memory every worker thread's
  request reuses. The cap must be set before any library starts a thread
  (``sdcnet.service.launch``): set after them, the first 2048 x 2048 frames after start-up
  took three times a warm frame's milliseconds (``benchmarks.first_frames``);
- a frame's full-resolution maps (16 MB each for 2048 x 2048 float32) are above malloc's
  default mmap threshold, so each is mapped for one request and unmapped after it, and the
  next request faults every page in again, which made the pipeline's slow frames slower still
  (docs/development.md, "Measurements"). Served from the heaps and kept there, they are
  reused from request to request.

Each setting gives way to glibc's own environment variable where it is set; nothing happens on
other C libraries.
"""

from __future__ import annotations

import ctypes
import os

#: Arenas the process may use (M_ARENA_MAX; environment MALLOC_ARENA_MAX).
MALLOC_ARENAS = 1
#: Allocations up to this many bytes come from the heaps (M_MMAP_THRESHOLD; environment
#: MALLOC_MMAP_THRESHOLD_): glibc's ceiling for the setting on 64-bit systems, 32 MiB.
MMAP_THRESHOLD_BYTES = 32 * 2**20
#: Free memory a heap keeps rather than giving it back (M_TRIM_THRESHOLD; environment
#: MALLOC_TRIM_THRESHOLD_): more than one frame's work, so that the next frame finds it.
TRIM_THRESHOLD_BYTES = 2**30

_SETTINGS = (  # mallopt parameter, value, environment variable that overrides it
    (-8, MALLOC_ARENAS, "MALLOC_ARENA_MAX"),
    (-3, MMAP_THRESHOLD_BYTES, "MALLOC_MMAP_THRESHOLD_"),
    (-1, TRIM_THRESHOLD_BYTES, "MALLOC_TRIM_THRESHOLD_"),
)


def configure_malloc() -> None:
    """Apply the settings above (before any worker thread starts)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        for parameter, value, variable in _SETTINGS:
            if variable not in os.environ:
                libc.mallopt(parameter, value)
    except (OSError, AttributeError):
        pass
