"""Pose of a known target from a point cloud: exact recovery, symmetric targets, tracking,
poses and their JSON form."""

import json
from dataclasses import replace

import numpy as np
import pytest
import small_gicp
import trimesh

from sdcnet.camera import Intrinsics
from sdcnet.registration import (
    DEFAULT_CONFIG,
    REASONS,
    Evidence,
    RegistrationConfig,
    TargetModel,
    UnusableCloudError,
    estimate_pose,
    judge,
)
from sdcnet.registration.choice import choose_searched
from sdcnet.registration.observed import consistency, framed_by, observe
from sdcnet.registration.refine import Hypothesis
from sdcnet.registration.search import search as search_from_scratch
from sdcnet.rigid import (
    Pose,
    axis_angle,
    extrapolate,
    matrix_from_quaternion,
    parse_pose,
    pose_errors,
    quaternion_from_matrix,
    rotation_angle_deg,
)
from tests.support.targets import probe_mesh


def visible_samples(mesh: trimesh.Trimesh, pose: Pose, seed: int, cell: float = 0.02):
    """Camera-frame points of the surface the camera sees (x right, y down, z forward): dense
    samples of the mesh under ``pose``, the nearest per ``cell`` across the line of sight."""
    points, _ = trimesh.sample.sample_surface(mesh, 200_000, seed=seed)
    camera = pose.apply(np.asarray(points))
    u = np.floor(camera[:, 0] / camera[:, 2] * camera[:, 2].mean() / cell).astype(int)
    v = np.floor(camera[:, 1] / camera[:, 2] * camera[:, 2].mean() / cell).astype(int)
    order = np.lexsort((camera[:, 2], v, u))
    key = (u * 1_000_003 + v)[order]
    first = np.ones(len(order), bool)
    first[1:] = key[1:] != key[:-1]
    return camera[order[first]]


def symmetric_distance(model: TargetModel, a: Pose, b: Pose) -> float:
    """Mean distance (metres) from some of the target's samples posed by ``a`` to the nearest
    of all posed by ``b``: about half their spacing (~5 mm here) for poses that differ by a
    symmetry of the target, much more otherwise."""
    tree = small_gicp.KdTree(b.apply(model.surface))
    _, squared = tree.batch_nearest_neighbor_search(a.apply(model.surface[::20]))
    return float(np.mean(np.sqrt(squared)))


@pytest.fixture(scope="module")
def spacecraft():
    mesh = probe_mesh()
    return mesh, TargetModel(mesh.vertices, mesh.faces)


def test_a_cloud_sampled_under_a_known_pose_gives_that_pose(spacecraft):
    mesh, model = spacecraft
    truth = Pose(axis_angle([0.3, -1.0, 0.4], 2.2), np.array([0.8, -0.5, 120.0]))
    cloud = visible_samples(mesh, truth, seed=1)
    estimate = estimate_pose(model, cloud, returns=cloud)
    rotation_deg, translation_m = pose_errors(estimate.pose, truth)
    assert rotation_deg < 0.1 and translation_m < 1e-3
    assert not estimate.ambiguous and not estimate.tracked
    assert estimate.fitness > 0.95 and estimate.returns_rmse_m < 0.005
    assert estimate.rotation_sigma_deg < 0.1
    # A singular Hessian (no correspondence left) gives an infinite covariance: its sigmas
    # say so instead of failing to find eigenvalues.
    unconstrained = replace(estimate, covariance=np.full((6, 6), np.inf))
    assert unconstrained.rotation_sigma_deg == unconstrained.translation_sigma_m == np.inf


def test_tracking_refines_a_nearby_pose_and_falls_back_when_lost(spacecraft):
    mesh, model = spacecraft
    truth = Pose(axis_angle([1.0, 0.2, 0.1], 0.7), np.array([-1.0, 0.4, 90.0]))
    cloud = visible_samples(mesh, truth, seed=2)
    shift = np.array([0.2, -0.1, 0.2])
    near = Pose(axis_angle([0, 1, 1], np.radians(3)) @ truth.R, truth.t + shift)
    tracked = estimate_pose(model, cloud, returns=cloud, init=near)
    assert tracked.tracked and tracked.hypotheses == 1
    assert pose_errors(tracked.pose, truth)[0] < 0.1
    lost = Pose(axis_angle([0, 1, 0], np.pi / 2) @ truth.R, truth.t + np.array([3.0, 0, 0]))
    recovered = estimate_pose(model, cloud, returns=cloud, init=lost)
    assert not recovered.tracked and recovered.hypotheses > 1
    assert pose_errors(recovered.pose, truth)[0] < 0.1


