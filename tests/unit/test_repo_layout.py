"""Where shared code lives: what two test files share is a helper in ``tests/helpers/`` (no test
module imports another), and no benchmark imports from ``tests/`` (the benchmarks stand on
the package and on ``benchmarks/`` alone)."""

from __future__ import annotations

import ast
from pathlib import Path

from repo_paths import ROOT

TESTS = ROOT / "tests"
HELPERS = {p.stem for p in (TESTS / "helpers").glob("*.py")}
TEST_MODULES = {p.stem for p in TESTS.rglob("test_*.py")} | {"conftest"}


def imported(source: str) -> set[str]:
    """The top-level names of the modules ``source`` imports (anywhere in it)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _offenders(files: list[Path], forbidden: set[str]) -> list[str]:
    return [f"{p.relative_to(ROOT)} imports {sorted(imported(p.read_text()) & forbidden)}"
            for p in files if imported(p.read_text()) & forbidden]


def test_no_test_module_imports_another() -> None:
    files = sorted(TESTS.rglob("*.py"))
    assert _offenders(files, TEST_MODULES) == []


def test_no_benchmark_imports_a_test_or_a_test_helper() -> None:
    files = sorted((ROOT / "benchmarks").glob("*.py"))
    assert _offenders(files, TEST_MODULES | HELPERS | {"tests"}) == []


def test_the_check_sees_such_imports() -> None:
    assert imported("from test_predict import NOISE\n") == {"test_predict"}
    assert imported("def f():\n    import stand_rig.x as y\n") == {"stand_rig"}
    assert imported("from . import sibling\n") == set()
