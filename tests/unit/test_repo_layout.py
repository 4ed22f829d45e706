"""Where shared code lives: what two test files share is a helper in ``tests/helpers/`` (no test
module imports another), and no benchmark imports from ``tests/`` (the benchmarks stand on
the package and on ``benchmarks/`` alone). And the code, tests, benchmarks and docs say what
they mean in their own words: none points at a tracker's issue by number."""

from __future__ import annotations

import ast
import re
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


ISSUE = re.compile(r"\bissues? ?#?[0-9]+", re.IGNORECASE)
TEXT_DIRS = ("benchctl", "tests", "benchmarks", "docs", "config", "profiles", "drivers", ".ci")


def test_no_file_points_at_an_issue_by_number() -> None:
    files = [ROOT / "README.md", ROOT / "pyproject.toml"]
    for d in TEXT_DIRS:
        files += [p for p in (ROOT / d).rglob("*") if p.is_file()
                  and p.suffix in (".py", ".md", ".yaml", ".yml", ".toml", ".j2", ".txt", "")
                  and "campaign-results" not in p.parts and "_build" not in p.parts]
    found = [f"{p.relative_to(ROOT)}: {m.group(0)!r}" for p in files
             for m in [ISSUE.search(p.read_text(errors="replace"))] if m]
    assert found == []


def test_the_check_sees_such_imports() -> None:
    word = "iss" + "ue"  # not written whole: this file is searched too
    assert ISSUE.search(f"see {word.title()} #12") and ISSUE.search(f"{word} 7")
    assert ISSUE.search(f"{word}s 3")
    assert not ISSUE.search("an issue with the stand")
    assert imported("from test_predict import NOISE\n") == {"test_predict"}
    assert imported("def f():\n    import stand_rig.x as y\n") == {"stand_rig"}
    assert imported("from . import sibling\n") == set()


LONG = 650  # "about 600 lines": a module over this says why it stays whole
ABOUT = re.compile(r"about ([0-9 ]+) lines")


def test_a_long_module_says_why_it_stays_whole() -> None:
    """Each Python file over ``LONG`` lines states in its docstring why it is one file, with
    its size (``about N lines``, N within 20 % of the count, so the reason is kept current)."""
    missing = []
    for d in ("benchctl", "tests", "benchmarks", "docs"):
        for p in sorted((ROOT / d).rglob("*.py")):
            text = p.read_text()
            n = text.count("\n")
            if n <= LONG:
                continue
            doc = ast.get_docstring(ast.parse(text)) or ""
            m = ABOUT.search(doc)
            if m is None or abs(int(m.group(1).replace(" ", "")) - n) > 0.2 * n:
                missing.append(f"{p.relative_to(ROOT)}: {n} lines")
    assert missing == []
