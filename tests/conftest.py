"""Shared fixtures. Every test is checked for leaked threads, child processes, sockets and ptys."""

# ruff: noqa: E402  (the BLAS setting below must come before anything imports numpy)

from __future__ import annotations

import os

# One BLAS thread per test process, set before numpy is first imported (this file is imported
# before any test module, in each xdist worker, and child processes inherit it). OpenBLAS
# otherwise starts a thread per core that spins after each call: with two workers on a 2-core
# machine they fight over the cores (a least-squares coverage test took 38 s instead of 3 s).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest
from archive_helpers import PgServer
from hypothesis import settings
from owned_trees import OWNED_ROOTS
from repo_paths import ROOT

from benchctl.clock.virtual import VirtualClock

# property tests: a bounded example count where a test states none (each states its own above
# this), and no per-example deadline — it would time the host's load, not the code
settings.register_profile("benchctl", max_examples=100, deadline=None)
settings.load_profile("benchctl")


def _threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.is_alive()}


def _ports_and_ptys(me: psutil.Process) -> set[str]:
    """This process's open inet sockets and pseudo-terminal fds, as readable names."""
    found = {
        f"socket {c.laddr.ip}:{c.laddr.port} {c.status}" for c in me.net_connections(kind="inet")
    }
    fd_dir = Path("/proc/self/fd")
    if fd_dir.is_dir():
        for fd in fd_dir.iterdir():
            try:
                target = str(fd.readlink())
            except OSError:
                continue
            if target.startswith("/dev/pts/") or target == "/dev/ptmx":
                found.add(f"fd {fd.name} -> {target}")
    return found


def _descendants(pid: int) -> set[int]:
    """The process ids of ``pid``'s children, their children and so on: what
    ``psutil.Process(pid).children(recursive=True)`` finds, read from each thread's
    ``/proc/<pid>/task/<tid>/children`` instead of a scan of every process on the machine (that
    scan cost each test ≈ 2 ms of CPU, twice). Where the kernel has no such file, psutil."""
    if not Path(f"/proc/{pid}/task/{pid}/children").exists():
        return {p.pid for p in psutil.Process(pid).children(recursive=True)}
    found: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tids = os.listdir(f"/proc/{p}/task")
        except OSError:  # ended meanwhile
            continue
        for tid in tids:
            try:
                with open(f"/proc/{p}/task/{tid}/children") as f:
                    kids = [int(k) for k in f.read().split()]
            except OSError:
                continue
            for k in kids:
                if k not in found:
                    found.add(k)
                    todo.append(k)
    return found


def _live(pid: int) -> psutil.Process | None:
    """``pid`` as a psutil process, unless it ended or is a zombie."""
    try:
        p = psutil.Process(pid)
        return p if p.is_running() and p.status() != psutil.STATUS_ZOMBIE else None
    except psutil.Error:
        return None


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """Fail a test that leaves a thread, a child process, an open socket or a pty behind
    (after a generous grace). The processes of a tree a fixture owns beyond the test
    (``owned_trees``: a module's Chromium) are that program's own."""
    before = _threads()
    me = psutil.Process()
    io_before = _ports_and_ptys(me)
    children_before = _descendants(me.pid)
    yield
    deadline = time.monotonic() + 5.0
    while True:
        leaked = [t for t in _threads() - before if not t.name.startswith(("pydevd", "asyncio_"))]
        owned = set().union(*(_descendants(r) | {r} for r in OWNED_ROOTS))
        kids = [
            p
            for p in map(_live, sorted(_descendants(me.pid) - children_before - owned))
            if p is not None
        ]
        io_leaked = sorted(_ports_and_ptys(me) - io_before)
        if not leaked and not kids and not io_leaked:
            return
        if time.monotonic() > deadline:
            break
        time.sleep(0.05)
    for p in kids:
        p.kill()
    pytest.fail(
        f"test leaked threads {[t.name for t in leaked]} / child processes {[p.pid for p in kids]}"
        f" / sockets and ptys {io_leaked}"
    )


@pytest.fixture
def root() -> Path:
    return ROOT


@pytest.fixture
def vclock() -> Iterator[VirtualClock]:
    """Simulated time for the test: the test's thread runs on a VirtualClock (threads it starts
    must be the clock's: ``vclock.thread``), and every simulator, driver and run it builds is
    handed ``clock=vclock``. Threads still waiting when the test ends are ended."""
    clock = VirtualClock(hang_s=120.0)
    with clock.running():
        yield clock


# --- the results archive: a PostgreSQL server for the session, an empty archive of each kind ---
@pytest.fixture(scope="session")
def pg() -> Iterator[PgServer]:
    """The distribution's PostgreSQL (initdb, pg_ctl) in a temporary folder, one for each test
    process (each test makes databases of its own on it; a module that changes the server's
    rules, as tests/unit/archive/test_archive_secrets.py does, starts its own)."""
    srv = PgServer.start()
    try:
        yield srv
    finally:
        srv.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def url(request: pytest.FixtureRequest, tmp_path: Path) -> str:
    """An empty archive: a SQLite file, then a new database on the session's PostgreSQL."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'archive.sqlite'}"
    srv: PgServer = request.getfixturevalue("pg")
    return srv.create_database(f"t_{uuid.uuid4().hex[:12]}")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The files holding a test marked ``slow`` first, each whole (its module fixtures set up
    once), the rest after them in their own order: pytest-xdist's workers, each handed a
    share of the collection and stealing from the other's end, then finish together instead
    of one of them waiting out a long test that started last."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow_files)
