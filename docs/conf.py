"""Sphinx configuration of benchctl's documentation (MyST Markdown, the furo theme).

Built offline: no intersphinx, nothing fetched. CI builds it with warnings as errors:
``sphinx-build -W -b html docs docs/_build/html``.
"""

import sys
from importlib import metadata
from pathlib import Path

# docs/cli_parser.py (the CLI parser for sphinx-argparse, reference/cli.md) and
# docs/config_schema.py (the bench config's fields, reference/config.md)
sys.path.insert(0, str(Path(__file__).parent))

project = "benchctl"
author = "benchctl contributors"
copyright = "benchctl contributors, MIT licence"
try:
    release = metadata.version("benchctl")
except metadata.PackageNotFoundError:  # a tree without the package installed
    release = "0.1.0"
version = release

extensions = [
    "myst_parser",  # Markdown pages
    "sphinxarg.ext",  # the CLI reference from benchctl.cli.build_parser()
    "config_schema",  # the bench config reference from benchctl.config (docs/config_schema.py)
]
source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build"]
myst_heading_anchors = 3
# option names stay as typed (--config, not an en dash)
smartquotes = False
# a few code blocks hold an ellipsis (…) standing for what a reader fills in: Pygments then
# highlights them in its relaxed mode, which is right, so that notice is not a warning here
suppress_warnings = ["misc.highlighting_failure"]

html_theme = "furo"
html_title = "benchctl"
