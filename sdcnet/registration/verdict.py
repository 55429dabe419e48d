"""The verdict on an answer (``judge``): "reliable" (use it as it is), "ambiguous" (a
plausible pose, but another competes: a symmetric twin, a close runner-up, the track's init;
or the frame pins its rotation loosely) or "unreliable" (the cloud does not support it), with
the reasons."""

from __future__ import annotations

from dataclasses import dataclass

from sdcnet.registration.config import DEFAULT_CONFIG, RegistrationConfig

#: Why an answer is not "reliable": the code, whether it makes the answer "unreliable" (else
#: "ambiguous"), and what it means.
REASONS: dict[str, tuple[bool, str]] = {
    "poor_fit": (True, "the target at this pose explains the cloud poorly (low consistency)"),
    "too_few_points": (True, "too few points of the cloud to register"),
    "too_few_returns": (True, "too few LIDAR returns to check the pose against"),
    "returns_misfit": (True, "the LIDAR returns lie off the target at this pose"),
    "symmetric_twins": (
        False,
        "other poses (a symmetric or near-symmetric target) fit the frame as well",
    ),
    "close_alternative": (False, "another pose fits the frame almost as well"),
    "loose_rotation": (False, "the frame pins the rotation loosely: see its sigma"),
    "left_init": (False, "the answer left the basin of the tracker's init"),
}


@dataclass(frozen=True)
class Evidence:
    """What the verdict is drawn from: the answer's scores (see ``PoseEstimate``)."""

    consistency: float
    runner_up_consistency: float | None
    twins: int  # alternatives that fit as well
    points: int
    returns: int
    left_init: bool
    returns_misfit: bool = False  # the returns' distance above ``reliable_max_returns_error_m``
    rotation_sigma_deg: float = 0.0  # the answer's, along its least certain axis


def judge(evidence: Evidence, config: RegistrationConfig = DEFAULT_CONFIG) -> tuple[str, list[str]]:
    """The verdict on an answer and its reasons (``REASONS``), from its ``evidence`` and the
    ``reliable_*`` thresholds of ``config``: "unreliable" when a reason says so, else
    "ambiguous" when any reason holds, else "reliable"."""
    e = evidence
    lead = None if e.runner_up_consistency is None else e.consistency - e.runner_up_consistency
    checks = {
        "poor_fit": e.consistency < config.reliable_min_consistency,
        "too_few_points": e.points < config.reliable_min_points,
        "too_few_returns": e.returns < config.reliable_min_returns,
        "returns_misfit": e.returns_misfit,
        "symmetric_twins": e.twins > 0,
        "close_alternative": e.twins == 0 and lead is not None and lead < config.reliable_min_lead,
        "left_init": e.left_init,
        "loose_rotation": e.rotation_sigma_deg > config.reliable_max_rotation_sigma_deg,
    }
    reasons = [code for code, holds in checks.items() if holds]
    if any(REASONS[code][0] for code in reasons):
        return "unreliable", reasons
    return ("ambiguous" if reasons else "reliable"), reasons
