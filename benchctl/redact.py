"""Secrets kept out of every output: one place that hides passwords in database URLs and in
anything holding them (a config as written into a recording, a message, a log line).

``redact(value)`` hides, in every string found in ``value`` (a string, or mappings and lists
of them, walked through):

- the password of a URL's user part, ``scheme://user:PASSWORD@host`` → ``user:***@host``
  (up to the last ``@`` before a space: a password holding an unescaped ``@`` or ``/`` is
  hidden whole, at worst with a bit more than the password);
- a ``password=VALUE`` (any ``…password`` key: ``sslpassword`` too) in a URL's query
  (``?password=…&…``) and in a libpq ``key=value`` connection string (quoted
  ``password='a b'`` included; unquoted, up to the next ``&`` or space: redact a value
  before quoting it for a message, not after);

and, in a mapping, the value of any key that names a password (``password``, ``passwd``,
``sslpassword``…) whole. It works on text that is not a valid URL (a port typo, a URL inside
a YAML list, a libpq string where a URL was expected): nothing is parsed that could fail.
``redact_secret(text, secret)`` also hides a known secret's literal text (a driver's message
could quote it).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any
from urllib.parse import unquote

MASK = "***"

# scheme://user:password@ — the user part runs to the last "@" of the string
_USERINFO = re.compile(r"(?P<head>[A-Za-z][A-Za-z0-9+.\-]*://[^:/?#@\s]*):(?P<pw>\S*)@")
# password=value: a query parameter or a libpq keyword (its value quoted or up to a separator)
_KEYWORD = re.compile(
    r"(?P<key>\b\w*passw(?:or)?d\s*=\s*)"
    r"(?P<value>(?:'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\")?[^&\s]*)",
    re.I,
)
_SECRET_KEY = re.compile(r"passw(?:or)?d|\bsecret\b", re.I)


def _hide(text: str) -> str:
    out = _USERINFO.sub(lambda m: f"{m['head']}:{MASK}@", text)
    return _KEYWORD.sub(lambda m: f"{m['key']}{MASK}", out)


def redact_text(text: str) -> str:
    """``text`` with every password in it hidden (see the module's docstring). A password
    key spelt with percent-escapes (``?pass%77ord=…``) is found too: the text is then shown
    unescaped."""
    out = _hide(text)
    if "%" in out:
        plain = unquote(out)
        hidden = _hide(plain)
        if hidden != plain:
            return hidden
    return out


def redact(value: Any) -> Any:
    """``value`` with its passwords hidden: a string through ``redact_text``; a mapping's
    values (a key naming a password: its value whole) and a list's or tuple's items walked
    through; anything else as it is."""
    if isinstance(value, str):
        return redact_text(value)
    if isinstance(value, Mapping):
        return {k: (MASK if isinstance(k, str) and _SECRET_KEY.search(k) and v is not None
                    else redact(v)) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return type(value)(redact(v) for v in value)
    return value


def redact_secret(text: str, secret: str | None) -> str:
    """``redact_text(text)`` with, too, every occurrence of ``secret`` itself hidden."""
    out = redact_text(text)
    return out.replace(secret, MASK) if secret else out


__all__ = ["MASK", "redact", "redact_secret", "redact_text"]
