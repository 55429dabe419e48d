"""The knobs of the registration: search, refinement, scoring and the verdict's thresholds."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RegistrationConfig:
    """Knobs of the search, refinement and scoring; sizes relative to the target's longest
    extent ``L`` where a size is named ``*_of_longest``."""

    views: int = 96  # view directions of the coarse search (Fibonacci sphere)
    rolls: int = 24  # roll steps about the line of sight per view
    coarse_points: int = 128  # observed points scored per coarse hypothesis
    hypotheses: int = 6  # best distinct coarse hypotheses refined by GICP
    finalists: int = 2  # of those, the most consistent refined again, finely
    retry_below_consistency: float = 0.5  # when the best is below this, refine
    retry_hypotheses: int = 12  # ... this many more
    separation_deg: float = 25.0  # refined hypotheses start at least this far apart
    samples_per_longest: float = 500  # target surface samples about L / this apart,
    samples: tuple[int, int] = (100_000, 200_000)  # ... within these counts
    voxel_of_longest: float = 1 / 32  # the observed cloud is downsampled to this voxel
    coarse_voxel_of_longest: float = 1 / 16  # ... and to this one for the hypotheses' GICP
    max_cloud_points: int = 50_000  # larger clouds are thinned first (every k-th point)
    max_refine_returns: int = 8192  # LIDAR returns refined on, at most: more are thinned
    max_icp_returns: int = 512  # ... of which each candidate's ICP moves at most this many,
    polish_icp_returns: int = 2048  # ... and the answer's last refinement this many
    polish_max_returns_error_m: float = 0.06  # ... unless they lie farther than this from it
    max_scored_returns: int = 2048  # returns a pose's fit to them is measured on, at most
    field_cell_of_longest: float = 1 / 48  # distance field cell
    coarse_truncation_of_longest: float = 0.05  # distances above it score the same
    grid_cell_of_longest: float = 1 / 40  # cell of the consistency grid
    ambiguity_margin: float = 0.04  # consistency within this of the best: an alternative
    returns_margin: float = 0.1  # ... with returns: within this, refined on them to choose
    alternative_deg: float = 10.0  # ... when at least this far from the best in rotation
    duplicate_deg: float = 0.5  # hypotheses closer than this are one (refined on returns once)
    max_candidates: int = 6  # the answer and its alternatives, at most
    tracking_min_consistency: float = 0.5  # below it, tracking falls back to the search
    min_points: int = 12  # fewer observed points than this: no pose
    leave_init_margin: float = 0.05  # tracking leaves the init's pose for one this more consistent
    init_basin_deg: float = 25.0  # an answer within this rotation of init,
    init_basin_of_longest: float = 0.5  # ... and this translation (x L), is in the init's basin
    # The verdict (``judge``): below or within these, an answer is not "reliable".
    reliable_min_consistency: float = 0.5  # poor_fit below it (unreliable)
    reliable_min_points: int = 20  # too_few_points: downsampled cloud points (unreliable)
    reliable_min_returns: int = 12  # too_few_returns: LIDAR returns refined on (unreliable)
    # returns_misfit: the returns' mean distance to the target (truncated at a third of
    # returns_max_distance_m) above this, metres. Right answers measured 0.008 median, 0.017 at
    # most, the wrong ones marked reliable before 0.053-0.055 (68 frames, the paper's LIDAR:
    # docs/pose/README.md); Gaussian range noise of sigma gives about 0.8 sigma, so a LIDAR
    # noisier than ~3.5 cm needs a larger value
    reliable_max_returns_error_m: float = 0.03
    # close_alternative: a pose >= alternative_deg away within this consistency, unless the
    # returns fit it clearly worse (returns_ambiguity_ratio)
    reliable_min_lead: float = 0.06
    # loose_rotation: the answer's rotation sigma (``PoseEstimate.rotation_sigma_deg``) above
    # this, degrees: it cannot vouch for the 2 degrees a right answer is held to. Right answers
    # marked reliable measured 0.18 median, 1.45 at most; two wrong ones 2.9 and 3.1 (780
    # suite frames: docs/pose/README.md)
    reliable_max_rotation_sigma_deg: float = 2.0
    max_span_of_longest: float = 20.0  # a cloud wider than this (x L): no pose
    returns_max_distance_m: float = 0.5  # correspondence gate of the returns' refinement
    returns_ambiguity_ratio: float = 1.25  # alternatives whose returns fit this close
    # ... to the larger of the answer's fit and this, metres: noise-free returns fit a pose
    # within a millimetre and its symmetric twin, refined for fewer iterations, within 3
    returns_error_floor_m: float = 0.004
    returns_voxel_of_longest: float = 1 / 200
    # the returns' mean distance to the target (truncated) at the search's answer above which
    # the search runs on the returns too: right answers 0.008 m median, wrong ones >= 0.02
    returns_doubt_m: float = 0.015
    voxelmap_of_longest: float = 1 / 24  # voxels of the target for the hypotheses' VGICP
    symmetry_tolerance_of_longest: float = 0.003  # see TargetModel._symmetries
    near_twin_tolerance_of_longest: float = 0.01  # see TargetModel._near_twins
    coarse_iterations: int = 8  # GICP iterations per hypothesis, then per finalist:
    fine_iterations: int = 15
    ranking_iterations: int = 8  # ... each candidate's precise stage on the returns
    final_iterations: int = 20  # ... and the answer's on more of them, until a step moves less than
    final_step_deg: float = 1e-3
    final_step_m: float = 1e-5


DEFAULT_CONFIG = RegistrationConfig()
