"""Imports at the top of each module, so that its dependencies are seen where they are stated.

A function-local import needs a measured reason, and each kind allowed is listed here:

- a heavy library imported only on the path that needs it (times from ``python -X importtime``
  after numpy, on the 2-core development machine): scipy's submodules (0.2–1.6 s), matplotlib
  (0.3 s), alembic (0.26 s), jsonschema (0.15 s), uvicorn (0.06 s), jinja2 (0.04 s), babel
  and SQLAlchemy's dialects (an optional extra's, or a database's, module);
- the command line (``benchctl/cli/``): each command's module is imported when that command
  runs, so that ``benchctl --help`` or ``benchctl run`` does not import what the others need;
- the profiles (their pydantic schema, 0.6 s) where ``analysis.lines`` re-synthesises a
  recording's lines: ``benchctl analyze`` of a CSV never needs them (its imports 2.5 s → 0.6 s);
- the imports that break a circle still listed in ``pyproject.toml``'s import-linter
  contracts (the Modbus link's in-process client);
- an import inside a ``try`` whose handler guards an optional part of a run (an output sink,
  a plot): a part that cannot even be imported fails alone, the run's verdict stands.
"""

from __future__ import annotations

import ast

from repo_paths import ROOT

HEAVY = ("scipy", "matplotlib", "alembic", "jsonschema", "uvicorn", "jinja2", "babel",
         "sqlalchemy")
CYCLE_BREAKERS = {
    ("benchctl/devices/modbus/link.py", "benchctl.devices.modbus.channel_client"),
    ("benchctl/devices/modbus/link.py", "benchctl.channels"),
}
#: an own module that is heavy on one path only (measured: see above)
MEASURED = {("benchctl/analysis/lines.py", "benchctl.profiles")}
EXEMPT_DIRS = ("benchctl/cli/",)


def _local_imports(tree: ast.Module) -> list[tuple[int, str]]:
    """(line, module) of every import inside a function, not under ``if TYPE_CHECKING`` nor in
    a ``try`` block."""
    exempt: set[int] = set()  # … nor inside a try (a guarded part, see above)
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            exempt.update(range(node.lineno, (node.end_lineno or node.lineno) + 1))
        if isinstance(node, ast.Try):
            for stmt in node.body:
                exempt.update(range(stmt.lineno, (stmt.end_lineno or stmt.lineno) + 1))
    found = []
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if not isinstance(node, ast.Import | ast.ImportFrom) or node.lineno in exempt:
                continue
            if isinstance(node, ast.ImportFrom):
                found.append((node.lineno, node.module or ""))
            elif isinstance(node, ast.Import):
                found += [(node.lineno, a.name) for a in node.names]
    return found


def test_function_local_imports_have_a_listed_reason() -> None:
    unexplained = []
    for path in sorted((ROOT / "benchctl").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        if rel.startswith(EXEMPT_DIRS):
            continue
        for line, module in _local_imports(ast.parse(path.read_text("utf-8"))):
            if module.startswith(HEAVY) or (rel, module) in CYCLE_BREAKERS | MEASURED:
                continue
            unexplained.append(f"{rel}:{line}: import of {module} inside a function")
    assert unexplained == [], "\n".join(unexplained)


def test_the_check_sees_a_local_import() -> None:
    tree = ast.parse(
        "import typing\n"
        "def f():\n    from benchctl.config import load_config\n"
        "def g():\n    if typing.TYPE_CHECKING:\n        from benchctl.run import session\n"
        "def h():\n    try:\n        from benchctl.report import html\n    except ImportError:\n"
        "        pass\n"
    )
    assert _local_imports(tree) == [(3, "benchctl.config")]
