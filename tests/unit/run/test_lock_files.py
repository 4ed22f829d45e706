"""The stand's lock cannot be turned into a weapon: a symlink, a hard link or a FIFO at a lock
file's path is refused and left as it is (its target untouched), lock files are created
exclusively and never made writable by others, and a lock folder another user owns, or one
writable by others without the sticky bit, is refused. The old lock followed a planted
symlink: it truncated the target, wrote JSON into it, chmod'ed it 0666 and removed the link.

Some cases need root (``chown`` to another user, a process of another user): the tests run as
root in CI; not root, such a test fails rather than skips."""

from __future__ import annotations

import json
import os
import signal
import stat
import tempfile
import time
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchctl.errors import ConfigError, StandInUse
from benchctl.run import lock as lockmod
from benchctl.run.lock import LOCK_FILE_MODE, StandLock, lock_file, open_lock_dir

KEY = "tcp localhost:5020"
NOBODY = 65534


@pytest.fixture
def as_root() -> None:
    """A test that makes files of another user needs root (CI runs as root): without it the
    test fails, never skips."""
    if os.geteuid() != 0:
        pytest.fail("needs root (chown to another user, a process of another user); run the "
                    "tests as root, as CI does")


needs_root = pytest.mark.usefixtures("as_root")


def _snapshot(p: Path) -> tuple[bytes, int, int, int]:
    st = os.stat(p, follow_symlinks=False)
    return p.read_bytes(), stat.S_IMODE(st.st_mode), st.st_uid, st.st_nlink


