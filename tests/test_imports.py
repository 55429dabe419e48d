"""Imports across the project: every `from sdcnet... import name` (and `from tests.support...`)
resolves, the lazy ones inside functions too, so a module moved without its importers updated
fails here, not in front of a user running a benchmark (benchmarks.wire once imported the
meshes from where they had been); and the shipped code imports nothing of the tests or the
benchmarks, which the wheel does not install."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: What the wheel installs (pyproject's package-dir).
SHIPPED = ("sdcnet", "training", "evaluation", "export", "service", "client", "models")
FOLDERS = (*SHIPPED, "benchmarks", "tests")
#: Top-level packages of the repository that the wheel leaves out.
NOT_SHIPPED = {"tests", "benchmarks"}


def imports_of(path: Path) -> list[ast.Import | ast.ImportFrom]:
    """Every import statement in the file, at module level or inside a function."""
    tree = ast.parse(path.read_text(), str(path))
    return [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)]


def modules_imported(path: Path) -> set[str]:
    """The absolute module names the file imports (``import a.b``, ``from a.b import c``)."""
    modules = set()
    for node in imports_of(path):
        if isinstance(node, ast.Import):
            modules.update(alias.name for alias in node.names)
        elif node.level == 0:
            modules.add(node.module)
    return modules


def project_imports() -> list[tuple[str, str, str]]:
    """(file, module, name) of every ``from sdcnet.X import name`` and ``from tests.support.X
    import name`` under the project folders."""
    found = []
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in imports_of(path):
                module = node.module if isinstance(node, ast.ImportFrom) else None
                if module and module.startswith(("sdcnet", "tests.support")):
                    relative = str(path.relative_to(ROOT))
                    found += [(relative, module, alias.name) for alias in node.names]
    return found


IMPORTS = project_imports()


def test_the_scan_sees_the_lazy_imports():
    assert ("benchmarks/wire.py", "sdcnet.meshes", "read_mesh_folder") in IMPORTS
    assert "tests.support.models" in modules_imported(ROOT / "tests/support/serving.py")


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


@pytest.mark.parametrize("folder", SHIPPED)
def test_shipped_code_imports_nothing_of_the_tests_or_the_benchmarks(folder):
    found = [
        f"{path.relative_to(ROOT)}: {module}"
        for path in sorted((ROOT / folder).rglob("*.py"))
        for module in sorted(modules_imported(path))
        if module.split(".")[0] in NOT_SHIPPED
    ]
    assert not found


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


#: What each runtime folder may import of the packages above the core (none of them).
ABOVE_THE_CORE = ("sdcnet.training", "sdcnet.evaluation", "sdcnet.export")


@pytest.mark.parametrize(
    ("folder", "forbidden"),
    [
        ("sdcnet/", (*ABOVE_THE_CORE, "sdcnet.service", "sdcnet.client")),
        ("service/", (*ABOVE_THE_CORE, "sdcnet.client")),
        ("client/", (*ABOVE_THE_CORE, "sdcnet.service")),
    ],
)
def test_the_runtime_imports_only_the_core_and_itself(folder, forbidden):
    found = [f"{file}: {m}" for file, m, _ in IMPORTS if file.startswith(folder)]
    assert not [line for line in found if line.split(": ")[1].startswith(forbidden)]