def test_a_target_the_camera_frames_only_in_part_is_scored_and_found_on_that_part(spacecraft):
    """At 4.5 m a 60 degree camera of 512 x 512 frames a quarter of the 6.3 m probe's visible
    surface: scored on the whole target, even the true pose explains the cloud poorly and the
    search ends turned 180 degrees; given the camera, the truth is found and trusted."""
    mesh, model = spacecraft
    view = Intrinsics(443.0, 443.0, 255.5, 255.5, 512, 512)
    truth = Pose(axis_angle([0.2, 1.0, -0.3], 1.1), np.array([2.0, -0.5, 4.5]))
    seen = visible_samples(mesh, truth, seed=2, cell=0.01)
    cloud = seen[framed_by(seen, view)]
    assert 0.15 < len(cloud) / len(seen) < 0.35
    unbounded = consistency(model, truth, observe(cloud, model))
    framed = consistency(model, truth, observe(cloud, model, view))
    assert framed > 0.8 and framed - unbounded > 0.3
    estimate = estimate_pose(model, cloud, returns=cloud[::10], view=view)
    rotation_deg, translation_m = pose_errors(estimate.pose, truth)
    assert rotation_deg < 0.1 and translation_m < 0.01
    assert estimate.verdict == "reliable"


def test_thousands_of_returns_are_refined_on_a_bounded_share_to_the_same_pose(spacecraft):
    """A close target's returns (here 14,000 with 1 cm of noise, every second of them kept:
    ``max_refine_returns``) all score the candidates, but the ICP on them moves at most
    ``max_icp_returns``: 64 still land within a few millimetres."""
    mesh, _ = spacecraft
    model = TargetModel(mesh.vertices, mesh.faces, replace(DEFAULT_CONFIG, max_icp_returns=64))
    truth = Pose(axis_angle([0.3, -1.0, 0.4], 2.2), np.array([0.8, -0.5, 120.0]))
    cloud = visible_samples(mesh, truth, seed=1)
    returns = cloud + np.random.default_rng(0).normal(0, 0.01, cloud.shape)
    estimate = estimate_pose(model, cloud, returns)
    rotation_deg, translation_m = pose_errors(estimate.pose, truth)
    assert len(returns) > 10_000 and estimate.returns == len(returns[::2])
    assert rotation_deg < 0.2 and translation_m < 0.01
    assert estimate.verdict == "reliable" and estimate.returns_rmse_m < 0.015


@pytest.mark.parametrize("seed", [0, 1])
def test_candidates_ranked_on_a_few_returns_leave_the_answer_polished_on_more(spacecraft, seed):
    """Each candidate's ICP moves ``max_icp_returns`` returns (here 16, with 2 cm of noise):
    enough to rank the candidates, not to place the answer; its last refinement on
    ``polish_icp_returns`` does, unless the returns lie farther from the answer than
    ``polish_max_returns_error_m`` (here 0: never); the sigma of an answer left on 16 returns
    says it is loose."""
    mesh, _ = spacecraft
    truth = Pose(axis_angle([0.3, -1.0, 0.4], 2.2 + seed), np.array([0.8, -0.5, 120.0]))
    cloud = visible_samples(mesh, truth, seed=1)
    returns = cloud + np.random.default_rng(seed).normal(0, 0.02, cloud.shape)
    errors, reasons = {}, {}
    for polish_within in (DEFAULT_CONFIG.polish_max_returns_error_m, 0.0):
        config = replace(
            DEFAULT_CONFIG, max_icp_returns=16, polish_max_returns_error_m=polish_within
        )
        estimate = estimate_pose(TargetModel(mesh.vertices, mesh.faces, config), cloud, returns)
        errors[polish_within] = pose_errors(estimate.pose, truth)
        reasons[polish_within] = estimate.reasons
    assert reasons[DEFAULT_CONFIG.polish_max_returns_error_m] == []  # reliable
    assert reasons[0.0] == ["loose_rotation"]
    rotation_deg, translation_m = errors[DEFAULT_CONFIG.polish_max_returns_error_m]
    assert rotation_deg < 0.4 and translation_m < 0.005
    assert errors[0.0][0] > 0.9 and errors[0.0][1] > 0.01  # not polished: the candidates' own


