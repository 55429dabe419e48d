"""The interpolating pre-fill against a NumPy reference, on planes and on random returns."""

import math

import numpy as np
import pytest
import torch

from sdcnet.training.model.plane_fit import AdaptivePlaneFit, PlaneFitPrefill
from sdcnet.training.model.sdcnet import build_model

Cell = tuple[int, int]


def nearest_per_cell(sparse: np.ndarray, f: int) -> dict[Cell, tuple[float, float, float]]:
    """(cell row, cell column) -> (row, column, depth) of the nearest return in each f x f block."""
    best: dict[Cell, tuple[float, float, float]] = {}
    for r, c in zip(*np.nonzero(sparse > 0), strict=True):
        key, z = (r // f, c // f), float(sparse[r, c])
        if key not in best or z < best[key][2]:
            best[key] = (float(r), float(c), z)
    return best


def reference_fit(
    sparse: np.ndarray, f: int, sigma: tuple[float, float], ridge: float
) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares z = a + b X + c Y around each cell centre, with a ridge on b, c,
    solved with numpy.linalg, one cell at a time: the plane's value a and the window weight."""
    H, W = sparse.shape
    cells = nearest_per_cell(sparse, f)
    radius = [math.ceil(2 * s / f) for s in sigma]
    plane, weight = np.zeros((H // f, W // f)), np.zeros((H // f, W // f))
    for i in range(H // f):
        for j in range(W // f):
            rows = []
            for (ci, cj), (r, c, z) in cells.items():
                u, v = cj - j, ci - i
                if abs(u) <= radius[1] and abs(v) <= radius[0]:
                    w = math.exp(-0.5 * (f * u / sigma[1]) ** 2 - 0.5 * (f * v / sigma[0]) ** 2)
                    rows.append((w, c - (f * j + (f - 1) / 2), r - (f * i + (f - 1) / 2), z))
            if not rows or sum(w for w, *_ in rows) <= math.exp(-1):
                continue
            w, X, Y, z = (np.array(a) for a in zip(*rows, strict=True))
            A = np.stack([np.ones_like(X), X, Y], 1)
            M = A.T @ (w[:, None] * A) + np.diag([0, ridge, ridge]) * w.sum()
            plane[i, j] = np.linalg.solve(M, A.T @ (w * z))[0]
            weight[i, j] = w.sum()
    return plane, weight


def beam_grid(height: int, width: int, depth_at, rng: np.random.Generator) -> np.ndarray:
    """Returns on a jittered 18 x 12.5 px beam grid, as the paper's LIDAR places them."""
    sparse = np.zeros((height, width), np.float32)
    for r in np.arange(rng.uniform(0, 18), height, 18):
        for c in np.arange(rng.uniform(0, 12.5), width, 12.5):
            ri, ci = int(r + rng.normal(0, 1)), int(c + rng.normal(0, 1))
            if 0 <= ri < height and 0 <= ci < width:
                sparse[ri, ci] = depth_at(ri, ci)
    return sparse


def run(fit: PlaneFitPrefill, sparse: np.ndarray, d_ref: float) -> tuple[np.ndarray, np.ndarray]:
    with torch.no_grad():
        plane, weight = fit(torch.from_numpy(sparse)[None, None], torch.full((1, 1, 1, 1), d_ref))
    return plane[0, 0].double().numpy(), weight[0, 0].double().numpy()


def test_a_tilted_plane_comes_back_exactly_at_every_cell_centre():
    rng = np.random.default_rng(0)
    sparse = beam_grid(128, 160, lambda r, c: 150.0 + 0.012 * c - 0.031 * r, rng)
    plane, weight = run(PlaneFitPrefill(factor=4, ridge_px2=1e-3), sparse, d_ref=149.0)
    rows, cols = np.mgrid[0:32, 0:40] * 4 + 1.5
    truth = 150.0 + 0.012 * cols - 0.031 * rows
    assert (weight > 0).all()
    inner = (slice(4, -4), slice(3, -3))  # windows with returns on two rows and columns or more
    assert np.abs(plane - truth)[inner].max() < 1e-3  # metres, float32 arithmetic


def test_random_returns_match_the_numpy_reference():
    rng = np.random.default_rng(1)
    sparse = beam_grid(96, 128, lambda r, c: rng.uniform(80.0, 90.0), rng)
    sparse[rng.random(sparse.shape) < 0.3] = 0  # dropouts: isolated returns, empty windows
    fit = PlaneFitPrefill(factor=4, sigma_px=(9.0, 6.0), ridge_px2=0.5)
    plane, weight = run(fit, sparse, d_ref=85.0)
    ref_plane, ref_weight = reference_fit(sparse, 4, (9.0, 6.0), 0.5)
    np.testing.assert_array_equal(weight > 0, ref_weight > 0)
    assert (weight > 0).mean() > 0.5 and (weight == 0).any()
    np.testing.assert_allclose(weight, ref_weight, atol=1e-4)
    np.testing.assert_allclose(plane, ref_plane, atol=2e-3)  # metres


def test_nearest_return_of_a_cell_wins_and_keeps_its_sub_pixel_position():
    sparse = np.zeros((32, 32), np.float32)
    sparse[13, 14] = 50.0  # cell (3, 3), offset (+0.5, -0.5) from its centre (13.5, 13.5)
    sparse[12, 12] = 70.0  # farther return in the same cell: ignored
    fit = PlaneFitPrefill(factor=4)
    with torch.no_grad():
        cells = fit.cell_channels(torch.from_numpy(sparse)[None, None], torch.zeros(1, 1, 1, 1))
    c, dx, dy = (cells[0, k, 3, 3].item() for k in range(3))
    assert (c, dx, dy) == (1.0, 0.5, -0.5)
    assert cells[0, 6, 3, 3].item() == 50.0
    assert cells[0, 0].sum().item() == 1.0


def test_the_adaptive_fit_takes_the_finest_window_the_returns_support():
    """A flash array's dense returns get the finest window, a sparse grid's a coarser one;
    both recover a plane exactly, and no window at all is used far from every return."""
    rng = np.random.default_rng(3)
    tilted = lambda r, c: 80.0 + 0.02 * c - 0.01 * r  # noqa: E731
    fit = AdaptivePlaneFit(factor=4, ridge_px2=1e-3)
    for spacing, level in ((3, 0.0), (18, 0.5)):
        sparse = np.zeros((128, 128), np.float32)
        for r in np.arange(rng.uniform(0, spacing), 128, spacing):
            for c in np.arange(rng.uniform(0, spacing), 128, spacing):
                sparse[int(r), int(c)] = tilted(int(r), int(c))
        with torch.no_grad():
            plane, weight, chosen = fit(
                torch.from_numpy(sparse)[None, None], torch.full((1, 1, 1, 1), 80.0)
            )
        rows, cols = np.mgrid[0:32, 0:32] * 4 + 1.5
        inner = (slice(6, -6), slice(6, -6))
        assert np.abs(plane[0, 0].numpy() - tilted(rows, cols))[inner].max() < 2e-3
        assert np.median(chosen[0, 0].numpy()[inner]) == pytest.approx(level)
        assert (weight[0, 0].numpy()[inner] >= 1.0).all()
    lone = np.zeros((256, 256), np.float32)
    lone[10, 10] = 50.0
    with torch.no_grad():
        plane, weight, chosen = fit(torch.from_numpy(lone)[None, None], torch.zeros(1, 1, 1, 1))
    assert weight[0, 0, -1, -1] == 0 and plane[0, 0, -1, -1] == 0 and chosen[0, 0, -1, -1] == 1


def test_a_fresh_model_answers_the_plane_fit_itself():
    """The residual head starts at zero: training starts from the interpolation."""
    torch.manual_seed(0)
    model = build_model("sdcnet").eval()
    rng = np.random.default_rng(2)
    sparse = beam_grid(128, 128, lambda r, c: 120.0 + 0.02 * c + 0.01 * r, rng)
    with torch.no_grad():
        depth, _, _ = model(
            torch.rand(1, 1, 128, 128),
            torch.from_numpy(sparse)[None, None],
            torch.full((1, 1, 1, 1), 7939.2),
        )
    rows, cols = np.mgrid[0:128, 0:128]
    truth = 120.0 + 0.02 * cols + 0.01 * rows
    inner = (slice(16, 112), slice(16, 112))
    assert np.abs(depth[0, 0].numpy() - truth)[inner].max() < 5e-3
