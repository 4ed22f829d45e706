"""Untrusted text in one place: the serial, the operator, the part number, the station and the
identity strings devices report.

**On input** (:func:`check_serial`, :func:`check_operator`, :func:`check_part_number`,
:func:`check_station`) a value is refused with an ``InputError`` (exit 2) naming the option, the
value (shown safe) and what is expected, unless it is

- there: not empty, not blank (only whitespace: ``'   '``, a lone TAB);
- printable: letters, digits, punctuation, symbols and spaces; no control character (C0, DEL,
  C1: ESC, CR, LF, TAB …), no format character (bidirectional overrides, zero-width
  characters, Unicode category Cf), no line or paragraph separator, no surrogate, private-use or
  unassigned code point;
- not longer than its bound: serial ``SERIAL_MAX`` (64) characters, operator ``OPERATOR_MAX``
  (128), part number ``PART_NUMBER_MAX`` (64), station ``STATION_MAX`` (64);
- for a serial, a whole match of the bench config's ``unit.serial_pattern`` when it has one.

Whitespace around a value is removed first: spaces, and the CR, LF, TAB or separator that a
barcode scanner sends after a scan. A barcode scanner's group separator (GS, 0x1D: between the
fields of a GS1 code) *inside* a value is refused with its own message: the fields it separates
are not one serial, and joining them silently would record a serial no one typed. Scan the
serial's field alone (or set the scanner to send it alone).

Device identities (vendor, model, serial, firmware) come from hardware and are never refused:
:func:`from_device` bounds their length (``DEVICE_TEXT_MAX``) and the output functions make them
safe.

**On output**, one function per medium, each total (any ``str`` in, never raises):

- :func:`visible` (terminal): every control or format character, line or paragraph separator
  and lone surrogate written as a visible escape (``\\x1b``, ``\\r``, ``\\u202e``), so nothing
  reaches a terminal as an escape sequence and no value starts a line of its own;
  :func:`terminal_lines` joins lines made of such values;
- :func:`for_xml` (JUnit): the characters XML 1.0 forbids, and the other control characters,
  written as the same visible escapes;
- :func:`csv_cell` (CSV): visible escapes, and a cell that a spreadsheet would take for a
  formula (starting with ``=``, ``+``, ``-``, ``@``, TAB or CR) gets a leading ``'`` (OWASP's
  advice for CSV injection);
- :func:`file_name_part` (a folder name): accents dropped, ``[A-Za-z0-9._-]`` only, other runs
  as ``_``, at most ``FILE_PART_MAX_BYTES`` (64) bytes (a longer one cut and given a short hash
  of the whole, so two long serials stay apart), never empty, never ``.`` or ``..``.

The HTML report and the history page escape through Jinja2's autoescaping.
"""

from __future__ import annotations

import hashlib
import re
import unicodedata
from collections.abc import Iterable

from benchctl.errors import InputError

SERIAL_MAX = 64
OPERATOR_MAX = 128
PART_NUMBER_MAX = 64
STATION_MAX = 64
DEVICE_TEXT_MAX = 256  # a device's identity string beyond this is cut (…)
FILE_PART_MAX_BYTES = 64
SHOWN_MAX = 60  # a refused value is shown up to this many characters

GS = "\x1d"  # a barcode scanner's group separator (GS1 FNC1)
# refused on input, escaped on output: control (Cc), format (Cf), surrogate (Cs), private use
# (Co), unassigned (Cn), line and paragraph separators (Zl, Zp)
_REFUSED = frozenset({"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"})
# escaped on output (private-use and unassigned code points are shown as they are)
_ESCAPED = frozenset({"Cc", "Cf", "Cs", "Zl", "Zp"})
_NAMES = {"\t": "TAB", "\n": "LF", "\r": "CR", "\x1b": "ESC", "\x7f": "DEL", GS: "GS",
          "\x00": "NUL", "\x9b": "CSI"}
FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "\n")
_UNSAFE_FILE = re.compile(r"[^A-Za-z0-9._-]+")


