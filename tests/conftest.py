"""Shared fixtures. Every test is checked for leaked threads and child processes."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import psutil
import pytest

ROOT = Path(__file__).resolve().parent.parent


def _threads() -> set[threading.Thread]:
    return {t for t in threading.enumerate() if t.is_alive()}


@pytest.fixture(autouse=True)
def no_leaks() -> Iterator[None]:
    """Fail a test that leaves a thread or a child process behind (after a generous grace)."""
    before = _threads()
    me = psutil.Process()
    children_before = {p.pid for p in me.children(recursive=True)}
    yield
    deadline = time.monotonic() + 5.0
    while True:
        leaked = [t for t in _threads() - before if not t.name.startswith(("pydevd", "asyncio_"))]
        kids = [
            p
            for p in me.children(recursive=True)
            if p.pid not in children_before
            and p.is_running()
            and p.status() != psutil.STATUS_ZOMBIE
        ]
        if not leaked and not kids:
            return
        if time.monotonic() > deadline:
            break
        time.sleep(0.05)
    for p in kids:
        p.kill()
    pytest.fail(
        f"test leaked threads {[t.name for t in leaked]} / child processes {[p.pid for p in kids]}"
    )


@pytest.fixture
def root() -> Path:
    return ROOT
