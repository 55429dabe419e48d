"""Point clouds: back-projection, statistical outlier removal on the pixel grid, binary PLY."""

import numpy as np
import pytest

from sdcnet.camera import PAPER_CAMERA
from sdcnet.pointcloud import (
    back_project,
    cloud_stride,
    mask_pixels,
    ply_bytes,
    point_pixels,
    read_ply,
    statistical_outliers,
    write_ply,
)

K = PAPER_CAMERA.intrinsics().scaled(256, 256)


def tilted_plane(h: int = 120, w: int = 160, z0: float = 100.0) -> np.ndarray:
    """Depth (metres) of a plane tilted about both image axes, at ~100 m."""
    rows, cols = np.mgrid[0:h, 0:w]
    return (z0 + 0.01 * cols + 0.02 * rows).astype(np.float32)


def test_back_projection_inverts_the_camera():
    depth = tilted_plane()
    mask = np.zeros(depth.shape, bool)
    mask[10:50, 20:90] = True
    depth[12, 30] = 0  # masked but no depth: no point
    points = back_project(depth, mask, K)
    assert points.dtype == np.float32 and points.shape == (mask.sum() - 1, 3)
    rows, cols = np.nonzero(mask & (depth > 0))  # row-major order
    u, v = K.project(points.astype(np.float64))
    np.testing.assert_allclose(u, cols, atol=1e-3)
    np.testing.assert_allclose(v, rows, atol=1e-3)
    np.testing.assert_array_equal(points[:, 2], depth[rows, cols])
    pixel_rows, pixel_cols = point_pixels(points, K)  # and back to their pixels, exactly
    np.testing.assert_array_equal(pixel_rows, rows)
    np.testing.assert_array_equal(pixel_cols, cols)