# ------------------------------------------------------------------------------- output
def _escape(ch: str) -> str:
    o = ord(ch)
    if ch in "\t\n\r":
        return {"\t": "\\t", "\n": "\\n", "\r": "\\r"}[ch]
    if o <= 0xFF:
        return f"\\x{o:02x}"
    if o <= 0xFFFF:
        return f"\\u{o:04x}"
    return f"\\U{o:08x}"


def _escaped(ch: str) -> bool:
    return unicodedata.category(ch) in _ESCAPED


def visible(value: object) -> str:
    """``value`` as text safe on a terminal: control and format characters, line and
    paragraph separators and lone surrogates as visible escapes (``\\x1b``, ``\\r``,
    ``\\u2028``); everything else as it is."""
    s = value if isinstance(value, str) else str(value)
    if s.isprintable():  # the common case: nothing to escape (fast)
        return s
    return "".join(_escape(c) if _escaped(c) else c for c in s)


def terminal_lines(lines: Iterable[str]) -> str:
    """Lines for a terminal, one per item: each made :func:`visible` (a CR or LF inside an item
    is shown, never starts a line), joined with newlines."""
    return "\n".join(visible(ln) for ln in lines)


def _xml_ok(ch: str) -> bool:
    """A character XML 1.0 allows and that is no other control character (TAB, LF, CR kept
    out too: an attribute would fold them into spaces)."""
    o = ord(ch)
    if o < 0x20 or 0x7F <= o <= 0x9F:
        return False
    return not (0xD800 <= o <= 0xDFFF or o in (0xFFFE, 0xFFFF))


def for_xml(value: object) -> str:
    """``value`` as text any XML 1.0 parser reads back unchanged: the characters XML forbids
    (C0 controls, lone surrogates, U+FFFE, U+FFFF) and the other control characters (DEL, C1)
    as visible escapes; the markup characters are the XML writer's (``xml.etree``) to escape."""
    s = value if isinstance(value, str) else str(value)
    if all(_xml_ok(c) for c in s):
        return s
    return "".join(c if _xml_ok(c) else _escape(c) for c in s)


def csv_cell(value: object) -> str:
    """``value`` as a CSV cell: :func:`visible`, and a cell a spreadsheet would read as a
    formula (``=``, ``+``, ``-``, ``@``, TAB, CR first) prefixed with ``'``."""
    s = visible(value)
    return "'" + s if s.startswith(FORMULA_START) else s


def file_name_part(value: object, max_bytes: int = FILE_PART_MAX_BYTES) -> str:
    """``value`` as a piece of a file or folder name: accents dropped (``é`` → ``e``), then
    ``[A-Za-z0-9._-]`` only (other runs as ``_``), at most ``max_bytes`` bytes, never empty,
    never starting or ending with ``.``, ``-`` or ``_``. A value cut to fit, or with nothing
    left of it (``unnamed``), ends in ``~`` and 8 hex digits of its SHA-256, so two such values
    get different names."""
    if max_bytes < 17:
        raise ValueError(f"max_bytes = {max_bytes}: expected at least 17")
    s = value if isinstance(value, str) else str(value)
    digest = hashlib.sha256(s.encode("utf-8", "surrogatepass")).hexdigest()[:8]
    ascii_ = unicodedata.normalize("NFKD", s).encode("ascii", "ignore").decode("ascii")
    safe = _UNSAFE_FILE.sub("_", ascii_).strip("_.-")
    if not safe:
        return "unnamed" if not s else "unnamed~" + digest
    if len(safe) <= max_bytes:  # ASCII only: one byte a character
        return safe
    return safe[: max_bytes - 9].rstrip("_.-") + "~" + digest


def from_device(value: object, limit: int = DEVICE_TEXT_MAX) -> str:
    """A device's identity string as recorded: never refused (it comes from hardware), cut to
    ``limit`` characters (… marks the cut). Shown through :func:`visible` and friends."""
    s = value if isinstance(value, str) else str(value)
    return s if len(s) <= limit else s[: limit - 1] + "…"


# -------------------------------------------------------------------------------- input
def shown(value: str) -> str:
    """A refused value for a message: quoted, :func:`visible`, cut to ``SHOWN_MAX``."""
    v = visible(value)
    return "'" + (v if len(v) <= SHOWN_MAX else v[: SHOWN_MAX - 1] + "…") + "'"


