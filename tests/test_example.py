"""The README's first example, verbatim, as a newcomer runs it after ``make serve``: the
shipped example frame through ``sdc-client`` and the real service on the shipped model."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from sdcnet.client.outputs import OUTPUT_FILES
from sdcnet.pointcloud import read_ply
from sdcnet.returns import read_returns_csv
from sdcnet.service.settings import shipped_model_path
from tests.support.serving import running_service

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = "tdrs"
COMMAND = f"sdc-client infer examples/{EXAMPLE}.png examples/{EXAMPLE}.returns.csv --out result/"


def test_the_example_frame_is_small_and_well_formed():
    gray = ROOT / "examples" / f"{EXAMPLE}.png"
    returns = ROOT / "examples" / f"{EXAMPLE}.returns.csv"
    assert gray.stat().st_size + returns.stat().st_size < 1_000_000
    image = cv2.imread(str(gray), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint8 and image.shape == (1024, 1024)  # the paper's camera
    points = read_returns_csv(returns)
    assert len(points) > 100 and 100 < np.median(points[:, 2]) < 180  # metres away


def test_the_readme_shows_the_command_and_its_output():
    readme = (ROOT / "README.md").read_text()
    assert f"\n{COMMAND}\n```\n" in readme  # in a shell block, as typed
    assert "docs/example_preview.png" in readme and (ROOT / "docs/example_preview.png").is_file()


@pytest.fixture(scope="module")
def url(tmp_path_factory):
    log = tmp_path_factory.mktemp("example-service") / "serve.log"
    with running_service(shipped_model_path(), log, "--threads=2") as address:
        yield address


def test_the_readme_example_writes_its_four_files(url, tmp_path):
    shutil.copytree(ROOT / "examples", tmp_path / "examples")  # a fresh clone's examples/
    sdc_client = Path(sys.executable).with_name("sdc-client")  # installed by pip, as in a venv
    command = [str(sdc_client), *COMMAND.split()[1:]]
    done = subprocess.run(
        command,
        cwd=tmp_path,
        env={**os.environ, "SDCNET_URL": url},  # the test's service, not :8000
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    result = tmp_path / "result"
    assert sorted(p.name for p in result.iterdir()) == sorted(OUTPUT_FILES)
    depth = np.load(result / "depth.npy", allow_pickle=False)
    mask = cv2.imread(str(result / "mask.png"), cv2.IMREAD_UNCHANGED) > 0
    cloud = read_ply(result / "points.ply")
    points = cloud.points
    assert depth.shape == mask.shape == (1024, 1024) and depth.dtype == np.float32
    assert mask.sum() > 10_000 and len(points) == np.count_nonzero(depth)
    sigma = np.load(result / "sigma.npy", allow_pickle=False)
    assert sigma.dtype == np.float32 and np.isfinite(sigma).all() and not sigma[~mask].any()
    np.testing.assert_array_equal(cloud.properties["sigma"], sigma[depth > 0])
    assert 100 < np.median(depth[depth > 0]) < 180  # the spacecraft at ~140 m
    assert cv2.imread(str(result / "preview.png")).shape[0] > 0
    assert "LIDAR returns" in done.stdout and "wrote     result/depth.npy" in done.stdout
