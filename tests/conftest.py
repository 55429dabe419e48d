"""Shared fixtures, and which modules ``make test-runtime`` leaves out.

``make test-runtime`` runs the suite in an environment with the runtime extras only (``serve``,
``client``, ``test-runtime``: no torch, no data generator) and passes ``--runtime-only``: the
modules in ``NEEDS_TRAINING`` are then not collected. Every other module must import and pass
there, so a service or client test that reached for torch or the generator fails loudly.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.support.models import tiny_model

# Every service the tests start, in process or not, keeps its model's own budget of working
# pixels, so that its answers are the in-process pipeline's on any machine; the budget a slow
# CPU would get instead is tested on its own (tests/test_frame_budget.py, which sets it).
os.environ["SDCNET_FRAME_MS"] = "0"

#: Test modules of training, evaluation, export and the generator (torch, embreex).
NEEDS_TRAINING = {
    "test_deploy.py",  # checks the dataset Job's arguments with sdc-data's own parser
    "test_export.py",
    "test_generator.py",
    "test_imports.py",  # imports the training code too
    "test_wheel.py",  # builds the wheel with the dev extra's build backend (setuptools, wheel)
    "test_model.py",
    "test_plane_fit.py",
    "test_pose_eval.py",  # sdc-eval pose: the generator's frames, the shipped model's clouds
    "test_real_meshes.py",
    "test_sequence.py",  # sdc-data sequence
    "test_training.py",
    "test_worlds.py",  # the generator's worlds
    "test_styles.py",  # the generator's render styles
    "test_evaluation.py",  # the classical fill, stored answers, the robustness suite
    "test_factors.py",  # sdc-eval factors on frames the generator renders
    "test_generalisation.py",  # the shipped model on frames the generator renders
    "test_lidar.py",
    "test_backgrounds.py",
}


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--runtime-only",
        action="store_true",
        help="leave out the modules that need torch or the data generator (make test-runtime)",
    )


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    if config.getoption("--runtime-only") and collection_path.name in NEEDS_TRAINING:
        return True
    return None


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """3 models x 2 views at 256 x 256 rendered by the generator (same optics, so LIDAR
    returns are ~3 x 4.5 px apart)."""
    from sdcnet.training.data.generate import GenerateConfig, generate

    out = tmp_path_factory.mktemp("tiny")
    generate(GenerateConfig(models=3, views=2, size=256, seed=0), out, workers=1, progress=False)
    return out


@pytest.fixture(scope="session")
def tiny_model_path(tmp_path_factory) -> Path:
    """The tiny sdcnet-shaped ONNX model (``tests.support.models.tiny_model``)."""
    return tiny_model(tmp_path_factory.mktemp("models"))