def test_the_distance_field_leaves_out_no_point_within_reach_of_the_surface():
    """``DistanceField.near(points, reach)`` reads the distance at a cell's centre: a point
    within ``reach`` of the surface is always kept, one two cells beyond it never."""
    box = trimesh.creation.box((3.0, 2.0, 1.0))
    model = TargetModel(box.vertices, box.faces)
    field, reach = model.field, 0.2
    on_surface, faces = trimesh.sample.sample_surface(box, 2000, seed=0)
    outward = box.face_normals[faces]
    for distance in (0.0, 0.5 * reach, reach):
        assert field.near(on_surface + distance * outward, reach).all()
    assert not field.near(on_surface + (reach + 2 * field.cell) * outward, reach).any()


def test_the_camera_frames_what_lies_ahead_of_it_inside_its_image():
    view = Intrinsics(100.0, 100.0, 49.5, 49.5, 100, 100)
    points = np.array(
        [
            [0.0, 0.0, 10.0],  # the centre
            [4.9, 4.9, 10.0],  # the last pixel's centre, (99, 99)
            [5.1, 0.0, 10.0],  # right of the image
            [0.0, -5.1, 10.0],  # above it
            [0.0, 0.0, -10.0],  # behind the camera
        ]
    )
    assert framed_by(points, view).tolist() == [True, True, False, False, False]
    assert framed_by(points.reshape(5, 1, 3), view).shape == (5, 1)


@pytest.mark.parametrize(
    "shape",
    [trimesh.creation.box((3.0, 2.0, 1.0)), trimesh.creation.cylinder(1.0, 4.0, sections=48)],
    ids=["box", "cylinder"],
)
def test_a_symmetric_target_reports_its_ambiguity(shape):
    model = TargetModel(shape.vertices, shape.faces)
    assert model.symmetries, "its turns onto itself are found at preparation"
    truth = Pose(axis_angle([0.2, 1.0, -0.3], 1.1), np.array([0.1, 0.2, 60.0]))
    cloud = visible_samples(shape, truth, seed=3)
    estimate = estimate_pose(model, cloud, returns=cloud[::10])
    assert estimate.ambiguous and estimate.alternatives
    # Every answer puts the shape where the truth does, though the rotations differ by the
    # symmetry; a pose turned 5 degrees off does not.
    for pose in [estimate.pose] + [a.pose for a in estimate.alternatives]:
        assert symmetric_distance(model, pose, truth) < 0.015
    assert min(pose_errors(a.pose, estimate.pose)[0] for a in estimate.alternatives) > 10
    off = Pose(axis_angle([1.0, 0, 0], np.radians(5)) @ truth.R, truth.t)
    assert symmetric_distance(model, off, truth) > 0.03


@pytest.fixture(scope="module")
def box():
    shape = trimesh.creation.box((3.0, 2.0, 1.0))
    return shape, TargetModel(shape.vertices, shape.faces)


def near(truth: Pose, rotation_deg: float, translation_m: float, seed: int) -> Pose:
    """``truth`` turned ``rotation_deg`` about a random axis, moved ``translation_m``."""
    rng = np.random.default_rng(seed)
    axis, direction = rng.normal(size=3), rng.normal(size=3)
    R = axis_angle(axis / np.linalg.norm(axis), np.radians(rotation_deg)) @ truth.R
    return Pose(R, truth.t + translation_m * direction / np.linalg.norm(direction))


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("search", [False, True], ids=["refined", "searched"])
def test_a_symmetric_target_tracked_from_a_close_init_stays_in_its_basin(box, seed, search):
    """From 5 degrees and 0.3 m off, the answer is the truth, not one of its twins that fit
    as well: also when the search runs (``searched``: tracking made to fall back always)."""
    shape, model = box
    if search:
        config = RegistrationConfig(tracking_min_consistency=1.01)
        model = TargetModel(shape.vertices, shape.faces, config)
    truth = Pose(
        axis_angle([0.3, 1.0, -0.2 + 0.3 * seed], 0.6 + 0.5 * seed), np.array([0.2, -0.1, 50.0])
    )
    cloud = visible_samples(shape, truth, seed=seed)
    estimate = estimate_pose(model, cloud, returns=cloud[::10], init=near(truth, 5, 0.3, seed))
    rotation_deg, translation_m = pose_errors(estimate.pose, truth)
    assert rotation_deg < 2 and translation_m < 0.2
    assert estimate.tracked and "left_init" not in estimate.reasons
    assert estimate.verdict == "ambiguous"  # the twins fit as well: never "reliable"


