"""Where the repository's files are, wherever a test module sits under tests/."""

from __future__ import annotations

from pathlib import Path

#: the folder of the helper modules (this one, wire, run_fakes, …), for a child process's sys.path
HELPERS = Path(__file__).resolve().parent


def _root() -> Path:
    for folder in HELPERS.parents:
        if (folder / "pyproject.toml").is_file() and (folder / "benchctl").is_dir():
            return folder
    raise RuntimeError(f"no repository root above {HELPERS}")


#: the repository's root: config/, profiles/, drivers/, pyproject.toml
ROOT = _root()
