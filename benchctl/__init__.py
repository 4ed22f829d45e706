"""benchctl: dynamic-error tests of ship navigation instruments on a roll/pitch motion stand.

The method is Gryazin & Belova (2023); see ``docs/method.md`` and ``docs/reference/analyze.md``.
"""

from __future__ import annotations

import functools
from importlib.metadata import PackageNotFoundError, version

__all__ = ["__version__"]


@functools.cache
def _version() -> str:
    """The installed distribution's version, looked up when first asked for (the lookup costs
    about 5 ms: paid by ``--version`` and a recording's meta.json, not by every command)."""
    try:
        return version("benchctl")
    except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
        return "0.0.0+unknown"


def __getattr__(name: str) -> str:
    if name == "__version__":
        return _version()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