@pytest.mark.parametrize("init", [False, True], ids=["scratch", "tracked"])
def test_a_cloud_that_fits_two_poses_as_well_is_never_reliable(box, init):
    shape, model = box
    truth = Pose(axis_angle([0.2, 1.0, -0.3], 1.1), np.array([0.1, 0.2, 60.0]))
    cloud = visible_samples(shape, truth, seed=3)
    estimate = estimate_pose(model, cloud, cloud[::10], near(truth, 3, 0.1, 0) if init else None)
    assert estimate.verdict == "ambiguous" and "symmetric_twins" in estimate.reasons


def test_a_cloud_that_fits_nothing_is_unreliable(spacecraft, box):
    """Points of a box registered to the probe, and a random blob to the box."""
    shape, box_model = box
    _, probe = spacecraft
    truth = Pose(axis_angle([0.2, 1.0, -0.3], 1.1), np.array([0.1, 0.2, 60.0]))
    blob = np.random.default_rng(0).normal(size=(3000, 3)) * 0.8 + truth.t
    for model, cloud in [(probe, visible_samples(shape, truth, seed=3)), (box_model, blob)]:
        estimate = estimate_pose(model, cloud, returns=cloud[::10])
        assert estimate.verdict == "unreliable" and "poor_fit" in estimate.reasons


@pytest.mark.parametrize("init", [False, True], ids=["scratch", "tracked"])
def test_a_cloud_the_returns_contradict_is_never_answered_reliable_elsewhere(spacecraft, init):
    """The completed cloud says one pose, the LIDAR returns another (60 degrees and 1.5 m
    away): a reliable answer must agree with the returns; one that follows the cloud must say
    the returns lie off it. (Before the returns' misfit was a reason, the tracked case
    answered "reliable" 49 degrees from the returns' pose.)"""
    mesh, model = spacecraft
    cloud_pose = Pose(axis_angle([0.3, -1.0, 0.4], 2.2), np.array([0.8, -0.5, 120.0]))
    turn = axis_angle([1.0, 0.0, 0.2], np.radians(60))
    truth = Pose(turn @ cloud_pose.R, cloud_pose.t + np.array([1.5, 0.0, 0.0]))
    cloud = visible_samples(mesh, cloud_pose, seed=1)
    returns = visible_samples(mesh, truth, seed=2)[::100]
    start = near(cloud_pose, 3, 0.1, 0) if init else None
    estimate = estimate_pose(model, cloud, returns, start)
    rotation_deg, translation_m = pose_errors(estimate.pose, truth)
    if estimate.verdict == "reliable":
        assert rotation_deg < 2 and translation_m < 0.2
    else:
        assert "returns_misfit" in estimate.reasons or (rotation_deg < 2 and translation_m < 0.2)
    follows_cloud = pose_errors(estimate.pose, cloud_pose)
    if follows_cloud[0] < 2 and follows_cloud[1] < 0.2:
        assert estimate.verdict == "unreliable" and "returns_misfit" in estimate.reasons


def test_an_answer_that_leaves_its_init_says_so(spacecraft):
    mesh, model = spacecraft
    truth = Pose(axis_angle([1.0, 0.2, 0.1], 0.7), np.array([-1.0, 0.4, 90.0]))
    cloud = visible_samples(mesh, truth, seed=2)
    lost = Pose(axis_angle([0, 1, 0], np.pi / 2) @ truth.R, truth.t + np.array([3.0, 0, 0]))
    estimate = estimate_pose(model, cloud, returns=cloud, init=lost)
    assert not estimate.tracked and "left_init" in estimate.reasons
    assert estimate.verdict == "ambiguous"
    fresh = estimate_pose(model, cloud, returns=cloud)
    assert fresh.verdict == "reliable" and fresh.reasons == []


