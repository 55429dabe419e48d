"""Every `from sdcnet... import name` in the project's code resolves, the lazy ones inside
functions too: a module moved without its importers updated fails here, not in front of a user
running a benchmark (benchmarks.wire once imported the meshes from where they had been)."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = (
    "sdcnet",
    "training",
    "evaluation",
    "export",
    "service",
    "client",
    "models",
    "benchmarks",
)


def sdcnet_imports() -> list[tuple[str, str, str]]:
    """(file, module, name) of every ``from sdcnet.X import name`` under the project folders."""
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sdcnet"):
                    relative = str(path.relative_to(ROOT))
                    found += [(relative, node.module, alias.name) for alias in node.names]
    return found


IMPORTS = sdcnet_imports()


def test_the_scan_sees_the_lazy_imports():
    assert ("benchmarks/wire.py", "sdcnet.meshes", "read_mesh_folder") in IMPORTS


@pytest.mark.parametrize(
    ("module", "names"),
    sorted({m: sorted({n for _, mm, n in IMPORTS if mm == m}) for _, m, _ in IMPORTS}.items()),
)
def test_every_imported_name_exists(module, names):
    loaded = importlib.import_module(module)
    missing = [n for n in names if n != "*" and not hasattr(loaded, n)]
    if missing:  # a submodule imported by name: `from sdcnet.training import train`
        missing = [n for n in missing if importlib.util.find_spec(f"{module}.{n}") is None]
    assert not missing, f"{module} has no {missing}"


#: Training validates with evaluation's yardstick, so the yardstick sits below training: these
#: modules import nothing from ``sdcnet.training``, and training imports nothing else of
#: ``sdcnet.evaluation`` (the rest of it sits above training: it loads checkpoints and renders
#: frames).
YARDSTICK = ("evaluation/scoring.py", "evaluation/classical_fill.py")


@pytest.mark.parametrize("path", YARDSTICK)
def test_the_yardstick_imports_nothing_from_training(path):
    assert (ROOT / path).is_file()
    assert not [m for file, m, _ in IMPORTS if file == path and m.startswith("sdcnet.training")]


def test_training_imports_only_the_yardstick_of_evaluation():
    from_training = {m for file, m, _ in IMPORTS if file.startswith("training/")}
    evaluation = {m for m in from_training if m.startswith("sdcnet.evaluation")}
    assert evaluation <= {"sdcnet.evaluation." + Path(path).stem for path in YARDSTICK}
