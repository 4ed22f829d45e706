"""One run per stand: an exclusive ``fcntl.flock`` on a lock file per stand endpoint.

The endpoint is the stand's: Modbus TCP ``host:port`` (the host resolved; every loopback or
wildcard address counts as ``localhost``), Modbus RTU the serial device's real path (symlinks
followed). The lock files live in ``run.lock_dir`` (default ``<system temp>/benchctl-locks``, one
folder for every user of the machine), one per endpoint, e.g.
``/tmp/benchctl-locks/stand-tcp_localhost_5020.lock``. The holder writes who it is into its file
as one JSON object (``pid``, ``command``, ``serial``, ``operator``, ``start_utc``, ``user``,
``host``, ``config``, ``recording``, ``endpoint``): ``cat`` the file to see it.

A second ``benchctl run`` on a stand in use is refused with ``StandInUse`` naming the holder,
before it connects to anything. The kernel releases the lock when the holder's process ends,
however it ends (``kill -9`` included). A holder that ends normally removes its file (while it
still holds the lock; a taker checks that the file it locked is still the one at the path, so
removing cannot let two runs in); after a ``kill -9`` the file stays, with the dead holder's
details, until the next run takes it over.
"""

from __future__ import annotations

import contextlib
import fcntl
import getpass
import ipaddress
import json
import os
import re
import socket
import stat
import tempfile
import time
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchctl.config import BenchConfig, StandConfig
from benchctl.errors import ConfigError, StandInUse
from benchctl.jsonout import dumps

DEFAULT_LOCK_DIR = Path(tempfile.gettempdir()) / "benchctl-locks"
HOLDER_WAIT_S = 1.0  # a holder that has just taken the lock writes its details within this


def endpoint_key(stand: StandConfig) -> str:
    """The stand's endpoint as a lock key: ``tcp HOST:PORT`` or ``rtu /real/device/path``."""
    if stand.driver == "modbus-rtu":
        port = str(stand.serial_port)
        if "://" in port:  # a pyserial URL: as given
            return f"rtu {port}"
        return f"rtu {os.path.realpath(port)}"
    return f"tcp {_host(stand.host, stand.port)}:{stand.port}"


def _host(host: str, port: int) -> str:
    try:
        addr = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][4][0]
    except (OSError, IndexError, UnicodeError):
        return host.lower()
    try:
        ip = ipaddress.ip_address(str(addr).split("%")[0])
    except ValueError:
        return str(addr)
    if ip.is_loopback or ip.is_unspecified:
        return "localhost"
    return str(ip)


def lock_dir_of(cfg: BenchConfig) -> Path:
    return cfg.run.lock_dir or DEFAULT_LOCK_DIR


def lock_file(lock_dir: Path, key: str) -> Path:
    return lock_dir / ("stand-" + re.sub(r"[^A-Za-z0-9.-]+", "_", key).strip("_") + ".lock")


def describe_holder(h: Mapping[str, Any]) -> str:
    """``benchctl run (pid 1234, user ana on bench-pc): serial S, operator O, since T``."""
    who = f"{h.get('command') or 'benchctl'} (pid {h.get('pid', '?')}"
    if h.get("user") or h.get("host"):
        who += f", user {h.get('user', '?')} on {h.get('host', '?')}"
    who += ")"
    parts = [f"{k} {h[k]}" for k in ("serial", "operator") if h.get(k)]
    if h.get("start_utc"):
        parts.append(f"since {h['start_utc']}")
    if h.get("recording"):
        parts.append(f"recording {h['recording']}")
    return who + (": " + ", ".join(parts) if parts else "")


