"""The pose of a known target from a camera-frame point cloud: global search, GICP, scoring.

``TargetModel`` prepares a target's triangle mesh once (surface samples, a GICP cloud with
covariances, a distance field, what the target shows from many view directions);
``estimate_pose`` finds ``p_camera = R p_target + t`` for one observed cloud. The stages, one
module each:

- ``config``: ``RegistrationConfig``, the knobs of every stage.
- ``target``: ``TargetModel``, its distance field, self-symmetries and near twins; distances
  to its surface.
- ``observed``: the observed cloud prepared, and step 3, the consistency that scores a pose.
- ``refine``: ``Hypothesis`` and its GICP refinement (small_gicp) on the observed cloud.
- ``search``: steps 1-2, from scratch: the coarse search over views and rolls, then GICP.
- ``choice``: step 4, the answer among the refined poses, refined on the LIDAR returns, and
  its alternatives.
- ``covariance``: the answer's covariance, GICP's Hessian inflated for its overconfidence.
- ``verdict``: ``judge``, "reliable", "ambiguous" or "unreliable", and the reasons.
- ``estimate``: ``estimate_pose``, which runs the stages (or tracks from an initial pose),
  and its answer, ``PoseEstimate``.

Units: metres, radians inside, degrees where a name says so. Deterministic: the subsets are
drawn with fixed seeds.
"""

from sdcnet.registration.config import DEFAULT_CONFIG, RegistrationConfig
from sdcnet.registration.estimate import PoseEstimate, UnusableCloudError, estimate_pose
from sdcnet.registration.target import TargetModel
from sdcnet.registration.verdict import REASONS, Evidence, judge

__all__ = [
    "DEFAULT_CONFIG",
    "REASONS",
    "Evidence",
    "PoseEstimate",
    "RegistrationConfig",
    "TargetModel",
    "UnusableCloudError",
    "estimate_pose",
    "judge",
]
