"""The wheel installs the runtime and the training code, every package of it and nothing of the
tests or the benchmarks: built offline from the files git would commit (tracked, or untracked
but not ignored), in a copy, so that no ``build/`` folder left in the checkout can leak into it.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path, PurePosixPath

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Folder names of what only the tests and the benchmarks use.
TEST_ONLY = {"tests", "support", "devtools", "benchmarks"}


def source_packages() -> set[str]:
    """Every package the sources hold: each folder with an ``__init__.py`` under a folder of
    pyproject's ``package-dir``, named as installed (``training/data`` is
    ``sdcnet.training.data``)."""
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    packages = set()
    for package, folder in setuptools["package-dir"].items():
        for init in (ROOT / folder).rglob("__init__.py"):
            packages.add(".".join((package, *init.parent.relative_to(ROOT / folder).parts)))
    return packages


@pytest.fixture(scope="module")
def wheel_names(tmp_path_factory) -> list[str]:
    """The paths inside the wheel built from a copy of the checkout."""
    work = tmp_path_factory.mktemp("wheel")
    source = work / "source"
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.decode()
    for name in filter(None, listed.split("\0")):
        if (ROOT / name).is_file():  # a tracked file deleted in the checkout is not listed
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, source / name)
    command = [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-index"]
    command += ["--no-build-isolation", "--wheel-dir", str(work / "dist"), str(source)]
    built = subprocess.run(command, capture_output=True, text=True)
    assert built.returncode == 0, built.stderr
    (wheel,) = (work / "dist").glob("sdcnet-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        return archive.namelist()


def test_the_wheel_holds_every_package_of_the_sources(wheel_names):
    installed = {
        ".".join(PurePosixPath(name).parent.parts)
        for name in wheel_names
        if name.endswith("/__init__.py")
    }
    expected = source_packages()
    assert not installed - expected, "in the wheel, not under pyproject's package-dir"
    assert not expected - installed, "a package of the sources missing from pyproject's packages"
    assert "sdcnet/models/sdcnet.onnx" in wheel_names


def test_the_wheel_holds_no_test_helpers(wheel_names):
    test_only = [
        name
        for name in wheel_names
        if TEST_ONLY & set(PurePosixPath(name).parts[:-1])
        or PurePosixPath(name).name == "conftest.py"
        or PurePosixPath(name).name.startswith("test_")
    ]
    assert not test_only
