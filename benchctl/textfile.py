"""Files from users (configs, profiles, plans, register maps, CSVs): read with bounds.

Every input file benchctl reads for a user goes through :func:`read_input`: it must be a regular
file (a symlink to one is fine) of at most a stated size, else the caller's error names the file,
what it is and what was expected — before anything is read. A device (``/dev/zero``,
``/dev/urandom``), a folder, a FIFO or a socket is refused at once: the file is opened with
``O_NONBLOCK`` (opening a FIFO with no writer never waits) and checked with ``fstat`` on that
same descriptor, so what is checked is what is read. The size is checked twice: by ``fstat``,
and while reading (a file that grows, or one whose size the kernel does not know, stops one byte
past the cap). A library that parses faster from a path than from bytes (numpy's loadtxt) may
read the same file again through the descriptor (:func:`input_file`: ``/proc/self/fd/N``, the
same inode) while it is still open; what it read is used only if the file is unchanged since.

Text is UTF-8 (:func:`decode_utf8`), or an error that names the line and the byte.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from benchctl.errors import InputError

MiB = 1024 * 1024
MAX_YAML_BYTES = 16 * MiB  # a bench config, profile, plan or register map (real ones: < 100 kB)
MAX_CSV_BYTES = 512 * MiB  # a CSV: 10⁷ rows of time,reference,device (the analysis grid's cap)
_CHUNK = 4 * MiB


def size_text(n: int) -> str:
    """``16 MiB``, ``512 MiB``, ``1.5 kB``: a byte count as a reader would say it."""
    if n >= MiB:
        return f"{n / MiB:g} MiB"
    if n >= 1024:
        return f"{n / 1024:g} kB"
    return f"{n} bytes"


def file_kind(mode: int) -> str:
    """What a file is, from its ``st_mode``: ``a regular file``, ``a character device``…"""
    kinds = (
        (stat.S_ISREG, "a regular file"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a FIFO (named pipe)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISLNK, "a symbolic link"),
    )
    for test, name in kinds:
        if test(mode):
            return name
    return "not a regular file"  # pragma: no cover - every Linux type is listed


def _expected(what: str, max_bytes: int) -> str:
    return f"expected the {what} as a regular file of at most {size_text(max_bytes)}"


def _check(st: os.stat_result, path: Path, what: str, error: type[InputError],
           max_bytes: int) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: {file_kind(st.st_mode)}; {_expected(what, max_bytes)}")
    if st.st_size > max_bytes:
        raise error(
            f"{path}: {st.st_size} bytes ({size_text(st.st_size)}); "
            f"{_expected(what, max_bytes)}"
        )


def read_input(path: Path, what: str, error: type[InputError], max_bytes: int) -> bytes:
    """The bytes of ``path``, a regular file of at most ``max_bytes``; else ``error`` naming
    the file, what it is (a device, a FIFO, a folder, its size) and ``what`` was expected.
    Never blocks on a FIFO or a device and never reads more than ``max_bytes + 1`` bytes."""
    with input_file(path, what, error, max_bytes) as f:
        return f.data


@dataclass(frozen=True)
class InputFile:
    """A file read by :func:`input_file`: its bytes, and the open descriptor they came from."""

    data: bytes
    fd: int
    stat: os.stat_result

    def reopened(self) -> str | None:
        """A path by which a library may read the very same file again while it is open
        (``/proc/self/fd/N``: the same inode, whatever its name now points at), or None where
        the system has no such path. Check :meth:`unchanged` after that read."""
        proc = f"/proc/self/fd/{self.fd}"
        return proc if os.path.exists(proc) else None

    def unchanged(self) -> bool:
        """The file still holds what was read: its size, modification and change times are
        those it had before the read (a second reader read the same bytes)."""
        try:
            now = os.fstat(self.fd)
        except OSError:
            return False
        then = self.stat
        return (now.st_size, now.st_mtime_ns, now.st_ctime_ns) == (
            len(self.data), then.st_mtime_ns, then.st_ctime_ns)


@contextlib.contextmanager
def input_file(path: Path, what: str, error: type[InputError],
               max_bytes: int) -> Iterator[InputFile]:
    """:func:`read_input`, the descriptor kept open while the block runs (see
    :meth:`InputFile.reopened`)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as e:
        raise error(f"{path}: cannot read {what}: {e.strerror or e}") from None
    try:
        try:
            st = os.fstat(fd)
            _check(st, path, what, error, max_bytes)
            chunks: list[bytes] = []
            total = 0
            while True:
                chunk = os.read(fd, min(_CHUNK, max_bytes + 1 - total))
                if not chunk:
                    break
                chunks.append(chunk)
                total += len(chunk)
                if total > max_bytes:
                    raise error(
                        f"{path}: more than {size_text(max_bytes)}; {_expected(what, max_bytes)}"
                    )
        except OSError as e:
            raise error(f"{path}: cannot read {what}: {e.strerror or e}") from None
        data = b"".join(chunks)
        del chunks
        yield InputFile(data, fd, st)
    finally:
        os.close(fd)


def check_input_file(path: Path, what: str, error: type[InputError], max_bytes: int) -> None:
    """The checks of :func:`read_input` without reading, for a file a library opens itself
    (a DBC, an EDS): ``error`` unless ``path`` is a regular file of at most ``max_bytes``."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise error(f"{path}: cannot read {what}: {e.strerror or e}") from None
    _check(st, path, what, error, max_bytes)


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
