"""Shared fixtures: small generated datasets, made once per test session."""

from __future__ import annotations

from pathlib import Path

import pytest

from sdcnet.training.data.generate import GenerateConfig, generate


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """3 models x 2 views at 256 x 256 (same optics, so LIDAR returns are ~3 x 4.5 px apart)."""
    out = tmp_path_factory.mktemp("tiny")
    generate(GenerateConfig(models=3, views=2, size=256, seed=0), out, workers=1, progress=False)
    return out
