"""The pieces of the disk-full abort, without a run (tests/e2e/test_disk_full.py runs them whole on
a tmpfs): a disk-full OSError from any thread is the documented reason, not an unexpected error;
a whole-file write that fails leaves no ``.tmp``; an index line is appended whole or not at
all; the run's log file closes quietly on a full disk."""

from __future__ import annotations

import errno
import logging
import os
from pathlib import Path
from typing import Any

import pytest

from benchctl import exits, fileout
from benchctl.archive.service import enqueue
from benchctl.errors import RecordingError
from benchctl.results.record import abort_kind
from benchctl.run.report import append_line
from benchctl.run.supervisor import Supervisor


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EFBIG])
def test_a_disk_full_oserror_from_a_thread_is_the_documented_reason(code: int) -> None:
    sup = Supervisor()
    t = sup.thread("can logger", lambda: (_ for _ in ()).throw(
        OSError(code, os.strerror(code), "/runs/rec/can.blf")))
    t.start()
    t.join(10)
    assert sup.first is not None
    assert isinstance(sup.first.error, RecordingError)
    reason = sup.first.reason
    assert reason.startswith("can logger: ") and "cannot write /runs/rec/can.blf" in reason
    assert "unexpected" not in reason and f"errno {code}" in reason
    assert abort_kind(sup.first.error, sup.first.source) == "equipment"


def test_another_oserror_stays_unexpected() -> None:
    sup = Supervisor()
    sup.fault(OSError(errno.EIO, "I/O error"), "x")
    assert sup.first is not None and "unexpected OSError" in sup.first.reason


def _fill_on_write(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every whole-file write of benchctl.fileout writes 10 bytes, then finds the disk full."""
    real_open = open

    class Full:
        def __init__(self, f: Any) -> None:
            self.f = f

        def write(self, data: bytes) -> int:
            self.f.write(data[:10])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __getattr__(self, name: str) -> Any:
            return getattr(self.f, name)

        def __enter__(self) -> Full:
            return self

        def __exit__(self, *a: Any) -> None:
            self.f.close()

    monkeypatch.setattr(fileout, "open", lambda *a, **k: Full(real_open(*a, **k)),
                        raising=False)


def test_a_failed_whole_file_write_leaves_no_tmp(tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    dest = tmp_path / "record.json"
    dest.write_text("old")
    _fill_on_write(monkeypatch)
    with pytest.raises(OSError) as e:
        fileout.atomic_write_text(dest, "new content, long enough to be cut")
    assert e.value.errno == errno.ENOSPC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["record.json"]
    assert dest.read_text() == "old"  # the old one stays whole


def test_a_queued_record_that_cannot_be_written_leaves_no_tmp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    queue = tmp_path / "archive-queue"
    _fill_on_write(monkeypatch)
    with pytest.raises(OSError) as e:
        enqueue(queue, {"record": {"run_id": "r1"}})
    assert e.value.errno == errno.ENOSPC
    assert list(queue.iterdir()) == []  # no hidden 0-byte or partial .tmp left in the queue


def test_an_index_line_is_appended_whole_or_not_at_all(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    index = tmp_path / "index.jsonl"
    append_line(index, '{"run": 1}')
    real_write = os.write

    def half(fd: int, data: Any) -> int:
        n = real_write(fd, bytes(data[: len(data) // 2]))
        if n:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return n

    monkeypatch.setattr(os, "write", half)
    with pytest.raises(RecordingError, match=r"disk full: cannot write .*index\.jsonl"):
        append_line(index, '{"run": 2, "long": "' + "x" * 100 + '"}')
    monkeypatch.setattr(os, "write", real_write)
    assert index.read_text() == '{"run": 1}\n'


def test_the_run_log_closes_quietly_on_a_full_disk(tmp_path: Path) -> None:
    with exits.run_log(tmp_path) as path:
        assert path is not None
        handler = next(h for h in logging.getLogger().handlers
                       if isinstance(h, logging.FileHandler) and h.baseFilename == str(path))

        class FullStream:
            def write(self, text: str) -> int:
                return len(text)

            def flush(self) -> None:
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

            def close(self) -> None:
                self.flush()

        handler.stream.close()
        handler.stream = FullStream()  # type: ignore[assignment]
        logging.getLogger("benchctl.test").warning("a line the disk has no room for")
    # leaving the block closed the handler without raising


def test_a_junit_file_that_cannot_be_written_leaves_no_tmp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from benchctl.plan.junit import write_junit
    from benchctl.plan.runner import PlanResult

    dest = tmp_path / "junit.xml"
    _fill_on_write(monkeypatch)
    with pytest.raises(OSError) as e:
        write_junit(PlanResult(name="p", source=None, serial="S", operator="o", config=None), dest)
    assert e.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == []  # no junit.xml.tmp left behind