GOOD = Evidence(
    consistency=0.9, runner_up_consistency=0.3, twins=0, points=500, returns=400, left_init=False
)


@pytest.mark.parametrize(
    "change, verdict, reason",
    [
        ({}, "reliable", None),
        ({"consistency": DEFAULT_CONFIG.reliable_min_consistency - 0.01}, "unreliable", "poor_fit"),
        ({"points": DEFAULT_CONFIG.reliable_min_points - 1}, "unreliable", "too_few_points"),
        ({"returns": 0}, "unreliable", "too_few_returns"),
        ({"twins": 1}, "ambiguous", "symmetric_twins"),
        ({"runner_up_consistency": 0.88}, "ambiguous", "close_alternative"),
        ({"runner_up_consistency": None}, "reliable", None),
        ({"rotation_sigma_deg": 2.5}, "ambiguous", "loose_rotation"),
        ({"rotation_sigma_deg": float("inf")}, "ambiguous", "loose_rotation"),
        ({"left_init": True}, "ambiguous", "left_init"),
        ({"left_init": True, "returns": 0}, "unreliable", "too_few_returns"),
        ({"returns_misfit": True}, "unreliable", "returns_misfit"),
    ],
)
def test_the_verdict_follows_from_the_evidence(change, verdict, reason):
    got, reasons = judge(Evidence(**{**GOOD.__dict__, **change}))
    assert got == verdict
    assert reasons == [] if reason is None else reason in reasons
    assert all(r in REASONS for r in reasons)


def test_an_asymmetric_real_shape_has_no_symmetry(spacecraft):
    _, model = spacecraft
    assert model.symmetries == []


def winged_box() -> trimesh.Trimesh:
    """A 2 x 1 x 1 m bus with one 1.2 x 2 m wing on its +y side, off its middle: no turn maps it
    onto itself, its 180-degree turn about the bus's long axis almost does (the bus)."""
    bus = trimesh.creation.box((2.0, 1.0, 1.0))
    wing = trimesh.creation.box((1.2, 2.0, 0.02))
    wing.apply_translation([0.4, 1.5, 0.0])
    return trimesh.util.concatenate([bus, wing])


def test_a_turn_that_almost_maps_the_target_onto_itself_is_a_near_twin_not_a_symmetry():
    mesh = winged_box()
    model = TargetModel(mesh.vertices, mesh.faces)
    assert model.symmetries == [] and len(model.near_twins) == 1
    assert rotation_angle_deg(model.near_twins[0][:3, :3], np.eye(3)) == pytest.approx(180, abs=5)
    strict = replace(DEFAULT_CONFIG, near_twin_tolerance_of_longest=0.0)
    assert TargetModel(mesh.vertices, mesh.faces, strict).near_twins == []
    box = trimesh.creation.box((3.0, 2.0, 1.0))  # its turns are symmetries, not near twins
    assert TargetModel(box.vertices, box.faces).near_twins == []


def test_the_search_offers_the_best_pose_turned_by_each_near_twin():
    """The search's starts lie 25 degrees apart at least, so a pose and its near twin seldom
    both start: the best is turned by each near twin, for the returns to tell them apart."""
    mesh = winged_box()
    model = TargetModel(mesh.vertices, mesh.faces)
    truth = Pose(axis_angle([0.4, 1.0, -0.2], 0.9), np.array([0.2, -0.1, 30.0]))
    hypotheses = search_from_scratch(
        model, observe(visible_samples(mesh, truth, seed=2), model, None), {}
    )
    best = hypotheses[0].pose.matrix()
    twin = Pose.from_matrix(best @ model.near_twins[0])
    assert min(rotation_angle_deg(h.pose.R, twin.R) for h in hypotheses[1:]) < 0.01