def _char_name(ch: str) -> str:
    name = _NAMES.get(ch) or unicodedata.name(ch, "")
    code = f"U+{ord(ch):04X}"
    return f"{code} {name}" if name else code


def problem(value: str, max_chars: int, what: str) -> str | None:
    """What is wrong with ``value`` (already stripped) as a ``what`` of at most ``max_chars``
    characters, or None when nothing is (see the module notes)."""
    if not value:
        return f"expected the {what}, got nothing"
    if GS in value:
        return (f"contains a group separator (GS, 0x1D) at position {value.index(GS) + 1}, as "
                "a barcode scanner sends between the fields of a GS1 code; expected the "
                f"{what} alone: scan or type that field only")
    bad = next((c for c in value if unicodedata.category(c) in _REFUSED), None)
    if bad is not None:
        kind = {"Cc": "a control character", "Cf": "a format character",
                "Cs": "a lone surrogate", "Co": "a private-use character",
                "Cn": "an unassigned code point", "Zl": "a line separator",
                "Zp": "a paragraph separator"}[unicodedata.category(bad)]
        return (f"contains {kind} ({_char_name(bad)}) at position {value.index(bad) + 1}; "
                "expected printable text (letters, digits, punctuation, symbols, spaces)")
    if len(value) > max_chars:
        return f"{len(value)} characters long; expected at most {max_chars}"
    return None


def check_text(value: object, option: str, max_chars: int, what: str) -> str:
    """``value`` with the whitespace around it removed, or ``InputError`` naming ``option``,
    the value (shown safe) and what is expected: a non-empty printable text of at most
    ``max_chars`` characters (see the module notes). ``what`` names the field in the
    message (``serial number``)."""
    if not isinstance(value, str):
        raise InputError(f"{option} = {visible(repr(value))}: expected the {what} as text")
    s = value.strip()
    if not s and value:  # '   ', a lone TAB or CR: typed, but nothing of a value
        raise InputError(f"{option} {shown(value)}: blank (only whitespace); expected the "
                         f"{what}")
    bad = problem(s, max_chars, what)
    if bad is not None:
        raise InputError(f"{option} {shown(s or value)}: {bad}")
    return s


def check_serial(value: object, option: str = "--serial",
                 pattern: re.Pattern[str] | str | None = None,
                 pattern_source: str = "unit.serial_pattern") -> str:
    """The serial number of the unit under test (:func:`check_text`, ``SERIAL_MAX``), and a
    whole match of ``pattern`` (the config's ``unit.serial_pattern``) when given."""
    s = check_text(value, option, SERIAL_MAX, "serial number")
    if pattern is not None:
        rx = re.compile(pattern) if isinstance(pattern, str) else pattern
        if rx.fullmatch(s) is None:
            raise InputError(
                f"{option} {shown(s)}: does not match the serial pattern {visible(rx.pattern)!r} "
                f"({pattern_source}); expected a serial number of that form"
            )
    return s


def check_operator(value: object, option: str = "--operator") -> str:
    """Who runs the test (:func:`check_text`, ``OPERATOR_MAX``)."""
    return check_text(value, option, OPERATOR_MAX, "operator's name")


def check_part_number(value: object, option: str = "--part-number") -> str:
    """The unit's part number (:func:`check_text`, ``PART_NUMBER_MAX``)."""
    return check_text(value, option, PART_NUMBER_MAX, "part number")


def check_station(value: object, option: str = "station") -> str:
    """The bench's station name (:func:`check_text`, ``STATION_MAX``)."""
    return check_text(value, option, STATION_MAX, "station name")


__all__ = [
    "DEVICE_TEXT_MAX",
    "FILE_PART_MAX_BYTES",
    "FORMULA_START",
    "GS",
    "OPERATOR_MAX",
    "PART_NUMBER_MAX",
    "SERIAL_MAX",
    "STATION_MAX",
    "check_operator",
    "check_part_number",
    "check_serial",
    "check_station",
    "check_text",
    "csv_cell",
    "file_name_part",
    "for_xml",
    "from_device",
    "problem",
    "shown",
    "terminal_lines",
    "visible",
]
