"""The CLI parser as the CLI reference shows it (docs/reference/cli.md, sphinx-argparse).

sphinx-argparse reads the help texts as reStructuredText; benchctl's are plain text, and some
hold characters that reStructuredText takes as markup (``profiles/*.yaml``, ``|H(f) − 1|``).
This returns ``benchctl.cli.build_parser()`` with those characters escaped, so the page shows
the text exactly as ``--help`` prints it. Documentation only: the product is not changed.
"""

from __future__ import annotations

import argparse
import re

from benchctl.cli import build_parser

_MARKUP = re.compile(r"([\\*`|_\[\]<>])")


def _escape(text: str | None) -> str | None:
    if not text or text is argparse.SUPPRESS:
        return text
    return _MARKUP.sub(r"\\\1", text)


def _escape_parser(parser: argparse.ArgumentParser, seen: set[int]) -> None:
    if id(parser) in seen:
        return
    seen.add(id(parser))
    parser.description = _escape(parser.description)
    parser.epilog = _escape(parser.epilog)
    for action in parser._actions:
        action.help = _escape(action.help)
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                choice.help = _escape(choice.help)
            for sub in action.choices.values():
                _escape_parser(sub, seen)


def parser() -> argparse.ArgumentParser:
    """benchctl's parser, its help texts escaped for reStructuredText."""
    p = build_parser()
    _escape_parser(p, set())
    return p