@pytest.fixture
def locks(tmp_path: Path) -> Path:
    d = tmp_path / "locks"
    d.mkdir(mode=0o755)
    return d


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A file the lock must never touch: content, mode, owner and links are compared after."""
    v = tmp_path / "victim.conf"
    v.write_bytes(b"precious: do not truncate\n")
    os.chmod(v, 0o600)
    return v


def _refused(locks: Path, *words: str) -> str:
    with pytest.raises(ConfigError) as e:
        StandLock(KEY, locks).acquire({"command": "test"})
    msg = str(e.value)
    assert msg.startswith(str(lock_file(locks, KEY))) or msg.startswith(str(locks)), msg
    for w in words:
        assert w in msg, msg
    return msg


# -- what is at the lock file's path ----------------------------------------------------------


def test_a_symlink_to_a_file_of_ours_is_refused_and_the_file_left_alone(
    locks: Path, victim: Path
) -> None:
    before = _snapshot(victim)
    link = lock_file(locks, KEY)
    link.symlink_to(victim)
    _refused(locks, "a symbolic link", str(victim))
    assert _snapshot(victim) == before  # not truncated, not written, not chmod'ed
    assert link.is_symlink()  # not removed: whoever made it can be found


@needs_root
def test_a_symlink_to_another_users_file_is_refused_and_the_file_left_alone(
    locks: Path, victim: Path
) -> None:
    os.chown(victim, NOBODY, NOBODY)
    before = _snapshot(victim)
    lock_file(locks, KEY).symlink_to(victim)
    _refused(locks, "a symbolic link")
    assert _snapshot(victim) == before
    assert before[2] == NOBODY


def test_a_dangling_symlink_is_refused_and_nothing_created(locks: Path, tmp_path: Path) -> None:
    target = tmp_path / "would-be-created"
    lock_file(locks, KEY).symlink_to(target)
    _refused(locks, "a symbolic link")
    assert not target.exists()


def test_a_hard_link_is_refused_and_the_file_left_alone(locks: Path, victim: Path) -> None:
    os.link(victim, lock_file(locks, KEY))
    before = _snapshot(victim)
    _refused(locks, "2 links", "hard link")
    assert _snapshot(victim) == before
    assert lock_file(locks, KEY).exists()


@pytest.mark.timeout(60, method="thread")  # a FIFO opened for writing would block
def test_a_fifo_is_refused_at_once(locks: Path) -> None:
    os.mkfifo(lock_file(locks, KEY))
    t0 = time.monotonic()
    _refused(locks, "a FIFO")
    assert time.monotonic() - t0 < 20.0


def test_the_reader_of_the_holder_never_follows_a_symlink(locks: Path, victim: Path) -> None:
    victim.write_text(json.dumps({"pid": os.getpid(), "serial": "FAKE"}))
    lock_file(locks, KEY).symlink_to(victim)
    assert StandLock(KEY, locks).holder() is None


# -- the lock files benchctl makes ------------------------------------------------------------


def test_lock_files_are_created_never_writable_by_others_whatever_the_umask(locks: Path) -> None:
    old = os.umask(0)
    try:
        lock = StandLock(KEY, locks)
        lock.acquire({"command": "test", "serial": "S1"})
        try:
            st = os.stat(lock.path)
            assert stat.S_IMODE(st.st_mode) == LOCK_FILE_MODE == 0o644  # was chmod'ed 0666
            assert st.st_uid == os.geteuid() and st.st_nlink == 1
            assert json.loads(lock.path.read_text())["serial"] == "S1"
        finally:
            lock.release()
    finally:
        os.umask(old)
    assert not lock.path.exists()


def test_a_killed_runs_file_of_ours_is_taken_over(locks: Path) -> None:
    stale = lock_file(locks, KEY)
    stale.write_text(json.dumps({"pid": 2**22 + 12345, "serial": "DEAD"}))  # no such pid
    os.chmod(stale, 0o600)
    lock = StandLock(KEY, locks)
    lock.acquire({"command": "test", "serial": "NEW"})
    try:
        assert json.loads(stale.read_text())["serial"] == "NEW"
        assert stat.S_IMODE(os.stat(stale).st_mode) == 0o600  # never chmod'ed
    finally:
        lock.release()


# -- the lock folder --------------------------------------------------------------------------


@needs_root
def test_a_folder_made_by_another_user_is_refused(locks: Path) -> None:
    os.chown(locks, NOBODY, NOBODY)
    msg = _refused(locks, "owned by", f"uid {NOBODY}", "not by you", "run.lock_dir")
    assert msg.startswith(f"{locks}: ")
    assert list(locks.iterdir()) == []  # nothing created in it


@needs_root
def test_a_folder_symlink_made_by_another_user_is_refused(tmp_path: Path, locks: Path) -> None:
    link = tmp_path / "locks-link"
    link.symlink_to(locks)
    os.lchown(link, NOBODY, NOBODY)
    _refused(link, "a symlink owned by", f"uid {NOBODY}")


@pytest.mark.parametrize(("mode", "who"), [(0o777, "others"), (0o775, "its group")])
def test_a_folder_writable_by_others_without_the_sticky_bit_is_refused(
    locks: Path, mode: int, who: str
) -> None:
    os.chmod(locks, mode)
    _refused(locks, f"writable by {who} without the sticky bit", f"mode {mode:04o}", "1777")
    assert list(locks.iterdir()) == []


def test_a_sticky_shared_folder_like_tmp_is_accepted(locks: Path) -> None:
    os.chmod(locks, 0o1777)
    with StandLock(KEY, locks) as lock:
        lock.acquire({"command": "test"})
        assert lock.held
    assert not lock_file(locks, KEY).exists()


def test_the_default_folder_is_one_another_user_cannot_create_first() -> None:
    default = lockmod.DEFAULT_LOCK_DIR
    assert not str(default).startswith(tempfile.gettempdir())
    parent = os.stat(default.parent)
    assert parent.st_uid == 0 and not parent.st_mode & 0o022  # /run: root's alone


def test_the_default_folder_is_made_shared_and_sticky_by_its_first_user(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    default = tmp_path / "run-benchctl-locks"
    monkeypatch.setattr(lockmod, "DEFAULT_LOCK_DIR", default)
    os.close(open_lock_dir(default))
    st = os.stat(default)
    assert stat.S_IMODE(st.st_mode) == 0o1777 and st.st_uid == os.geteuid()


# -- another user's lock file -----------------------------------------------------------------


@pytest.fixture
def shared(tmp_path: Path) -> Iterator[Path]:
    """A root-owned sticky folder like /tmp that another user can reach."""
    d = Path(tempfile.mkdtemp(prefix="benchctl-locktest-"))
    os.chmod(d, 0o1777)
    try:
        yield d
    finally:
        for p in d.iterdir():
            p.unlink()
        d.rmdir()


def _other_user_holds(path: Path) -> tuple[int, int]:
    """A child process of user nobody that creates ``path`` (0644), writes its details, locks
    it and waits until the returned pipe end is closed; (pid, write end)."""
    ready_r, ready_w = os.pipe()
    hold_r, hold_w = os.pipe()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # fork with threads: os calls only
        pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        try:
            import fcntl

            os.close(hold_w)
            os.close(ready_r)
            os.setgid(NOBODY)
            os.setuid(NOBODY)
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
            os.write(fd, json.dumps({"pid": os.getpid(), "serial": "OTHER",
                                     "user": "nobody"}).encode())
            fcntl.flock(fd, fcntl.LOCK_EX)
            os.write(ready_w, b"1")
            os.read(hold_r, 1)
        finally:
            os._exit(0)
    os.close(ready_w)
    os.close(hold_r)
    assert os.read(ready_r, 1) == b"1"
    os.close(ready_r)
    return pid, hold_w


@needs_root
def test_another_users_lock_serialises_and_its_stale_file_is_never_written(shared: Path) -> None:
    path = lock_file(shared, KEY)
    pid, hold = _other_user_holds(path)
    try:
        with pytest.raises(StandInUse, match="serial OTHER"):
            StandLock(KEY, shared).acquire({"command": "test"})
    finally:
        os.close(hold)
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
    assert os.stat(path).st_uid == NOBODY  # left by a killed run of another user
    keep = os.open(path, os.O_RDONLY)  # the old file, to look at after
    before = os.pread(keep, 4096, 0)
    try:
        lock = StandLock(KEY, shared)
        lock.acquire({"command": "test", "serial": "ROOT"})
        try:  # root removed it under the lock and made its own; the old one never written
            assert os.pread(keep, 4096, 0) == before and os.fstat(keep).st_nlink == 0
            assert os.stat(path).st_uid == os.geteuid()
            assert json.loads(path.read_text())["serial"] == "ROOT"
        finally:
            lock.release()
    finally:
        os.close(keep)


@settings(max_examples=150, deadline=None)
@given(mode=st.integers(min_value=0, max_value=0o7777),
       other_owner=st.booleans() if os.geteuid() == 0 else st.just(False))
def test_the_folder_check_accepts_exactly_safe_folders(
    tmp_path_factory: pytest.TempPathFactory, mode: int, other_owner: bool
) -> None:
    d = tmp_path_factory.mktemp("lockdir")
    os.chmod(d, mode | 0o700)  # we can always look in it
    if other_owner:
        os.chown(d, NOBODY, NOBODY)
    st_ = os.stat(d)
    safe = st_.st_uid in (os.geteuid(), 0) and (
        not st_.st_mode & 0o022 or bool(st_.st_mode & stat.S_ISVTX))
    try:
        os.close(open_lock_dir(d))
        accepted = True
    except ConfigError as e:
        accepted = False
        assert str(e).startswith(f"{d}: the stand lock folder "), e
    assert accepted == safe, (oct(st_.st_mode), st_.st_uid)


@needs_root
def test_a_user_takes_roots_stale_file_without_writing_into_it(shared: Path) -> None:
    """The other way round: a run of user nobody finds a lock file root's killed run left in
    the shared folder. It cannot remove it (sticky folder) and must not write into it: it
    locks it as it is, and keeps a second run out all the same."""
    path = lock_file(shared, KEY)
    details = json.dumps({"pid": 2**22 + 54321, "serial": "ROOT-DEAD"}).encode()
    path.write_bytes(details)
    os.chmod(path, 0o644)
    ready_r, ready_w = os.pipe()
    hold_r, hold_w = os.pipe()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # fork with threads: no locks used
        pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 1
        try:
            os.close(hold_w)  # the parent's end: its close is the signal to let go
            os.close(ready_r)
            os.setgid(NOBODY)
            os.setuid(NOBODY)
            lock = StandLock(KEY, shared)
            lock.acquire({"command": "test", "serial": "NOBODY"})
            os.write(ready_w, b"1" if lock.held else b"0")
            os.read(hold_r, 1)
            lock.release()
            code = 0
        except BaseException as e:
            os.write(ready_w, repr(e).encode()[:200])
        finally:
            os._exit(code)
    os.close(ready_w)
    os.close(hold_r)
    try:
        said = os.read(ready_r, 200)
        assert said == b"1", said
        with pytest.raises(StandInUse, match="could not write its details"):
            StandLock(KEY, shared).acquire({"command": "test"})
    finally:
        os.close(hold_w)
        os.close(ready_r)
        _, status = os.waitpid(pid, 0)
    assert os.waitstatus_to_exitcode(status) == 0
    assert path.read_bytes() == details and os.stat(path).st_uid == 0  # untouched, still there


def test_an_in_process_link_is_locked_as_this_process_own_endpoint() -> None:
    """A simulated stand on an in-process link (``simchan://NAME``) exists only in the process
    that made it, and every process numbers its links from the same name: two test processes
    (pytest-xdist) each running a simulated-time run must not lock one another out."""
    from types import SimpleNamespace

    from benchctl.run.lock import endpoint_key

    tcp = SimpleNamespace(driver="modbus-tcp", host="simchan://sim-stand", port=502)
    rtu = SimpleNamespace(driver="modbus-rtu", serial_port="simchan://sim-stand")
    me = f"pid {os.getpid()}"
    assert endpoint_key(tcp) == f"tcp simchan://sim-stand:502 {me}"  # type: ignore[arg-type]
    assert endpoint_key(rtu) == f"rtu simchan://sim-stand {me}"  # type: ignore[arg-type]
    real = SimpleNamespace(driver="modbus-tcp", host="127.0.0.1", port=5020)
    assert endpoint_key(real) == "tcp localhost:5020"  # type: ignore[arg-type]
