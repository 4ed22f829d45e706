"""Messages for input that failed validation: one format for every file benchctl reads.

A bench config, a profile, a plan or the panel's settings that pydantic refuses becomes one
line: the file, what it is, then each failing field with the value given and what was expected::

    bench.yaml: invalid bench config: field stand.port = 70000: Input should be ... 65535

Values are shown cut to 60 characters, with any password in a URL replaced (``redact``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from benchctl.redact import redact


def shown_value(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (one line: repr escapes newlines)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*\Z")


def field_path(loc: tuple[int | str, ...]) -> str:
    """A pydantic error location as a field path: ``sim.faults[0].kind`` (a key that is not
    a plain name quoted: ``can_options['a b']``)."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not _NAME.match(part):
            out += f"[{shown_value(part)}]"
        else:
            out += f".{part}" if out else part
    return out




def invalid(
    source: Path | str,
    what: str,
    err: ValidationError,
    *,
    tag: object = None,
    tags: Callable[[], Sequence[str]] | None = None,
) -> str:
    """``{source}: invalid {what}: field … = …: …; field …`` for every error of ``err``.

    For a model chosen by a tag (a profile's ``kind``): ``tag`` is the value given, dropped
    from the error locations (a tag, not a field), and ``tags()`` the tags there are, named
    when the given one is unknown.
    """
    parts = []
    for e in err.errors():
        loc = list(e["loc"])
        if loc and isinstance(tag, str) and loc[0] == tag:
            loc = loc[1:]  # the discriminator's tag, not a field
        where = field_path(tuple(loc)) or "(top level)"
        value = redact(e.get("input"))  # a password in a URL (in a list…) never shown
        shown = "" if isinstance(value, dict) else f" = {shown_value(value)}"
        msg = e["msg"]
        if e["type"] == "union_tag_invalid" and tags is not None:
            where, shown = "kind", f" = {shown_value(tag)}"
            msg = f"unknown kind; expected one of {', '.join(tags())}"
        parts.append(f"field {where}{shown}: {msg}")
    return f"{source}: invalid {what}: " + "; ".join(parts)
