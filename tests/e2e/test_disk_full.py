"""A full disk at every phase of a real run is the documented abort.

Each test runs ``benchctl run`` (in-process, through ``benchctl.cli.main``) against the real
simulators on simulated time (the ``vclock`` fixture: the run, its drivers and the simulators
over in-process links; the disk is real) with its output on a small tmpfs of its own, and fills
that tmpfs to the last byte at one moment of the run: on entering prechecks, running
(mid-motion), analysing, and just before the report, the record and the archive index are
written. Every time: exit 2, the stand at rest at zero and disabled (read from the simulated
stand), ``end.json`` written (in the room the recording kept for it) with the disk-full reason,
no ``.tmp`` file left, ``ABORTED`` and every cleanup step printed — and once the analysis had
measured, its verdict printed and kept.

The tests mount a tmpfs: they need root (CI runs as root) and FAIL, not skip, without it.
"""

from __future__ import annotations

import errno
import json
import os
import subprocess
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest
from live_bench import ROLL, LiveBench, live_bench

import benchctl.run
from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.recording import load_recording
from benchctl.run import session as session_mod
from benchctl.run.state import RunState, StateMachine

# a real tmpfs of a few MB mounted per test; the run and its simulators on simulated time
pytestmark = pytest.mark.slow
DISK_SIZE = "4m"  # the whole recording of the 20 s profile (~0.6 MB) and its reserve fit


def _need_root() -> None:
    if os.geteuid() != 0:
        pytest.fail("this test mounts a tmpfs (a small disk to fill) and must run as root, as "
                    "CI does; run it as root")


@pytest.fixture
def disk(tmp_path: Path) -> Iterator[Path]:
    """A small tmpfs of this test's own, unmounted after."""
    _need_root()
    d = tmp_path / "disk"
    d.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={DISK_SIZE}", "tmpfs", str(d)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.fail(f"cannot mount a tmpfs of {DISK_SIZE} at {d} (needed to fill a disk): "
                    f"{r.stderr.strip() or r.returncode}")
    try:
        yield d
    finally:
        for _ in range(50):
            r = subprocess.run(["umount", str(d)], capture_output=True)
            if r.returncode == 0:
                break
            time.sleep(0.1)
        else:
            subprocess.run(["umount", "-l", str(d)], capture_output=True)