class StandLock:
    """The lock of one stand endpoint; ``acquire(holder)`` or ``StandInUse``."""

    def __init__(self, key: str, lock_dir: Path) -> None:
        self.key = key
        self.lock_dir = Path(lock_dir)
        self.path = lock_file(self.lock_dir, key)
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def _open(self) -> int:
        try:
            if not self.lock_dir.is_dir():
                self.lock_dir.mkdir(parents=True, exist_ok=True)
                if self.lock_dir == DEFAULT_LOCK_DIR:  # shared by every user, like /tmp
                    with contextlib.suppress(OSError):
                        os.chmod(self.lock_dir, 0o1777)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as e:
            raise ConfigError(
                f"{self.path}: cannot open the stand's lock file: {e.strerror}; "
                "expected a writable folder in field run.lock_dir"
            ) from None
        with contextlib.suppress(OSError):  # another user's run must be able to lock it too
            if os.fstat(fd).st_uid == os.getuid():
                os.fchmod(fd, 0o666)
        return fd

    def acquire(self, holder: Mapping[str, Any]) -> None:
        """Take the lock (never waits) and write ``holder`` into the file; ``StandInUse``
        naming the current holder when another process has it."""
        if self._fd is not None:
            return
        for _ in range(100):
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                other = _read_holder(fd, wait_s=HOLDER_WAIT_S)
                os.close(fd)
                who = describe_holder(other) if other else "another process (no details)"
                raise StandInUse(
                    f"stand {self.key} is in use by {who}; lock file {self.path}. Refused before "
                    "connecting: wait for that run to end, or stop it",
                    other,
                ) from None
            if _same_file(fd, self.path):
                break
            os.close(fd)  # its last holder removed it between our open and our lock: again
        else:  # pragma: no cover - a path replaced 100 times in a row
            raise ConfigError(
                f"{self.path}: cannot take the stand's lock (the file keeps changing)"
            )
        info = {
            **holder,
            "pid": os.getpid(),
            "user": _user(),
            "host": socket.gethostname(),
            "endpoint": self.key,
        }
        info.setdefault("start_utc", datetime.now(UTC).isoformat(timespec="seconds"))
        data = (dumps(info) + "\n").encode()
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, data, 0)
        except OSError:
            pass  # the lock holds all the same; a refused run then says "no details"
        self._fd = fd

    def release(self) -> None:
        """Remove the file (still holding the lock) and let go; idempotent."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        with contextlib.suppress(OSError):
            if _same_file(fd, self.path):
                os.unlink(self.path)
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)

    def holder(self) -> dict[str, Any] | None:
        """The details in the lock file: its holder's (or a killed holder's), None when free."""
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError:
            return None
        try:
            return _read_holder(fd, wait_s=0.0)
        finally:
            os.close(fd)

    def __enter__(self) -> StandLock:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def _same_file(fd: int, path: Path) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(path)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return str(os.getuid())


def _alive(pid: Any) -> bool:
    try:
        os.kill(int(pid), 0)
    except PermissionError:
        return True  # another user's process
    except (OSError, ValueError, TypeError):
        return False
    return True


def _read_holder(fd: int, wait_s: float) -> dict[str, Any] | None:
    """The holder's JSON; waits up to ``wait_s`` for a fresh holder to write its details (an
    empty file, or the details of a dead process, are from before it)."""
    deadline = time.monotonic() + wait_s
    found: dict[str, Any] | None = None
    while True:
        try:
            st = os.fstat(fd)
            raw = os.pread(fd, min(st.st_size, 65536), 0) if stat.S_ISREG(st.st_mode) else b""
            obj = json.loads(raw.decode("utf-8", errors="replace")) if raw.strip() else None
            found = obj if isinstance(obj, dict) else None
        except (OSError, ValueError):
            found = None
        if (found is not None and _alive(found.get("pid"))) or time.monotonic() >= deadline:
            return found
        time.sleep(0.02)


@contextlib.contextmanager
def stand_lock(cfg: BenchConfig, holder: Mapping[str, Any]) -> Iterator[StandLock]:
    """Hold the lock of ``cfg``'s stand while the block lasts (``StandInUse`` if taken)."""
    lock = StandLock(endpoint_key(cfg.stand), lock_dir_of(cfg))
    lock.acquire(holder)
    try:
        yield lock
    finally:
        lock.release()


def check_free(cfg: BenchConfig, holder: Mapping[str, Any]) -> None:
    """``StandInUse`` when a run holds ``cfg``'s stand endpoint (for ``benchctl sim``, which
    serves that endpoint but must not keep a run from locking it)."""
    lock = StandLock(endpoint_key(cfg.stand), lock_dir_of(cfg))
    lock.acquire(holder)
    lock.release()
