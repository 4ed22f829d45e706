"""benchctl: dynamic-error tests of ship navigation instruments on a roll/pitch motion stand.

The method is Gryazin & Belova (2023); see ``docs/method.md`` and ``docs/reference/analyze.md``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("benchctl")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without install
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