def test_back_projection_is_the_pinhole_formula_per_pixel_in_bands_of_any_size():
    """Only the mask's box is visited, a band at a time: the points are still each pixel's
    (x, y, z) computed in float64 and stored as float32, in row-major order."""
    rng = np.random.default_rng(3)
    depth = (50 + 100 * rng.random((90, 130))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0
    scattered = rng.random(depth.shape) < 0.3
    scattered[:7] = scattered[:, :11] = False  # a box away from the frame's corner
    for mask in (scattered, scattered[::2], np.eye(90, 130, 40, dtype=bool)):
        d = depth[: mask.shape[0]] if mask.shape != depth.shape else depth
        rows, cols = np.nonzero(mask & (d > 0))
        z = d[rows, cols].astype(np.float64)
        expected = np.stack([(cols - K.cx) * z / K.fx, (rows - K.cy) * z / K.fy, z], 1)
        for band_pixels in (1, 500, 2**17):
            points = back_project(d, mask, K, band_pixels)
            np.testing.assert_array_equal(points, expected.astype(np.float32))


def test_a_strided_cloud_is_the_pinhole_formula_on_every_kth_row_and_column():
    rng = np.random.default_rng(4)
    depth = (50 + 100 * rng.random((90, 130))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0
    mask = rng.random(depth.shape) < 0.5
    mask[:5] = False
    for stride in (1, 2, 3, 7):
        rows, cols = np.nonzero(mask & (depth > 0))
        on = (rows % stride == 0) & (cols % stride == 0)
        rows, cols = rows[on], cols[on]
        z = depth[rows, cols].astype(np.float64)
        expected = np.stack([(cols - K.cx) * z / K.fx, (rows - K.cy) * z / K.fy, z], 1)
        for band_pixels in (1, 2**17):
            points = back_project(depth, mask, K, band_pixels, stride=stride)
            np.testing.assert_array_equal(points, expected.astype(np.float32))


@pytest.mark.parametrize(
    ("max_points", "stride"), [(100, 1), (1000, 1), (99, 2), (25, 2), (24, 3), (16, 3), (1, 10)]
)
def test_the_cloud_stride_is_the_smallest_that_keeps_at_most_max_points(max_points, stride):
    """A 10 x 10 mask all True holds 100 pixels, 25 on every second row and column, 16 on
    every third, 1 on every tenth."""
    assert cloud_stride(np.ones((10, 10), bool), max_points) == stride


def test_mask_pixels_are_numpys_nonzero_in_its_order():
    mask = np.random.default_rng(0).random((37, 53)) < 0.3
    for view in (mask, mask[5:30, 7:41], mask[::2, ::3], np.zeros((3, 4), bool)):
        rows, cols = mask_pixels(view)
        expected_rows, expected_cols = np.nonzero(view)
        np.testing.assert_array_equal(rows, expected_rows)
        np.testing.assert_array_equal(cols, expected_cols)


def test_back_projection_of_nothing_is_an_empty_cloud():
    points = back_project(np.zeros((4, 5), np.float32), np.ones((4, 5), bool), K)
    assert points.shape == (0, 3)


def test_outlier_removal_drops_spikes_and_keeps_the_surface():
    depth = tilted_plane()
    mask = depth > 0
    rng = np.random.default_rng(0)
    spikes = rng.choice(depth.size, 40, replace=False)
    rows, cols = np.unravel_index(spikes, depth.shape)
    depth[rows, cols] += rng.uniform(0.5, 5.0, 40).astype(np.float32)  # flying pixels
    keep = statistical_outliers(depth, mask, K)
    assert not keep[rows, cols].any()
    assert keep.sum() >= 0.97 * (mask.sum() - 40)
    assert not (keep & ~mask).any()


def test_outlier_removal_drops_isolated_points():
    depth = np.zeros((60, 80), np.float32)
    depth[20:40, 10:50] = tilted_plane(20, 40)  # a panel
    depth[5, 70] = 100.0  # a lone pixel, nothing around it
    keep = statistical_outliers(depth, depth > 0, K)
    assert not keep[5, 70]
    # the panel's inside stays; on such perfectly regular data (no spread in the scores at
    # all) SOR may take its rim, whose neighbours are fewer and so farther: not asserted
    assert keep[22:38, 12:48].all()


def test_outlier_removal_on_a_rendered_spacecraft():
    pytest.importorskip("embreex", reason="renders with the generator: the data extra")
    from tests.support.frames import generated_sample

    s = generated_sample(256)
    depth, mask = s.depth.copy(), s.depth > 0
    rows, cols = np.nonzero(mask)
    picked = np.random.default_rng(1).choice(len(rows), 20, replace=False)
    depth[rows[picked], cols[picked]] += 3.0
    keep = statistical_outliers(depth, mask, K)
    assert not keep[rows[picked], cols[picked]].any()
    assert keep.sum() >= 0.9 * mask.sum()


def test_outlier_removal_edge_cases():
    empty = np.zeros((8, 8), np.float32)
    assert not statistical_outliers(empty, empty > 0, K).any()
    with pytest.raises(ValueError, match="at least 1"):
        statistical_outliers(empty, empty > 0, K, radius=0)
    full = np.full((1024, 1024), 100.0, np.float32)  # a million points: the grid search copes
    assert statistical_outliers(full, full > 0, PAPER_CAMERA.intrinsics()).sum() > 0.9 * 2**20


def test_ply_round_trip(tmp_path):
    points = np.random.default_rng(0).normal(size=(1000, 3)).astype(np.float32)
    path = write_ply(tmp_path / "cloud.ply", points, ("made by a test", "metres"))
    header = path.read_bytes().split(b"end_header\n")[0].decode()
    assert header.splitlines()[:2] == ["ply", "format binary_little_endian 1.0"]
    assert "element vertex 1000" in header and "property float z" in header
    cloud = read_ply(path)
    np.testing.assert_array_equal(cloud.points, points)
    assert cloud.comments == ["made by a test", "metres"] and cloud.properties == {}
    assert read_ply(ply_bytes(np.zeros((0, 3), np.float32))).points.shape == (0, 3)


def test_ply_vertices_carry_their_properties_after_x_y_z():
    points = np.random.default_rng(1).normal(size=(50, 3)).astype(np.float32)
    sigma = np.linspace(0.01, 0.5, 50, dtype=np.float32)
    data = ply_bytes(points, ("metres",), {"sigma": sigma})
    header, vertices = data.split(b"end_header\n")
    assert header.decode().splitlines()[-4:] == [
        "property float x",
        "property float y",
        "property float z",
        "property float sigma",
    ]
    rows = np.frombuffer(vertices, "<f4").reshape(50, 4)  # interleaved, a vertex a row
    np.testing.assert_array_equal(rows[:, :3], points)
    np.testing.assert_array_equal(rows[:, 3], sigma)
    cloud = read_ply(data)
    np.testing.assert_array_equal(cloud.points, points)
    assert list(cloud.properties) == ["sigma"]
    np.testing.assert_array_equal(cloud.properties["sigma"], sigma)
    with pytest.raises(ValueError, match="one value per point"):
        ply_bytes(points, (), {"sigma": sigma[:-1]})
    with pytest.raises(ValueError, match="cannot be a PLY property"):
        ply_bytes(points, (), {"z": sigma})


@pytest.mark.parametrize(
    "data, message",
    [
        (b"not a ply", "does not start"),
        (b"ply\nformat ascii 1.0\nelement vertex 1\nend_header\n", "binary_little_endian"),
        (ply_bytes(np.ones((3, 3), np.float32))[:-4], "truncated"),
        (b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n", "end_header"),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
            b"end_header\n",
            "layout",
        ),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n"
            b"property float y\nproperty float z\nproperty uchar red\nend_header\n",
            "layout",
        ),
    ],
)
def test_read_ply_refuses_other_layouts(data, message):
    with pytest.raises(ValueError, match=message):
        read_ply(data)


def test_ply_needs_n_by_3_points():
    with pytest.raises(ValueError, match="N, 3"):
        ply_bytes(np.zeros((4, 2), np.float32))
