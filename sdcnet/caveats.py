"""What a completed frame's mask may not capture, said with the answer.

Sigma says how far each pixel's depth can be trusted; a frame can also be one whose mask as a
whole is less sure, and the answer says so by code (``POST /complete``'s ``caveats``). Each
code marks frames the robustness suite's masks scored markedly lower on (docs/service.md,
"Caveats"): fewer than ``FEW_RETURNS`` returns, where the image alone must say how far the
spacecraft reaches, and a LIDAR field that ended across the spacecraft, where what lies
beyond its edge comes from the image alone (most of the masks' misses on the other LIDARs).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the client prints the codes' meanings without the pipeline's imports
    from sdcnet.pipeline import Completion

#: A frame with fewer LIDAR returns than this gets the caveat ``few_returns``.
FEW_RETURNS = 20

#: Each caveat's code and what it means for the answer.
CAVEATS = {
    "few_returns": f"fewer than {FEW_RETURNS} LIDAR returns: how far the spacecraft reaches "
    "rests on the image alone; parts may be missing or background taken for it",
    "lidar_field_cut": "the LIDAR's field ended across the spacecraft: the mask past its edge "
    "comes from the image alone, and parts there may be missing",
}


def frame_caveats(completion: Completion, returns: int) -> list[str]:
    """The codes of ``CAVEATS`` that hold for a completed frame with ``returns`` LIDAR
    returns, in ``CAVEATS``' order; empty when none does."""
    holds = {
        "few_returns": returns < FEW_RETURNS,
        "lidar_field_cut": completion.cuts is not None,
    }
    return [code for code in CAVEATS if holds[code]]


def as_text(codes: list[str]) -> str:
    """``codes`` as one text, where only a scalar travels (the Open Inference Protocol's
    parameters, a PLY header's comment): joined by commas, empty for none."""
    return ",".join(codes)


def from_text(text: str) -> list[str]:
    """The codes of an ``as_text``."""
    return [code for code in text.split(",") if code]
