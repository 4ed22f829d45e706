"""One run per stand: an exclusive ``fcntl.flock`` on a lock file per stand endpoint.

The endpoint is the stand's: Modbus TCP ``host:port`` (the host resolved; every loopback or
wildcard address counts as ``localhost``), Modbus RTU the serial device's real path (symlinks
followed). The lock files live in ``run.lock_dir``, one per endpoint, e.g.
``/run/benchctl-locks/stand-tcp_localhost_5020.lock``. The holder writes who it is into its file
as one JSON object (``pid``, ``command``, ``serial``, ``operator``, ``start_utc``, ``user``,
``host``, ``config``, ``recording``, ``endpoint``): ``cat`` the file to see it.

A second ``benchctl run`` on a stand in use is refused with ``StandInUse`` naming the holder,
before it connects to anything. The kernel releases the lock when the holder's process ends,
however it ends (``kill -9`` included). A holder that ends normally removes its file (while it
still holds the lock; a taker checks that the file it locked is still the one at the path, so
removing cannot let two runs in); after a ``kill -9`` the file stays, with the dead holder's
details, until the next run takes it over.

The lock folder is shared by every user of the machine (one stand, one lock, whoever runs), and
benchctl often runs as root on a line PC, so nothing in it may be turned against the one who
runs:

- The folder must belong to this user or to root, and must not be writable by the group or by
  others unless it has the sticky bit (like ``/tmp``: then only a file's owner, the folder's
  owner or root may remove or rename a file in it). Else ``ConfigError``: another user could
  swap the lock files in it. A symlink as the folder must belong to this user or root too.
- The default folder, ``/run/benchctl-locks``, is one another user cannot create first (``/run``
  is root's): root creates it on first use, mode 1777 (every user may create lock files, none
  may remove another's). A user other than root cannot create it: an administrator creates it
  once (``install -d -m 1777 /run/benchctl-locks``; to keep it over a reboot, a systemd-tmpfiles
  line ``d /run/benchctl-locks 1777 root root -``), or the config names a folder of the user's
  own in ``run.lock_dir`` (which then serialises only that user's runs). A folder in ``/tmp``
  would not do: anyone can create it first, own it, and swap its files.
- A lock file is created exclusively (``O_CREAT | O_EXCL | O_NOFOLLOW``, mode 0644 under the
  umask: readable by all, so other users' runs can lock it and name its holder; written only
  by its owner) and never chmod'ed. An existing one is opened with ``O_NOFOLLOW`` (and
  ``O_NONBLOCK``) and used only if it is a regular file with one link: a symlink, a hard link,
  a FIFO or a device at that path is refused with ``ConfigError`` naming it, never opened for
  writing, never removed.
- An existing file is written into only if it belongs to this user (a ``kill -9``'d run of this
  user: taken over, as before). Another user's file left by a killed run is locked as it is;
  root (or the folder's owner) removes it under the lock and makes its own, anyone else holds
  the lock on it without writing its details.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import getpass
import ipaddress
import json
import os
import pwd
import re
import socket
import stat
import time
from collections.abc import Iterator, Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchctl.config import BenchConfig, StandConfig
from benchctl.errors import ConfigError, StandInUse
from benchctl.jsonout import dumps
from benchctl.textfile import file_kind

DEFAULT_LOCK_DIR = Path("/run/benchctl-locks")  # only root can create it: see the docstring
HOLDER_WAIT_S = 1.0  # a holder that has just taken the lock writes its details within this
LOCK_FILE_MODE = 0o644  # created so (under the umask), never chmod'ed
_OPEN_FLAGS = os.O_NOFOLLOW | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC
#: an in-process link's URL (benchctl.channels): a simulated stand of this process only
IN_PROCESS_SCHEME = "simchan://"


def endpoint_key(stand: StandConfig) -> str:
    """The stand's endpoint as a lock key: ``tcp HOST:PORT`` or ``rtu /real/device/path``.

    A simulated stand on an in-process link (``simchan://NAME``, simulated time) exists only in
    the process that made it: its key names that process (``… pid N``), so two processes'
    simulated stands of the same name (two test workers) are two stands, while two runs on one
    of them in its process still exclude each other."""
    where = str(stand.serial_port if stand.driver == "modbus-rtu" else stand.host)
    if where.startswith(IN_PROCESS_SCHEME):
        kind = "rtu" if stand.driver == "modbus-rtu" else "tcp"
        port = "" if kind == "rtu" else f":{stand.port}"
        return f"{kind} {where}{port} pid {os.getpid()}"
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


def _owner(uid: int) -> str:
    try:
        return f"user {pwd.getpwuid(uid).pw_name} (uid {uid})"
    except KeyError:
        return f"uid {uid}"


def open_lock_dir(lock_dir: Path) -> int:
    """A descriptor of the lock folder, checked: it belongs to this user or root and is not
    writable by the group or others without the sticky bit; ``ConfigError`` naming the folder,
    what is wrong and what was expected. A missing folder is created (the default one, by root,
    mode 1777)."""
    me = os.geteuid()
    where = "field run.lock_dir"
    created = False
    if not os.path.lexists(lock_dir):
        try:
            if lock_dir == DEFAULT_LOCK_DIR:
                os.mkdir(lock_dir, 0o755)  # made shared below, once it is known to be ours
            else:
                lock_dir.mkdir(parents=True, mode=0o755)
            created = True
        except FileExistsError:
            pass  # another run made it meanwhile: checked below like any folder
        except OSError as e:
            hint = (
                "only root can create it: create it once as root (install -d -m 1777 "
                f"{lock_dir}) or set {where} to a folder of yours"
                if lock_dir == DEFAULT_LOCK_DIR and e.errno in (errno.EACCES, errno.EPERM)
                else f"expected a folder you can create or write in {where}"
            )
            raise ConfigError(
                f"{lock_dir}: cannot create the stand lock folder: {e.strerror or e}; {hint}"
            ) from None
    try:
        link = os.lstat(lock_dir)
        fd = os.open(lock_dir, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    except OSError as e:
        raise ConfigError(
            f"{lock_dir}: cannot open the stand lock folder: {e.strerror or e}; expected a "
            f"folder in {where}"
        ) from None
    try:
        st = os.fstat(fd)
        if stat.S_ISLNK(link.st_mode) and link.st_uid not in (me, 0):
            raise ConfigError(
                f"{lock_dir}: the stand lock folder is a symlink owned by {_owner(link.st_uid)}, "
                f"not by you or root; refused (it could point anywhere); expected a folder of "
                f"yours or root's in {where}"
            )
        if st.st_uid not in (me, 0):
            raise ConfigError(
                f"{lock_dir}: the stand lock folder is owned by {_owner(st.st_uid)}, not by you "
                f"({_owner(me)}) or root; refused: its owner could replace the lock files in it; "
                f"expected a folder of yours or root's in {where} (the default "
                f"{DEFAULT_LOCK_DIR} is made by root)"
            )
        if created and lock_dir == DEFAULT_LOCK_DIR:
            os.fchmod(fd, 0o1777)  # shared by every user, like /tmp
            st = os.fstat(fd)
        if st.st_mode & 0o022 and not st.st_mode & stat.S_ISVTX:
            raise ConfigError(
                f"{lock_dir}: the stand lock folder is writable by "
                f"{'others' if st.st_mode & 0o002 else 'its group'} without the sticky bit "
                f"(mode {stat.S_IMODE(st.st_mode):04o}); refused: anyone who may write there "
                f"could replace the lock files; expected mode 1777 like /tmp (chmod +t "
                f"{lock_dir}), or a folder only you can write ({where})"
            )
    except BaseException:
        os.close(fd)
        raise
    return fd


class StandLock:
    """The lock of one stand endpoint; ``acquire(holder)`` or ``StandInUse``."""

    def __init__(self, key: str, lock_dir: Path) -> None:
        self.key = key
        self.lock_dir = Path(lock_dir)
        self.path = lock_file(self.lock_dir, key)
        self._fd: int | None = None
        self._dir_fd: int | None = None
        self._mine = False  # the file is ours: written into, removed on release

    @property
    def held(self) -> bool:
        return self._fd is not None

    def _refuse(self, what: str) -> ConfigError:
        return ConfigError(
            f"{self.path}: {what}; refused: a stand's lock file is never followed, written "
            "through or removed when it is not a plain file of its own; remove it (and find "
            "out who made it) before running"
        )

    def _open(self, dfd: int) -> int:
        """The lock file, created exclusively, or the one there if it is a regular file with
        one link (``ConfigError`` for anything else); -1 when it changed meanwhile."""
        name = self.path.name
        try:
            return os.open(name, os.O_RDWR | os.O_CREAT | os.O_EXCL | _OPEN_FLAGS,
                           LOCK_FILE_MODE, dir_fd=dfd)
        except FileExistsError:
            pass
        except OSError as e:
            raise ConfigError(
                f"{self.path}: cannot create the stand's lock file: {e.strerror or e}; "
                "expected a folder you can write in field run.lock_dir"
            ) from None
        try:
            seen = os.stat(name, dir_fd=dfd, follow_symlinks=False)
        except FileNotFoundError:
            return -1  # its holder removed it meanwhile: again
        if stat.S_ISLNK(seen.st_mode):
            try:
                target = os.readlink(name, dir_fd=dfd)
            except OSError:
                target = "?"
            raise self._refuse(f"a symbolic link (to {target}), not a lock file")
        if not stat.S_ISREG(seen.st_mode):
            raise self._refuse(_kind(seen.st_mode))
        if seen.st_nlink != 1:
            raise self._refuse(f"a file with {seen.st_nlink} links (a hard link to another file)")
        fd = -1
        for flags in (os.O_RDWR, os.O_RDONLY):  # another user's file: read-only is enough
            try:
                fd = os.open(name, flags | _OPEN_FLAGS, dir_fd=dfd)
                break
            except PermissionError:
                continue
            except FileNotFoundError:
                return -1
            except OSError as e:
                if e.errno == errno.ELOOP:  # made a symlink since: looked at again
                    return -1
                raise ConfigError(
                    f"{self.path}: cannot open the stand's lock file: {e.strerror or e}"
                ) from None
        if fd < 0:
            raise ConfigError(
                f"{self.path}: a lock file of {_owner(seen.st_uid)} that you cannot read (mode "
                f"{stat.S_IMODE(seen.st_mode):04o}): the stand may be in use by them; refused: "
                "expected a lock file every user can read (benchctl makes them 0644); ask its "
                "owner or root to remove it when no run of theirs holds the stand"
            )
        st = os.fstat(fd)
        if (st.st_dev, st.st_ino) != (seen.st_dev, seen.st_ino) or st.st_nlink != 1:
            os.close(fd)  # replaced between the look and the open: again
            return -1
        return fd

    def acquire(self, holder: Mapping[str, Any]) -> None:
        """Take the lock (never waits) and write ``holder`` into the file; ``StandInUse``
        naming the current holder when another process has it; ``ConfigError`` when the lock
        folder or the file at the lock's path is not safe to use (see the module)."""
        if self._fd is not None:
            return
        dfd = open_lock_dir(self.lock_dir)
        try:
            fd, mine = self._take(dfd)
        except BaseException:
            os.close(dfd)
            raise
        self._fd, self._dir_fd, self._mine = fd, dfd, mine
        if not mine:
            return  # another user's file: locked, never written
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

    def _take(self, dfd: int) -> tuple[int, bool]:
        """(locked descriptor, ours to write and remove)."""
        for _ in range(100):
            fd = self._open(dfd)
            if fd < 0:
                continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                other = _read_holder(fd, wait_s=HOLDER_WAIT_S)
                os.close(fd)
                raise StandInUse(
                    f"stand {self.key} is in use by {_who(other)}; lock file {self.path}. "
                    "Refused before connecting: wait for that run to end, or stop it",
                    other,
                ) from None
            if not _same_file(fd, dfd, self.path.name):
                os.close(fd)  # its last holder removed it between our open and our lock
                continue
            if os.fstat(fd).st_uid == os.geteuid() and _writable(fd):
                return fd, True
            # another user's file, left by a killed run: removed under the lock if we may
            # (root, or the folder's owner), then made anew; else held as it is
            try:
                os.unlink(self.path.name, dir_fd=dfd)
            except OSError:
                return fd, False
            os.close(fd)
        raise ConfigError(  # pragma: no cover - a path replaced 100 times in a row
            f"{self.path}: cannot take the stand's lock (the file keeps changing)"
        )

    def release(self) -> None:
        """Remove the file (still holding the lock; only a file of ours) and let go;
        idempotent."""
        fd, self._fd = self._fd, None
        dfd, self._dir_fd = self._dir_fd, None
        if fd is None:
            return
        if self._mine and dfd is not None:
            with contextlib.suppress(OSError):
                if _same_file(fd, dfd, self.path.name):
                    os.unlink(self.path.name, dir_fd=dfd)
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
        if dfd is not None:
            os.close(dfd)

    def holder(self) -> dict[str, Any] | None:
        """The details in the lock file: its holder's (or a killed holder's), None when free
        (or when the path holds no regular file: a symlink is never followed)."""
        try:
            fd = os.open(self.path, os.O_RDONLY | _OPEN_FLAGS)
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


def _kind(mode: int) -> str:

    return f"{file_kind(mode)}, not a lock file"


def _writable(fd: int) -> bool:
    return fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_RDWR


def _who(other: dict[str, Any] | None) -> str:
    if not other:
        return "another process (no details)"
    if not process_alive(other.get("pid")):  # one that could not write into another's file
        return ("another process, which could not write its details (the file holds those "
                f"of a finished run: {describe_holder(other)})")
    return describe_holder(other)


def _same_file(fd: int, dfd: int, name: str) -> bool:
    try:
        a, b = os.fstat(fd), os.stat(name, dir_fd=dfd, follow_symlinks=False)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def _user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return str(os.getuid())


def process_alive(pid: Any) -> bool:
    """Whether process ``pid`` (a holder's, as its lock file says) still runs; another user's
    process counts as running."""
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
        if ((found is not None and process_alive(found.get("pid")))
                or time.monotonic() >= deadline):
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
    lock_dir = lock_dir_of(cfg)
    if not os.path.lexists(lock_dir):
        return  # no lock folder yet: no run holds anything (and a user may not create it)
    lock = StandLock(endpoint_key(cfg.stand), lock_dir)
    lock.acquire(holder)
    lock.release()