def fill(disk: Path) -> None:
    """Fill ``disk`` to the last byte (a filler file grown until ENOSPC)."""
    fd = os.open(disk / "filler", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        chunk = 1 << 20
        while chunk >= 1:
            try:
                if os.write(fd, b"\0" * chunk) < chunk:
                    chunk //= 2
            except OSError as e:
                if e.errno != errno.ENOSPC:
                    raise
                chunk //= 2
    finally:
        os.close(fd)
    assert os.statvfs(disk).f_bavail == 0


def _fill_on_state(monkeypatch: pytest.MonkeyPatch, disk: Path, state: RunState) -> None:
    """The run's state machine fills the disk as the run enters ``state`` (before the run's
    own listener writes the state change)."""

    class Filling(StateMachine):
        def __init__(self, *a: Any, **k: Any) -> None:
            super().__init__(*a, **k)

            def on(old: RunState, new: RunState, t: float, reason: str) -> None:
                if new is state:
                    fill(disk)

            self.subscribe(on)

    monkeypatch.setattr(session_mod, "StateMachine", Filling)


def _fill_before(monkeypatch: pytest.MonkeyPatch, disk: Path, name: str,
                 where: Any = session_mod) -> None:
    """The disk fills just before the session's first call of ``name`` (write_report,
    write_record, archive; the precheck ``check_stand_ready``, once the devices answered)."""
    real: Callable[..., Any] = getattr(where, name)
    done = {"filled": False}

    def wrapped(*a: Any, **k: Any) -> Any:
        if not done["filled"]:
            done["filled"] = True
            fill(disk)
        return real(*a, **k)

    monkeypatch.setattr(where, name, wrapped)


def _run(bench: LiveBench, tmp_path: Path, out: Path, monkeypatch: pytest.MonkeyPatch) -> int:
    """``benchctl run`` through the CLI, its run on the simulators' (virtual) clock."""
    profile = tmp_path / "roll.yaml"
    profile.write_text(ROLL)
    monkeypatch.setattr(benchctl.run, "run_test",
                        partial(benchctl.run.run_test, clock=bench.stand.clock))
    return main(["run", "--config", str(bench.config_path), "--profile", str(profile),
                 "--out", str(out), "--serial", "DF-1", "--operator", "ci", "--quiet"])


def _bench(tmp_path: Path, clock: VirtualClock) -> Any:
    return live_bench(tmp_path, instrument="nmea0183", stand={"mode": "buffered"},
                      run={"lock_dir": str(tmp_path / "locks"), "min_free_disk_mb": 0.01},
                      clock=clock)


DATA = ("stand.csv", "instrument.csv", "setpoints.csv", "events.jsonl")  # whichever first


def _check_abort(code: int, out: str, err: str, bench: LiveBench, disk: Path,
                 files: tuple[str, ...], moved: bool) -> dict[str, Any]:
    """What every phase must show (the reason names one of ``files``); returns end.json."""
    assert code == 2, (out, err[-3000:])
    assert "Traceback" not in err and "unexpected" not in out + err, (out, err[-3000:])
    assert f"ABORTED: recording: disk full: cannot write {disk}" in out, out
    first = out.splitlines()[0]
    assert any(f"/{f} (ENOSPC" in first for f in files), out
    assert "  cleanup:" in out and "    disable: ok" in out, out  # (after the verdict: at the
    # motion's end, the stand already brought to rest then)
    assert "    close recording: ok" in out and "(closed, marked aborted)" in out, out
    if moved:
        assert "    ramp to zero: ok" in out, out
    # the stand: disabled, at rest at zero
    assert not bench.stand._enabled
    clock = bench.stand.clock
    a = bench.stand.true_angles(clock.monotonic())
    clock.sleep(0.2)
    b = bench.stand.true_angles(clock.monotonic())
    assert all(abs(v) <= 0.05 for v in b.values()), b
    assert all(abs(b[k] - a[k]) < 0.002 for k in a), (a, b)
    # end.json written, valid, with the reason; nothing half-written left behind
    (rec,) = [p.parent for p in disk.glob("*/meta.json")]
    end = json.loads((rec / "end.json").read_text())
    assert end["state"] == "aborted" and end["reason"].startswith("recording: disk full")
    assert end["reason"] in first, end["reason"]
    steps = {s["step"]: s["ok"] for s in [*end.get("motion_end_shutdown", []), *end["shutdown"]]}
    assert steps["disable"] and steps.get("ramp to zero", not moved), end["shutdown"]
    assert all(steps.values()), end["shutdown"]
    assert list(disk.rglob("*.tmp")) == []
    assert not (rec / "end.json.reserve").exists()  # given up for end.json
    r = load_recording(rec)
    assert r.state == "aborted"
    return end


def _check_measured(out: str, end: dict[str, Any], disk: Path) -> None:
    """The verdict the analysis measured is printed and kept, the run still ABORTED."""
    assert "measured before the abort: PASS (roll σ " in out, out
    assert end["measured"]["verdict"] == "PASS"
    assert end["measured"]["axes"]["roll"]["sigma"] < end["measured"]["axes"]["roll"]["limit"]
    (rec,) = [p.parent for p in disk.glob("*/meta.json")]
    record = json.loads((rec / "record.json").read_text())
    assert record["outcome"] == "ABORTED" and record["abort"]["measured_verdict"] == "PASS"
    # where the stand is: as the motion's end left it (its devices closed since), at rest at
    # zero, so no command to bring it there
    where = record["abort"]["stand"]
    assert where["known"] and where["at_zero"] and where["commands"] == [], where
    assert "to bring it to rest at zero" not in out, out
    assert f"stand: {where['text']}" in out, out


def test_disk_full_in_the_prechecks(
    tmp_path: Path, disk: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], vclock: VirtualClock,
) -> None:
    """Full once the devices answered, before the stand is enabled (the files' last pages may
    take a few rows more: the abort may come once it is enabled, then it is ramped)."""
    _fill_before(monkeypatch, disk, "check_stand_ready", session_mod.pc)
    with _bench(tmp_path, vclock) as b:
        code = _run(b, tmp_path, disk, monkeypatch)
        out, err = capsys.readouterr()
        end = _check_abort(code, out, err, b, disk, DATA, moved=False)
    assert "measured" not in end and "measured before" not in out


def test_disk_full_mid_motion(
    tmp_path: Path, disk: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], vclock: VirtualClock,
) -> None:
    _fill_on_state(monkeypatch, disk, RunState.RUNNING)
    with _bench(tmp_path, vclock) as b:
        code = _run(b, tmp_path, disk, monkeypatch)
        out, err = capsys.readouterr()
        end = _check_abort(code, out, err, b, disk, DATA, moved=True)
    assert "measured" not in end and "measured before" not in out


def test_disk_full_while_analysing(
    tmp_path: Path, disk: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], vclock: VirtualClock,
) -> None:
    _fill_on_state(monkeypatch, disk, RunState.ANALYSING)
    with _bench(tmp_path, vclock) as b:
        code = _run(b, tmp_path, disk, monkeypatch)
        out, err = capsys.readouterr()
        # the first write to fail: the state change's event, or (the events file's last page had
        # room for it) the report after the analysis
        end = _check_abort(code, out, err, b, disk, ("events.jsonl", "report.json"), moved=False)
    _check_measured(out, end, disk)


@pytest.mark.parametrize(
    ("hook", "file"),
    [("write_report", "report.json"), ("write_record", "record.json"),
     ("archive", "index.jsonl")],
    ids=["report", "record", "archive"],
)
def test_disk_full_after_the_verdict_keeps_it(
    tmp_path: Path, disk: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str], vclock: VirtualClock, hook: str, file: str,
) -> None:
    _fill_before(monkeypatch, disk, hook)
    with _bench(tmp_path, vclock) as b:
        code = _run(b, tmp_path, disk, monkeypatch)
        out, err = capsys.readouterr()
        end = _check_abort(code, out, err, b, disk, (file,), moved=False)
    _check_measured(out, end, disk)
    index = disk / "index.jsonl"  # no torn line: whole lines or none
    assert not index.exists() or index.read_bytes().endswith(b"\n") or index.stat().st_size == 0
