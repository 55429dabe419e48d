"""LIDAR kinds of the generator: patterns in the image, range noise, losses, parallax, draws."""

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import trimesh

from sdcnet.camera import PAPER_CAMERA, PAPER_LIDAR
from sdcnet.training.data.lidar import (
    LIDAR_KINDS,
    PAPER_SCANNER,
    FlashLidar,
    MultiBeamLidar,
    ScanningLidar,
    camera_fov_deg,
    lidar_from_metadata,
    sample_lidar,
    scan,
    scan_lidar,
)
from sdcnet.training.data.materials import Material, jittered_shading
from sdcnet.training.data.render import PosedModel, render_camera
from sdcnet.training.data.scene import Scene
from sdcnet.training.data.spacecraft import SpacecraftModel, _crinkle_waves

K = PAPER_CAMERA.intrinsics().scaled(256, 256)  # fx = fy = 1985 px, 7.38 deg across

#: A noise-free, loss-free LIDAR's common fields: patterns exactly where the beams point.
EXACT = {"range_noise_m": 0.0, "dropout": 0.0}


def plate(
    distance: float,
    size_m: float = 100.0,
    yaw_deg: float = 0.0,
    material: Material = Material.WHITE_PAINT,
) -> PosedModel:
    """A square plate, centre on the optical axis at ``distance``, turned by ``yaw_deg``
    about the camera's y axis (0: facing the camera, its front face at ``distance``)."""
    mesh = trimesh.creation.box((size_m, size_m, 0.01))
    rng = np.random.default_rng(0)
    model = SpacecraftModel(
        "plate",
        mesh,
        np.full(len(mesh.faces), material, np.int16),
        np.zeros((len(mesh.faces), 9)),
        jittered_shading(rng),
        _crinkle_waves(rng),
    )
    a = math.radians(yaw_deg)
    rotation = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    scene = Scene(rotation, np.array([0.0, 0.0, distance + 0.005]), np.array([0, 0, -1.0]), 0.0)
    return PosedModel.place(model, scene)


