"""Print a pip constraints file pinning every dependency (and the test extra's) at the lower
bound pyproject.toml allows, so that CI can check those bounds install and work.

Lint and type tools are left out (the fast tests do not run them)."""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

SKIP = {"ruff", "mypy", "types-pyyaml", "import-linter"}


def pins(pyproject: Path) -> list[str]:
    project = tomllib.loads(pyproject.read_text())["project"]
    out = []
    for req in [*project["dependencies"], *project["optional-dependencies"]["test"]]:
        m = re.match(r"\s*([A-Za-z0-9_.\-]+)(\[[^\]]*\])?\s*(.*)", req)
        if m is None or m.group(1).lower() in SKIP:
            continue
        low = re.search(r">=\s*([0-9][^,;\s]*)", m.group(3))
        if low is None:
            sys.exit(f"{pyproject}: {req!r} has no lower bound (>=): every dependency needs one")
        out.append(f"{m.group(1)}=={low.group(1)}")
    return out


if __name__ == "__main__":
    print("\n".join(pins(Path(__file__).resolve().parent.parent / "pyproject.toml")))
