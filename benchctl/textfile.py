"""Text files from users (configs, profiles, CSVs): UTF-8, or an error that names the byte."""

from __future__ import annotations

from pathlib import Path

from benchctl.errors import InputError


def decode_utf8(raw: bytes, path: Path, what: str, error: type[InputError]) -> str:
    """``raw`` as UTF-8 text (a leading byte-order mark dropped); else ``error`` naming the
    file, the line and the byte offset of the first byte that is not UTF-8."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        raise error(
            f"{path}: line {line}: byte 0x{raw[e.start]:02x} at offset {e.start} is not UTF-8; "
            f"expected a UTF-8 text {what}"
        ) from None