def returns(sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    v, u = np.nonzero(sparse)
    return u, v, sparse[v, u]


def range_error(sparse: np.ndarray, distance: float) -> np.ndarray:
    """Measured minus true range of the returns on a facing plate at ``distance``."""
    u, v, z = returns(sparse)
    cos = 1 / np.linalg.norm(K.pixel_rays(u, v), axis=1)  # Z = range * cos(beam angle)
    return (z - distance) / cos


def clusters(values: np.ndarray, gap: float = 3) -> list[np.ndarray]:
    values = np.sort(values)
    return np.split(values, np.flatnonzero(np.diff(values) > gap) + 1)


@pytest.mark.parametrize("kind", LIDAR_KINDS)
def test_every_kind_returns_on_the_mesh_within_its_noise(kind):
    posed = plate(60.0, size_m=5.0, yaw_deg=35.0)  # ~140 x 165 px: background all around
    truth = render_camera(posed, K, np.random.default_rng(0)).depth
    on_plate = cv2.dilate((truth > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    interior = cv2.erode((truth > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    gv, gu = np.gradient(truth.astype(np.float64))
    slope = 0.5 * (np.abs(gu) + np.abs(gv))  # depth change within half a pixel
    for seed in range(3):
        lidar = sample_lidar(np.random.default_rng([seed, 7]), K, kind)
        sparse = scan_lidar(posed, lidar, K, np.random.default_rng(seed))
        u, v, z = returns(sparse)
        assert len(u) > 10, f"{lidar} sees the plate"
        assert np.all(on_plate[v, u]), "returns only where the camera sees the mesh"
        inner = interior[v, u]
        bound = 3 * lidar.range_sigma(z[inner]) + slope[v, u][inner] + 1e-3
        assert np.all(np.abs(z[inner] - truth[v, u][inner]) <= bound)
        assert inner.mean() > 0.8


def test_paper_scanner_is_table_2_and_scans_as_the_spec():
    assert ScanningLidar.from_spec(PAPER_LIDAR) == PAPER_SCANNER
    assert sample_lidar(np.random.default_rng(0), K, "paper") == PAPER_SCANNER
    assert PAPER_SCANNER.range_noise_m * 3 == pytest.approx(PAPER_LIDAR.range_error_m)
    assert PAPER_SCANNER.offset_m == (0.0, 0.0, 0.0) and not PAPER_SCANNER.has_losses
    posed = plate(120.0, size_m=3.0, yaw_deg=20.0)
    old = scan(posed.caster, PAPER_LIDAR, K, np.random.default_rng(4))
    new = scan_lidar(posed, PAPER_SCANNER, K, np.random.default_rng(4))
    assert np.count_nonzero(new) > 20
    np.testing.assert_array_equal(old, new)  # casting only towards the mesh changes nothing
    with pytest.raises(ValueError, match="scan_lidar"):
        scan(posed.caster, replace(PAPER_SCANNER, dark_loss=0.5), K, np.random.default_rng(0))


@pytest.mark.parametrize("kind", LIDAR_KINDS)
def test_casting_only_towards_the_mesh_loses_no_return(kind):
    posed = plate(40.0, size_m=1.5, yaw_deg=50.0)  # ~75 px of the frame's 256
    for seed in range(3):
        lidar = sample_lidar(np.random.default_rng([seed, 8]), K, kind)
        lidar = replace(lidar, dark_loss=0.0, specular_loss=0.0)  # scan has no materials
        everywhere = scan(posed.caster, lidar, K, np.random.default_rng(seed))
        np.testing.assert_array_equal(
            scan_lidar(posed, lidar, K, np.random.default_rng(seed)), everywhere
        )


def test_grid_spacing_follows_its_angular_steps():
    du, dv = 6.0, 9.0  # pixels
    lidar = ScanningLidar(
        horizontal_step_deg=math.degrees(math.atan(du / K.fx)),
        vertical_step_deg=math.degrees(math.atan(dv / K.fy)),
        **EXACT,
    )
    u, v, z = returns(scan_lidar(plate(80.0), lidar, K, np.random.default_rng(2)))
    assert len(u) == pytest.approx(256 * 256 / (du * dv), rel=0.1), "the whole frame"
    centre = v == v[np.argmin(np.abs(v - K.cy))]
    assert np.median(np.diff(np.sort(u[centre]))) == pytest.approx(du, abs=1)
    assert np.median(np.diff(np.unique(v))) == pytest.approx(dv, abs=1)
    np.testing.assert_allclose(z, 80.0, atol=1e-3)


def test_multibeam_returns_lie_on_its_beam_rows():
    lidar = MultiBeamLidar(beams=16, vertical_fov_deg=20.0, azimuth_step_deg=0.1, **EXACT)
    u, v, _ = returns(scan_lidar(plate(60.0), lidar, K, np.random.default_rng(3)))
    rows = clusters(v)
    elevations = lidar.elevations_deg()
    half_v = math.degrees(math.atan((K.height / 2) / K.fy))
    visible = elevations[np.abs(elevations) < half_v - 0.05]
    assert len(rows) == len(visible) == 6 <= lidar.beams  # 1.33 deg apart, 7.38 deg frame
    centres = np.array([r.mean() for r in rows])
    np.testing.assert_allclose(centres, K.cy + K.fy * np.tan(np.radians(visible)), atol=1)
    spacing = K.fy * math.tan(math.radians(lidar.vertical_fov_deg / (lidar.beams - 1)))
    np.testing.assert_allclose(np.diff(centres), spacing, rtol=0.03)
    assert all(np.ptp(r) <= 1 for r in rows), "a beam sweeps one row (curving < 1 px here)"
    middle = v == rows[len(rows) // 2][0]
    step_px = K.fx * math.tan(math.radians(lidar.azimuth_step_deg))
    assert np.median(np.diff(np.sort(u[middle]))) == pytest.approx(step_px, abs=1)
    rolled = replace(lidar, tilt_deg=(0.0, 4.0))
    tu, tv, _ = returns(scan_lidar(plate(60.0), rolled, K, np.random.default_rng(3)))
    near = np.abs(tv - centres[2]) < 8  # the beam row around that of visible beam 2
    slope = np.polyfit(tu[near], tv[near], 1)[0]
    assert slope == pytest.approx(math.tan(math.radians(4.0)), abs=0.01), "rolled head: tilted rows"


def test_flash_array_is_dense_and_complete_on_a_plate_filling_its_view():
    fov_x, fov_y = camera_fov_deg(K)
    lidar = FlashLidar(columns=40, rows=30, fov_x_deg=0.6 * fov_x, fov_y_deg=0.5 * fov_y, **EXACT)
    u, v, z = returns(scan_lidar(plate(70.0), lidar, K, np.random.default_rng(0)))
    assert len(u) == 40 * 30
    assert len(np.unique(u)) == 40 and len(np.unique(v)) == 30
    pitch = K.fx * 2 * math.tan(math.radians(lidar.fov_x_deg / 2)) / 40
    assert np.diff(np.unique(u)) == pytest.approx(np.full(39, pitch), abs=1)
    assert np.ptp(u) == pytest.approx(39 * pitch, abs=1)
    assert abs(u.mean() - K.cx) < 1 and abs(v.mean() - K.cy) < 1, "on the boresight"
    np.testing.assert_allclose(z, 70.0, atol=1e-3)


def test_parallax_shifts_returns_by_the_baseline_over_the_distance():
    distance, b = 20.0, 0.2
    lidar = FlashLidar(columns=10, rows=10, fov_x_deg=3.0, fov_y_deg=3.0, **EXACT)
    here = returns(scan_lidar(plate(distance), lidar, K, np.random.default_rng(0)))
    offset = replace(lidar, offset_m=(b, 0.0, 0.0))
    there = returns(scan_lidar(plate(distance), offset, K, np.random.default_rng(0)))
    shift = K.fx * b / distance  # 19.85 px
    columns = np.unique(there[0]) - np.unique(here[0])  # each rounded to a pixel
    np.testing.assert_allclose(columns, shift, atol=1.0)
    assert columns.mean() == pytest.approx(shift, abs=0.3)
    np.testing.assert_array_equal(np.unique(there[1]), np.unique(here[1]))
    np.testing.assert_allclose(there[2], distance, atol=1e-3)


def test_range_noise_grows_with_range():
    lidar = ScanningLidar(
        horizontal_step_deg=0.1,
        vertical_step_deg=0.1,
        range_noise_m=0.01,
        range_noise_per_100m=0.04,
        dropout=0.0,
        max_range_m=300.0,
    )
    spread = {}
    for distance in (20.0, 250.0):
        sparse = scan_lidar(plate(distance), lidar, K, np.random.default_rng(5))
        error = range_error(sparse, distance)
        sigma = lidar.range_sigma(distance)
        assert len(error) > 3000
        assert np.abs(error).max() <= 3 * sigma + 1e-3, "clipped at 3 sigma"
        assert error.std() == pytest.approx(sigma, rel=0.1)
        spread[distance] = error.std()
    assert spread[250.0] > 4 * spread[20.0]  # sigma 0.11 m against 0.018 m
    short = replace(lidar, max_range_m=200.0)
    assert not np.any(scan_lidar(plate(250.0), short, K, np.random.default_rng(5))), "too far"


def test_dark_grazing_solar_cells_lose_returns_that_white_paint_keeps():
    lossy = ScanningLidar(
        horizontal_step_deg=0.1,
        vertical_step_deg=0.1,
        dropout=0.0,
        dark_loss=0.9,
        dark_threshold=0.1,
        specular_loss=1.0,
    )
    lossless = replace(lossy, dark_loss=0.0, specular_loss=0.0)
    white = plate(60.0)
    cells = plate(60.0, yaw_deg=75.0, material=Material.SOLAR_CELL)

    def count(posed, lidar, radius=np.inf):
        u, v, _ = returns(scan_lidar(posed, lidar, K, np.random.default_rng(6)))
        return np.count_nonzero(np.hypot(u - K.cx, v - K.cy) < radius)

    beams = count(white, lossless)
    assert count(cells, lossless) == beams, "without losses every beam returns"
    assert count(white, lossy) > 0.97 * beams, "bright paint at normal incidence keeps them"
    assert count(cells, lossy) < 0.3 * beams
    # a mirror returns at normal incidence: within 0.9 deg of the plate's normal
    mirror, centre = plate(60.0, material=Material.SOLAR_CELL), 30 * K.fx / 1985
    facing = count(mirror, replace(lossy, dark_loss=0.0), centre)
    assert facing > 0.95 * count(white, lossless, centre)


def test_sampled_lidars_cover_every_kind_in_range_and_round_trip_through_json():
    fov_x, _ = camera_fov_deg(K)
    drawn = {sample_lidar(np.random.default_rng(s), K).kind for s in range(60)}
    assert drawn == {"scanning", "multibeam", "flash", "rosette"}
    for kind in LIDAR_KINDS:
        for seed in range(20):
            lidar = sample_lidar(np.random.default_rng(seed), K, kind)
            meta = lidar.metadata()
            assert json.loads(json.dumps(meta)) == meta
            assert meta["kind"] == lidar.kind
            assert lidar_from_metadata(meta).metadata() == meta
            assert np.linalg.norm(lidar.offset_m) <= 0.31 and lidar.max_range_m >= 150
            if kind == "grid":
                for step, f in ((lidar.horizontal_step_deg, K.fx), (lidar.vertical_step_deg, K.fy)):
                    assert 2 - 1e-6 <= f * math.tan(math.radians(step)) <= 40 + 1e-6
            if kind == "multibeam":
                assert 16 <= lidar.beams <= 256 and 20 <= lidar.vertical_fov_deg <= 45
                assert 0.05 <= lidar.azimuth_step_deg <= 0.4
            if kind == "flash":
                assert 32 <= min(lidar.columns, lidar.rows) <= max(lidar.columns, lidar.rows) <= 256
                assert 0.3 * fov_x <= lidar.fov_x_deg <= fov_x
    with pytest.raises(ValueError, match="unknown LIDAR kind"):
        sample_lidar(np.random.default_rng(0), K, "sonar")


def test_a_seed_gives_the_same_lidar_and_returns():
    posed = plate(90.0, size_m=6.0, yaw_deg=30.0)
    for kind in LIDAR_KINDS:
        rngs = [(np.random.default_rng(s), np.random.default_rng(s)) for s in (11, 11, 12)]
        runs = [scan_lidar(posed, sample_lidar(a, K, kind), K, b) for a, b in rngs]
        np.testing.assert_array_equal(runs[0], runs[1])
        assert not np.array_equal(runs[0], runs[2])
