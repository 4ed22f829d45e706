"""One exception tree for everything benchctl raises.

::

    BenchError                      root; the CLI maps every BenchError to exit code 2
    ├── InputError                  bad user input: a file, a column, a value
    │   ├── ConfigError             bench config or profile YAML fails validation
    │   ├── DataError               a recording/CSV is unusable (NaN, non-monotonic time, gaps…)
    │   │   └── RecordingError      a recording cannot be written (disk full, I/O error): names
    │   │                           the file and the errno
    │   └── LimitError              a motion exceeds the stand limits (needed vs allowed)
    ├── AnalysisError               an internal cross-check failed (Parseval): a bug, never silent
    ├── ArchiveError                the results archive (a database) cannot be opened or written;
    │                               names the archive (password hidden) and the cause
    ├── DeviceError                 a device answered with an error or could not be used
    │   ├── DeviceTimeout           no answer in time (also a TimeoutError)
    │   ├── ConnectionLost          a link dropped mid-run
    │   ├── ProtocolError           a malformed frame, bad CRC/checksum, Modbus exception
    │   │   └── ModbusException     the device returned a Modbus exception code
    │   ├── StandFault              the stand reports a fault or an E-stop
    │   └── StandInUse              another benchctl process holds the stand (its lock); names it
    ├── SafetyAbort                 the run was stopped for safety (signal, tracking error, silent
    │                               instrument…); carries the reason
    └── SimulationHang              a run on simulated time cannot go on: a thread waits outside the
                                    clock, or every thread waits for something nobody will do;
                                    names the threads and what each waits on

Example scenarios: a profile asking 30°/s from a stand allowing 20°/s raises ``LimitError``
before anything moves; a stand that stops answering raises ``DeviceTimeout``; Ctrl-C during a
run becomes ``SafetyAbort("interrupted by SIGINT")`` and goes through the one cleanup path; a
full disk mid-run raises ``RecordingError`` once (later rows are dropped and counted) and aborts
the run the same way.

Outside the tree: ``Interrupted`` (a ``KeyboardInterrupt``) is what SIGINT, SIGTERM, SIGHUP or
SIGQUIT raise when no run is there to take them (``benchctl.exits``); the CLI turns it into a
one-line message and exit code 2.
"""

from __future__ import annotations

import errno as _errno
import os
import signal
from pathlib import Path


class BenchError(Exception):
    """Root of all benchctl errors."""


class InputError(BenchError):
    """Bad input from the user: a file, a field, a value. Messages name all three."""


class ConfigError(InputError):
    """A bench config or a profile failed validation."""


class DataError(InputError):
    """A recording or CSV cannot be analysed as it is."""


#: the errors that mean "no room to write": a full disk, a user's quota, a file size limit
DISK_FULL_ERRNOS = frozenset(
    e for e in (_errno.ENOSPC, getattr(_errno, "EDQUOT", None), _errno.EFBIG) if e is not None
)


def is_disk_full(e: BaseException) -> bool:
    """True for an ``OSError`` that says there is no room to write (``DISK_FULL_ERRNOS``)."""
    return isinstance(e, OSError) and e.errno in DISK_FULL_ERRNOS


class RecordingError(DataError):
    """A recording could not be written (disk full, I/O error). Names the file and the errno."""

    def __init__(self, message: str, path: Path | None = None, errno: int | None = None) -> None:
        self.path = path
        self.errno = errno
        super().__init__(message)

    @classmethod
    def from_oserror(cls, path: Path, e: OSError, what: str = "write") -> RecordingError:
        code = e.errno
        name = _errno.errorcode.get(code, str(code)) if code is not None else "?"
        text = (e.strerror or os.strerror(code)) if code is not None else str(e)
        if code == _errno.ENOSPC:
            head = "disk full"
        elif code == getattr(_errno, "EDQUOT", None):
            head = "disk quota exceeded"
        else:
            head = "write error"
        return cls(f"{head}: cannot {what} {path} ({name}, errno {code}: {text})", path, code)

    @classmethod
    def disk_full(cls, e: BaseException, path: Path | None = None) -> RecordingError | None:
        """``e`` as a ``RecordingError`` when it is a disk-full ``OSError`` (``is_disk_full``),
        naming ``e.filename`` or else ``path``; None for anything else."""
        if isinstance(e, RecordingError) or not is_disk_full(e):
            return e if isinstance(e, RecordingError) else None
        assert isinstance(e, OSError)
        where = Path(e.filename) if e.filename else path
        return cls.from_oserror(where if where is not None else Path("?"), e)


class LimitError(InputError):
    """A motion exceeds the stand's limits; the message gives needed vs allowed."""


class AnalysisError(BenchError):
    """An internal consistency check of the analysis failed: a bug, raised, never hidden."""


class ArchiveError(BenchError):
    """The results archive cannot be reached, migrated or written (or its URL is wrong).
    ``kind`` says which, as it is: ``refused`` (the database will not take this record: it
    is set aside, the others still go), ``locked``, ``timed out``, ``read-only``, ``denied``
    (the login), ``unreachable``, ``failed`` (anything else)."""

    def __init__(self, message: str, kind: str = "failed") -> None:
        super().__init__(message)
        self.kind = kind


class DeviceError(BenchError):
    """A device answered with an error or could not be used."""


class DeviceTimeout(DeviceError, TimeoutError):
    """A device did not answer in time."""


class ConnectionLost(DeviceError):
    """The link to a device dropped."""


class ProtocolError(DeviceError):
    """A malformed frame, a bad CRC or checksum, an unexpected reply."""


class ModbusException(ProtocolError):
    """The device returned a Modbus exception response."""

    def __init__(self, function_code: int, exception_code: int, message: str = "") -> None:
        self.function_code = function_code
        self.exception_code = exception_code
        super().__init__(
            message
            or f"Modbus exception {exception_code} in reply to function code {function_code}"
        )


class StandFault(DeviceError):
    """The stand reports a fault (with its code) or an E-stop."""

    def __init__(self, message: str, code: int | None = None) -> None:
        self.code = code
        super().__init__(message)


class StandInUse(DeviceError):
    """Another benchctl process holds the stand's lock; the message names the holder."""

    def __init__(self, message: str, holder: dict[str, object] | None = None) -> None:
        self.holder = holder or {}
        super().__init__(message)


class SafetyAbort(BenchError):
    """The run was stopped for safety; ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


class SimulationHang(BenchError):
    """A run on simulated time cannot go on (a wait outside the clock, or all threads blocked)."""


class Interrupted(KeyboardInterrupt):
    """A signal (SIGINT, SIGTERM, SIGHUP, SIGQUIT) with no run there to take it over."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        try:
            self.signame = signal.Signals(signum).name
        except ValueError:
            self.signame = f"signal {signum}"
        super().__init__(f"interrupted by {self.signame}")
