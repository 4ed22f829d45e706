"""Every subcommand's ``--help`` (and its actions': ``archive sync``, ``profile show`` …) opens
with a description of what the command does, not only its usage and options."""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import pytest

from benchctl.cli import SUBCOMMANDS, build_parser, main

Command = tuple[tuple[str, ...], argparse.ArgumentParser]


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()) -> Iterator[Command]:
    """Every parser below ``parser`` with its command words, depth first."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _commands(sub, (*path, name))


COMMANDS = [words for words, _ in _commands(build_parser())]


def test_every_subcommand_is_walked() -> None:
    assert {w[0] for w in COMMANDS} == set(SUBCOMMANDS)
    for nested in (("archive", "sync"), ("profile", "plot"), ("recording", "export"),
                   ("stand", "home")):
        assert nested in COMMANDS


@pytest.mark.parametrize("words", COMMANDS, ids=[" ".join(w) for w in COMMANDS])
def test_help_has_a_description(words: tuple[str, ...],
                                capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main([*words, "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: benchctl " + " ".join(words))
    # argparse: the usage, a blank line, then the description (before the first section)
    blocks = out.split("\n\n")
    assert len(blocks) >= 3, out
    description = " ".join(blocks[1].split())
    assert not description.startswith(("positional arguments:", "options:")), \
        f"no description: {words}\n{out}"  # a section where the description should be
    assert len(description.split()) >= 8, description  # a sentence, not a word
    sub = dict(_commands(build_parser()))[words]
    # the description, as argparse wraps it (at spaces and after hyphens)
    assert sub.description and "".join(sub.description.split()) == "".join(description.split())