def test_a_pose_the_returns_fit_clearly_worse_is_no_close_alternative():
    """The completed cloud, decimetres from the surface, can find a near twin almost as
    consistent as the truth; the returns, centimetres from it, tell them apart: the twin (and
    a hypothesis the search found beside it) is neither an alternative nor the runner-up that
    makes an answer ``close_alternative``. Without returns it is that runner-up."""
    mesh = winged_box()
    model = TargetModel(mesh.vertices, mesh.faces)
    truth = Pose(axis_angle([0.4, 1.0, -0.2], 0.9), np.array([0.2, -0.1, 30.0]))
    twin = Pose.from_matrix(truth.matrix() @ model.near_twins[0])
    beside = Pose(axis_angle([0.0, 0.0, 1.0], np.radians(0.2)) @ twin.R, twin.t)
    returns = visible_samples(mesh, truth, seed=2)[::10]

    def hypotheses() -> list[Hypothesis]:
        return [Hypothesis(truth, 0.90), Hypothesis(twin, 0.88), Hypothesis(beside, 0.87)]

    told = choose_searched(model, hypotheses(), returns)
    assert pose_errors(told.best.pose, truth)[0] < 0.5
    assert told.alternatives == [] and told.runner_up_consistency is None
    assert choose_searched(model, hypotheses(), None).runner_up_consistency == 0.88


def test_a_cloud_too_small_or_too_large_or_not_finite_is_an_error(spacecraft):
    _, model = spacecraft
    with pytest.raises(UnusableCloudError, match="at least") as small:
        estimate_pose(model, np.array([[0.0, 0.0, 100.0]] * 5))
    assert small.value.code == "too_few_points"
    huge = np.random.default_rng(0).uniform(-1e6, 1e6, size=(500, 3))
    with pytest.raises(UnusableCloudError, match="spans") as large:
        estimate_pose(model, huge)
    assert large.value.code == "too_large"
    with pytest.raises(UnusableCloudError, match="at least"):  # infinite points are left out
        estimate_pose(model, np.full((500, 3), np.inf))


def test_quaternions_round_trip_and_poses_parse_from_json():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R = axis_angle(rng.normal(size=3), rng.uniform(0, np.pi))
        q = quaternion_from_matrix(R)
        assert q[0] >= 0 and np.isclose(np.linalg.norm(q), 1)
        np.testing.assert_allclose(matrix_from_quaternion(q), R, atol=1e-12)
    pose = Pose(axis_angle([1, 2, 3], 0.5), np.array([1.0, 2.0, 3.0]))
    as_json = json.loads(json.dumps(pose.as_dict()))
    from_R = parse_pose({"R": as_json["R"], "t": as_json["t"]})
    from_q = parse_pose({"quaternion_wxyz": as_json["quaternion_wxyz"], "t": as_json["t"]})
    for parsed in (from_R, from_q):
        assert pose_errors(parsed, pose)[0] < 1e-6 and pose_errors(parsed, pose)[1] < 1e-12


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ([1, 2, 3], "JSON object"),
        ({"R": np.eye(3).tolist()}, "'t' is missing"),
        ({"t": [0, 0, 1]}, "needs 'R'"),
        ({"R": [[1, 0], [0, 1]], "t": [0, 0, 1]}, "shape"),
        ({"R": (2 * np.eye(3)).tolist(), "t": [0, 0, 1]}, "not a rotation"),
        ({"R": np.diag([1, 1, -1]).tolist(), "t": [0, 0, 1]}, "not a rotation"),
        ({"quaternion_wxyz": [0, 0, 0, 0], "t": [0, 0, 1]}, "zero"),
        ({"quaternion_wxyz": ["1", 0, 0, 0], "t": [0, 0, 1]}, "numbers only"),
        ({"quaternion_wxyz": [1, 0, 0, 0], "t": [0, True, 1]}, "numbers only"),
        ({"quaternion_wxyz": [1, 0, 0, 0], "t": [0, 1e400, 1]}, "NaN or infinite"),
    ],
)
def test_a_malformed_pose_is_explained(value, message):
    with pytest.raises(ValueError, match=message):
        parse_pose(value)


def test_constant_velocity_prediction_continues_a_steady_motion():
    step = Pose(axis_angle([0.2, 1.0, 0.1], np.radians(1.5)), np.array([0.1, 0.0, -5.0]))
    first = Pose(axis_angle([1, 0, 0], 0.3), np.array([1.0, 2.0, 200.0]))
    second = Pose.from_matrix(step.matrix() @ first.matrix())
    third = Pose.from_matrix(step.matrix() @ second.matrix())
    predicted = extrapolate(first, second)
    assert pose_errors(predicted, third)[0] < 1e-5 and pose_errors(predicted, third)[1] < 1e-9
