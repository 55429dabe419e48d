"""The service's memory budget (docs/service.md, "Memory budget"): what one request may hold,
and what a pod needs, from the settings.

Every input is checked against ``max_pixels`` and ``max_upload_bytes`` before it is parsed,
and everything a request builds follows its frame's pixels (the network's own work is a fixed
``work_pixels`` per frame, one at a time), so an in-flight request holds at most its body,
``FIXED_MIB`` and ``BYTES_PER_PIXEL`` bytes per pixel of the largest frame. A request held in
another phase (receiving its body, waiting for a place, sending its answer) holds its spools'
memory, the rest of them on disk (``sdcnet.service.spool``).
"""

from __future__ import annotations

from dataclasses import dataclass

from sdcnet.service.settings import Settings
from sdcnet.service.spool import SPOOL_MEMORY_BYTES

MIB = 2**20
#: Resident memory of a warm service, MiB: SDCNet's graph on onnxruntime (2 threads, its
#: arena grown by one frame), Python and the libraries, after valid frames on every route;
#: measured 234 MiB. Each folder of targets (``--targets``) adds its own.
WARM_MIB = 240
#: Memory an in-flight request takes above the warm service beside its body: a fixed part,
#: MiB, and bytes per pixel of its frame. Fitted to the worst frames measured, all foreground
#: to the tiny model, outlier removal, a JSON answer (benchmarks.hostile B4, B8 and
#: tests/test_hostile.py): 80 to 91 MiB at 1024 x 1024 with a 0.5 MiB body, 248 to 259 and
#: 279 to 306 MiB at 2048 x 2048 with 12 and 40 MiB bodies (four runs).
FIXED_MIB = 40
BYTES_PER_PIXEL = 56
#: Bytes of the largest answer per pixel of its frame: a JSON answer of a frame all foreground
#: (float32 depth, uint8 mask, float32 sigma, float32 x, y, z and the normal's three per
#: pixel: 33 bytes, as base64).
ANSWER_BYTES_PER_PIXEL = 44


@dataclass(frozen=True)
class Budget:
    """What the settings let the service hold at most, MiB."""

    request_mib: float  # one in-flight request: its body and its frame's work
    memory_mib: float  # the pod: the warm service, max_in_flight requests, the spools
    disk_mib: float  # the temporary files of the spools and of multipart uploads

    def describe(self, settings: Settings) -> str:
        """One line for the log."""
        spooled = 2 * SPOOL_MEMORY_BYTES / MIB
        return (
            f"memory budget {self.memory_mib:.0f} MiB ({WARM_MIB} warm + "
            f"{settings.max_in_flight} x {self.request_mib:.0f} in flight + "
            f"{settings.max_requests} x {spooled:.0f} spooled), temporary files up to "
            f"{self.disk_mib:.0f} MiB"
        )


def budget(settings: Settings) -> Budget:
    """The memory and disk the settings allow the service to use at most."""
    upload = settings.max_upload_bytes
    request = FIXED_MIB + (BYTES_PER_PIXEL * settings.max_pixels + upload) / MIB
    spools = settings.max_requests * 2 * SPOOL_MEMORY_BYTES / MIB
    answer = ANSWER_BYTES_PER_PIXEL * settings.max_pixels
    disk = (settings.max_requests * (upload + answer) + settings.max_in_flight * upload) / MIB
    return Budget(request, WARM_MIB + settings.max_in_flight * request + spools, disk)
