"""Files benchctl writes whole (a record, a report, ``meta.json``, ``end.json``): written to a
temporary file beside the target, flushed to the disk and renamed over it, so a reader sees
the old file or the new one, never half of one. When the write fails (a full disk) the
temporary file is removed: nothing half-written is left behind."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

TMP_SUFFIX = ".tmp"


def atomic_write_bytes(path: Path, data: bytes, *, tmp_name: str | None = None) -> None:
    """Write ``data`` as ``path`` atomically (see the module notes); raises the ``OSError``.
    ``tmp_name``: the temporary file's name in the same folder (default ``<name>.tmp``)."""
    path = Path(path)
    tmp = path.with_name(tmp_name or path.name + TMP_SUFFIX)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8, ``\\n`` line ends as given) as ``path`` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


__all__ = ["TMP_SUFFIX", "atomic_write_bytes", "atomic_write_text"]
