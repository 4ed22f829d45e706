"""Every way out of `benchctl`, the same path, the right exit code, and never a traceback.

- SIGHUP and SIGTERM to a REAL `benchctl run` child mid-profile: exit 2, the recording
  closed ``aborted`` with the reason, the stand ramped to zero and disabled, an archive line;
  each exit signal (SIGQUIT and SIGINT too) the run's own signal fault while it lasts.
- a signal during startup (before the run's own handlers exist): exit 2, one line, no traceback.
- a full disk: an injected ENOSPC (in-process) and a real EFBIG (RLIMIT_FSIZE on a child): the
  run ends ABORTED (exit 2) "recording: …", the stand ramped and disabled, end.json written.
- one run per stand: a second run (and `benchctl sim` on the same endpoint) is refused before it
  connects, naming the holder; a holder killed with -9 leaves the stand free.
- an unexpected exception: exit 2, one line naming the log file, the traceback in that file.
- the simulators' child logs into the recording (sim.log) and is gone after the run.

One file (about 800 lines) on purpose: every way out shares the same child-process harness
(``_child``, ``_finish``, ``_reap``, the bench files) and the same assertions on the cleanup
path, and reading them side by side is how one checks that they are the same path.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import yaml
from live_bench import FOCUSED, ROOT, LiveBench, live_bench, motion_for, recording_in
from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion

import benchctl.run
from benchctl import exits
from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.errors import Interrupted, RecordingError, StandInUse
from benchctl.jsonout import dumps
from benchctl.recording import RecordingWriter, load_recording
from benchctl.run import run_test
from benchctl.run import session as session_mod
from benchctl.run.lock import StandLock, endpoint_key, lock_file
from benchctl.run.prepare import RunOptions
from benchctl.run.session import Session
from benchctl.run.supervisor import Supervisor, shutdown

CI_SHORT = ROOT / "profiles/ci_short.yaml"
# a child inherits an ignored SIGHUP (tests run under nohup), and then rightly keeps ignoring it
NOHUP = pytest.mark.skipif(
    signal.getsignal(signal.SIGHUP) is signal.SIG_IGN, reason="SIGHUP ignored (nohup)"
)
DURATION = "20"  # ci_short shortened: steady part 14 s (its band's low edge fits)


# ------------------------------------------------------------------------------ helpers
def _wait(cond: Callable[[], bool], timeout_s: float, what: str) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out waiting for {what}")


def _child(cfg: Path, out: Path, *extra: str, serial: str = "EXIT-1") -> subprocess.Popen[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = [sys.executable, "-m", "benchctl", "run", "--config", str(cfg)]
    cmd += ["--profile", str(CI_SHORT), "--duration", DURATION, "--out", str(out)]
    cmd += ["--serial", serial, "--operator", "ci", *extra]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _finish(proc: subprocess.Popen[str], timeout_s: float = 90.0) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        raise AssertionError(f"child did not finish: {err[-3000:]}") from None
    return proc.returncode, out, err


def _reap(proc: subprocess.Popen[str]) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate()


def _still(bench: LiveBench) -> bool:
    a = bench.stand.true_angles(time.monotonic())
    time.sleep(0.1)
    b = bench.stand.true_angles(time.monotonic())
    return all(abs(b[k] - a[k]) < 0.002 for k in a)


def _archive(runs: Path) -> list[dict[str, Any]]:
    index = runs / "index.jsonl"
    if not index.is_file():
        return []
    return [json.loads(line) for line in index.read_text().splitlines() if line.strip()]


def _steps(end: dict[str, Any]) -> dict[str, bool]:
    return {s["step"]: s["ok"] for s in end["shutdown"]}


def _cfg_file(tmp_path: Path, **run: Any) -> Path:
    """A hardware-like config whose stand nothing listens on (a run that got as far as
    connecting fails there, not before)."""
    data = {
        "station": "exits",
        "stand": {
            "driver": "modbus-tcp",
            "host": "127.0.0.1",
            "port": 1,
            "register_map": str(ROOT / "drivers/stand_generic.yaml"),
            "limits": {"angle_deg": 25.0, "rate_deg_s": 40.0, "accel_deg_s2": 200.0},
            "timeout_s": 0.2,
            "retries": 0,
        },
        "instrument": {"driver": "nmea0183", "serial_port": "/nonexistent/tty"},
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp_path / "runs"), **run},
    }
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _sim_cfg_file(tmp_path: Path, **run: Any) -> Path:
    """config/sim.yaml (it has a sim: section), its relative paths made absolute."""
    data = yaml.safe_load((ROOT / "config/sim.yaml").read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["instrument"]["channel"] = str(tmp_path / "slcan0")
    # these tests are about signals and exits: the mounting check's 9 s tilt and the host
    # check's 2 s are left out (each has its own tests; the README's command runs both), and
    # the report's figures (1–3 s per axis: drawn by the README's command, as live_bench)
    data["run"].update(mounting_check={"enabled": False}, host_check={"enabled": False},
                       figures=False)
    data["run"].update(output_dir=str(tmp_path / "runs"), **run)
    p = tmp_path / "sim.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _run_main(cfg: Path, *extra: str) -> int:
    return main(
        [
            *("run", "--config", str(cfg), "--profile", str(CI_SHORT), "--duration", DURATION),
            *("--serial", "SECOND-2", "--operator", "late", *extra),
        ]
    )


# ------------------------------------------------------------------------------ signals
# A real signal to this process is handled in its main thread before ``os.kill`` returns to the
# test (the handler runs at the next bytecode): no clock and no other process in it, so the
# tests of the handlers run in the simulated-time tier (as tests/e2e/test_plan_consent.py's
# signals at a prompt do); the real signals to a child run mid-profile stay ``realtime``.
@pytest.mark.parametrize(
    "sig",
    [signal.SIGINT, signal.SIGTERM, pytest.param(signal.SIGHUP, marks=NOHUP), signal.SIGQUIT],
    ids=["SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT"],
)
def test_each_exit_signal_is_the_runs_signal_fault_while_it_lasts(sig: signal.Signals) -> None:
    """While a run lasts (``Supervisor.signals``) each exit signal is the fault "signal:
    interrupted by <name>" — the one path to the cleanup that a real child takes below for
    SIGTERM and SIGHUP (and every way out takes on simulated time, tests/e2e/test_run_e2e.py);
    the handler there before comes back after."""
    assert sig in exits.EXIT_SIGNALS  # (else the signal below would end this process)
    sup = Supervisor()
    before = signal.getsignal(sig)
    with sup.signals():
        assert signal.getsignal(sig) is not before
        os.kill(os.getpid(), sig)
        _wait(lambda: sup.faulted, 10.0, "the handler")  # it runs in the main thread
    assert sup.first is not None and sup.first.reason == f"signal: interrupted by {sig.name}"
    assert sup.stop_event.is_set()
    assert signal.getsignal(sig) is before


@pytest.mark.realtime  # real signals to a real child run
@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM], ids=["SIGTERM"])
def test_signal_mid_profile_takes_the_one_cleanup_path(tmp_path: Path, sig: signal.Signals) -> None:
    """SIGTERM to a run against simulators this test reads (SIGHUP: the next test, with the
    run's own simulators; each exit signal's handler: the test above). About the signal: the
    mounting check's tilt and the host check left out (FOCUSED)."""
    locks = tmp_path / "locks"
    with live_bench(tmp_path, run={"lock_dir": str(locks), **FOCUSED}) as b:
        runs = tmp_path / "runs"
        proc = _child(b.config_path, runs)
        try:
            _wait(motion_for(runs, 1.0), 60.0, "the child's motion")
            proc.send_signal(sig)
            code, out, err = _finish(proc)
        finally:
            _reap(proc)
        assert code == 2, (out, err[-3000:])
        assert f"ABORTED: signal: interrupted by {sig.name}" in out, out
        assert "Traceback" not in err and "Traceback" not in out, err[-3000:]
        _wait(lambda: _still(b), 15.0, "the stand at rest")
        assert all(abs(v) <= 0.05 for v in b.stand.true_angles(time.monotonic()).values())
    rec = recording_in(runs)
    assert rec is not None
    r = load_recording(rec)
    # the driver connected and identified the stand over a real socket, and found it ready
    assert (r.meta["devices"]["stand"]["vendor"], r.meta["devices"]["stand"]["serial"]) == (
        "benchctl", "SIM-0001")
    assert r.meta["devices"]["stand"]["protocol"].startswith("modbus-tcp 127.0.0.1:")
    assert [e["ok"] for e in r.events
            if e["kind"] == "precheck" and e["name"] == "stand ready and at rest"] == [True]
    assert r.state == "aborted" and r.end is not None
    assert r.end["reason"] == f"signal: interrupted by {sig.name}"
    steps = _steps(r.end)
    for step in ("stop loops", "ramp to zero", "disable", "stop instrument", "record shutdown"):
        assert steps[step], (step, r.end["shutdown"])
    assert [e["to"] for e in r.events if e["kind"] == "state"][-1] == "aborted"
    (line,) = _archive(runs)
    assert line["verdict"] == "ABORTED" and sig.name in line["reason"]
    assert line["recording"] == str(rec)
    log = (rec / "benchctl.log").read_text()
    assert f"interrupted by {sig.name}" in log
    assert f"  log {rec / 'benchctl.log'}" in out
    # the lock went with the run: a new holder gets it at once
    lock = StandLock(endpoint_key(b.cfg.stand), locks)
    lock.acquire({"command": "test"})
    lock.release()


@pytest.mark.realtime  # a real SIGHUP to a child and its simulator child
@pytest.mark.slow
@NOHUP
def test_sighup_with_private_simulators_logs_them_into_the_recording(tmp_path: Path) -> None:
    """SIGHUP mid-profile takes the one cleanup path (as SIGTERM above). config/sim.yaml: the
    run starts its simulators once the recording exists; their output goes to
    <recording>/sim.log (no pipe), and the child is gone when the run is."""
    cfg = _sim_cfg_file(tmp_path)
    runs = tmp_path / "runs"
    proc = _child(cfg, runs)
    try:
        _wait(motion_for(runs, 1.0), 60.0, "the child's motion")
        proc.send_signal(signal.SIGHUP)
        code, out, err = _finish(proc)
    finally:
        _reap(proc)
    assert code == 2 and "interrupted by SIGHUP" in out, (out, err[-3000:])
    assert "ABORTED: signal: interrupted by SIGHUP" in out, out
    assert "Traceback" not in err and "Traceback" not in out, err[-3000:]
    rec = recording_in(runs)
    assert rec is not None
    r = load_recording(rec)
    assert r.state == "aborted" and r.end is not None
    assert r.end["reason"] == "signal: interrupted by SIGHUP"
    steps = _steps(r.end)
    for step in ("stop loops", "ramp to zero", "disable", "stop instrument", "record shutdown"):
        assert steps[step], (step, r.end["shutdown"])
    assert [e["to"] for e in r.events if e["kind"] == "state"][-1] == "aborted"
    assert abs(r.streams["stand"]["roll_deg"][-1]) <= 0.05  # its final state read: at zero
    (line,) = _archive(runs)
    assert line["verdict"] == "ABORTED" and "SIGHUP" in line["reason"]
    assert line["recording"] == str(rec)
    assert "interrupted by SIGHUP" in (rec / "benchctl.log").read_text()
    assert f"  log {rec / 'benchctl.log'}" in out
    # the config recorded is the live one: the simulators' private port
    assert r.meta["config"]["stand"]["port"] != 5020
    sim_log = (rec / "sim.log").read_text()
    m = re.search(r"simulators started, pid (\d+)", sim_log)
    assert m, sim_log
    pid = int(m.group(1))

    def gone() -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return Path(f"/proc/{pid}/stat").read_text().split()[2] == "Z"

    _wait(gone, 20.0, "the simulators' child to exit")


@pytest.mark.parametrize(
    "sig", [signal.SIGTERM, pytest.param(signal.SIGHUP, marks=NOHUP)], ids=["SIGTERM", "SIGHUP"]
)
def test_signal_during_startup_is_a_clean_exit_2(
    tmp_path: Path, sig: signal.Signals, monkeypatch: pytest.MonkeyPatch,
    capfd: pytest.CaptureFixture[str],
) -> None:
    """A signal during the start, before any run exists (today: killed, -15, silent): only
    ``main``'s handlers (benchctl.exits) are there. The real signal is sent to this process
    from inside the start, as ``benchctl run`` reads its config, so it lands there every time
    (a signal to a child just started landed anywhere in its start, or in its run); the
    console checked at the file descriptors (``capfd``): one line, no traceback."""
    import benchctl.config as config_mod

    real_load = config_mod.load_config

    def load_config(path: Any, *a: Any, **k: Any) -> Any:
        os.kill(os.getpid(), sig)  # the handler raises here, in this (the main) thread
        return real_load(path, *a, **k)

    monkeypatch.setattr(config_mod, "load_config", load_config)
    cfg = _sim_cfg_file(tmp_path)
    code = _run_main(cfg)
    out, err = capfd.readouterr()
    assert code == 2, (code, out, err[-3000:])
    assert "Traceback" not in err and "Traceback" not in out, err
    assert err.strip().splitlines()[-1] == f"benchctl run: interrupted by {sig.name}", err
    assert recording_in(tmp_path / "runs") is None  # it never got as far as the run


def test_main_restores_the_signal_handlers_and_respects_ignored_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = {s: signal.getsignal(s) for s in exits.EXIT_SIGNALS}
    old = signal.signal(signal.SIGHUP, signal.SIG_IGN)  # as under nohup
    try:
        with exits.exit_signals():
            assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
            with pytest.raises(Interrupted, match="interrupted by SIGTERM"):
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)  # the handler raises in the main thread at once
            os.kill(os.getpid(), signal.SIGTERM)  # a second one while leaving: ignored
    finally:
        signal.signal(signal.SIGHUP, old)
    assert {s: signal.getsignal(s) for s in exits.EXIT_SIGNALS} == before
    assert main(["run", "--config", str(tmp_path / "missing.yaml"), "--profile", "x"]) == 2
    assert {s: signal.getsignal(s) for s in exits.EXIT_SIGNALS} == before
    assert "cannot read bench config" in capsys.readouterr().err


# ------------------------------------------------------------------------------ disk full
class _FullAfter:
    """A stream file that fails with ENOSPC after ``n`` lines (a disk filling up)."""

    def __init__(self, inner: Any, n: int) -> None:
        self.inner, self.n = inner, n

    def write(self, text: str) -> int:
        if self.n <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.n -= 1
        return int(self.inner.write(text))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def _filling_writer(stream: str, after: int) -> type[RecordingWriter]:
    class Filling(RecordingWriter):
        def __init__(self, *a: Any, **k: Any) -> None:
            super().__init__(*a, **k)
            self._files[stream] = _FullAfter(self._files[stream], after)  # type: ignore[assignment]

    return Filling


def test_disk_full_mid_run_aborts_through_the_cleanup(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, vclock: VirtualClock
) -> None:
    monkeypatch.setattr(session_mod, "RecordingWriter", _filling_writer("stand", 250))
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand)
    cfg = bench_config(tmp_path)
    prep = sine_motion(stand.axes, duration_s=5.0, mode="stream", fade_s=0.5)
    sess = Session(
        cfg, prep, RunOptions("SN-F", "tester"), device_factory=lambda c, p: (stand, sensor),
        clock=vclock,
    )
    res = sess.run()
    assert res.exit_code == 2 and res.state == "aborted"
    assert res.reason.startswith("recording: disk full: cannot write "), res.reason
    assert "stand.csv" in res.reason and "ENOSPC" in res.reason and "errno 28" in res.reason
    steps = {s["step"]: s["ok"] for s in res.shutdown}
    assert steps["stop loops"] and steps["ramp to zero"] and steps["disable"], res.shutdown
    assert steps["close recording"], res.shutdown  # end.json fits (only stand.csv is "full")
    assert stand.ramped and not stand.enabled and stand.closed
    end = json.loads((res.recording / "end.json").read_text())  # type: ignore[operator]
    assert end["state"] == "aborted" and end["reason"] == res.reason
    assert end["dropped_rows"] > 0 and "ENOSPC" in end["recording_error"]
    assert sess.writer is not None and sess.writer.dropped_rows == end["dropped_rows"]
    (line,) = _archive(tmp_path)
    assert line["verdict"] == "ABORTED" and line["reason"] == res.reason


def test_disk_full_everywhere_still_cleans_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, vclock: VirtualClock
) -> None:
    """Nothing can be written any more, end.json included: the stand is still ramped and
    disabled, the failed step is reported, and the run is ABORTED (exit 2) without raising."""
    import benchctl.recording.writer as writer_mod

    real_atomic = writer_mod._atomic_json
    full = {"on": False}

    def atomic(path: Path, obj: Any) -> None:
        if full["on"]:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_atomic(path, obj)

    class Full(RecordingWriter):
        def __init__(self, *a: Any, **k: Any) -> None:
            super().__init__(*a, **k)
            for name in list(self._files):
                self._files[name] = _FullAfter(self._files[name], 100)  # type: ignore[assignment]
            self._events = _FullAfter(self._events, 8)  # type: ignore[assignment]
            full["on"] = True

    monkeypatch.setattr(writer_mod, "_atomic_json", atomic)
    monkeypatch.setattr(session_mod, "RecordingWriter", Full)
    monkeypatch.setattr(
        session_mod, "archive_abort", lambda *a: (_ for _ in ()).throw(OSError(errno.ENOSPC, "x"))
    )
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand)
    prep = sine_motion(stand.axes, duration_s=5.0, mode="stream", fade_s=0.5)
    sess = Session(
        bench_config(tmp_path),
        prep,
        RunOptions("SN-F", "tester"),
        device_factory=lambda c, p: (stand, sensor),
        clock=vclock,
    )
    res = sess.run()
    assert res.exit_code == 2 and res.reason.startswith("recording: disk full"), res.reason
    steps = {s["step"]: s["ok"] for s in res.shutdown}
    assert steps["disable"] and not steps["close recording"], res.shutdown
    assert stand.ramped or "ramp to zero" not in steps
    assert not stand.enabled and stand.closed
    assert not (res.recording / "end.json").exists()  # type: ignore[operator]


def test_recording_writer_raises_once_then_counts(tmp_path: Path) -> None:
    from benchctl.devices.base import InstrumentSample

    seen: list[RecordingError] = []
    w = RecordingWriter(tmp_path / "rec", ("roll",), {"serial": "S"}, on_error=seen.append)
    w._files["instrument"] = _FullAfter(w._files["instrument"], 2)  # type: ignore[assignment]
    for k in range(2):
        w.write_instrument(InstrumentSample(float(k), {"roll": 0.0}, counter=k))
    with pytest.raises(RecordingError) as ei:
        w.write_instrument(InstrumentSample(2.0, {"roll": 0.0}, counter=2))
    e = ei.value
    assert e.errno == errno.ENOSPC and e.path == tmp_path / "rec" / "instrument.csv"
    assert str(e).startswith(f"disk full: cannot write {tmp_path / 'rec' / 'instrument.csv'}")
    assert seen == [e]
    for k in range(5):  # no more raising: dropped and counted
        w.write_instrument(InstrumentSample(3.0 + k, {"roll": 0.0}, counter=3 + k))
    w.event("note", text="dropped too")
    assert w.dropped_rows == 6 and w.dropped_events == 1 and w.counts["instrument"] == 2
    w.close("aborted", "recording: disk full")
    r = load_recording(tmp_path / "rec")
    assert r.state == "aborted" and r.end is not None
    assert r.end["dropped_rows"] == 6 and "ENOSPC" in r.end["recording_error"]
    assert r.streams["instrument"]["t_host"].size == 2


def test_close_raises_when_end_json_cannot_be_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import benchctl.recording.writer as writer_mod

    w = RecordingWriter(tmp_path / "rec", ("roll",), {})

    def full(path: Path, obj: Any) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    real = writer_mod._atomic_json
    monkeypatch.setattr(writer_mod, "_atomic_json", full)
    with pytest.raises(RecordingError, match=r"disk full: cannot write .*end\.json \(ENOSPC"):
        w.close("done", "PASS")
    assert w.closed and all(f.closed for f in w._files.values())
    assert not (tmp_path / "rec" / "end.json").exists()
    with pytest.raises(RecordingError):  # a later close (the abort path's) tries again
        w.close("aborted", "recording: disk full")
    monkeypatch.setattr(writer_mod, "_atomic_json", real)  # space again
    w.close("aborted", "recording: disk full")
    assert load_recording(tmp_path / "rec").state == "aborted"
    w.close("done", "PASS")  # idempotent once end.json is written
    assert load_recording(tmp_path / "rec").state == "aborted"


def test_shutdown_guards_each_step(monkeypatch: pytest.MonkeyPatch) -> None:
    """A writer whose every call fails (and a stand that cannot ramp) does not skip a step."""
    stand = FakeStand()
    stand.enabled = True

    class Broken:
        def event(self, *a: Any, **k: Any) -> None:
            raise RecordingError("disk full: cannot write events.jsonl (ENOSPC, errno 28)")

        def close(self, *a: Any, **k: Any) -> None:
            raise RecordingError("disk full: cannot write end.json (ENOSPC, errno 28)")

    def bad_ramp(timeout_s: float) -> None:
        raise OSError(errno.EIO, "link gone")

    monkeypatch.setattr(stand, "ramp_to_zero", bad_ramp)
    sensor = FakeSensor(stand)
    rep = shutdown(
        stop_loops=lambda: None,
        stand=stand,
        sensor=sensor,
        writer=Broken(),  # type: ignore[arg-type]
        state="aborted",
        reason="x",
    )
    steps = {s["step"]: s["ok"] for s in rep.steps}
    assert steps == {
        "stop loops": True,
        "ramp to zero": False,
        "disable": True,
        "final angle": True,
        "read final state": True,
        "stop instrument": True,
        "record shutdown": False,
        "close recording": False,
        "close stand": True,
        "close instrument": True,
    }
    assert not stand.enabled and stand.closed


@pytest.mark.realtime  # the file-size limit (RLIMIT_FSIZE) of a real child
@pytest.mark.slow
def test_file_too_large_in_a_real_child_run(tmp_path: Path) -> None:
    """A real OS write failure: RLIMIT_FSIZE makes the child's streams fail with EFBIG."""
    resource = pytest.importorskip("resource")
    with live_bench(tmp_path, instrument="nmea0183",
                    run={"lock_dir": str(tmp_path / "l"), **FOCUSED}) as b:
        runs = tmp_path / "runs"
        proc = _child(b.config_path, runs)
        try:
            # bytes: stand.csv reaches it a few seconds into the motion (without the mounting
            # check's tilt, FOCUSED, the prechecks write about 12 kB of it; 6 kB a second then)
            limit = 40_000
            resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (limit, limit))
            code, out, err = _finish(proc)
        finally:
            _reap(proc)
        assert code == 2, (out, err[-3000:])
        assert "ABORTED: recording: write error: cannot write" in out, out
        assert "EFBIG" in out and "Traceback" not in err
        assert "(closed, marked aborted)" in out  # end.json is small: it still fits
        _wait(lambda: _still(b), 15.0, "the stand at rest")
        assert all(abs(v) <= 0.05 for v in b.stand.true_angles(time.monotonic()).values())
    rec = recording_in(runs)
    assert rec is not None
    r = load_recording(rec)
    assert r.state == "aborted" and r.end is not None
    assert r.end["reason"].startswith("recording: write error") and r.end["dropped_rows"] > 0
    steps = _steps(r.end)
    assert steps["ramp to zero"] and steps["disable"] and steps["stop instrument"]
    assert r.end["stats"]["setpoints_sent"] > 50  # it was moving when the file filled up
    (line,) = _archive(runs)
    assert line["verdict"] == "ABORTED" and "EFBIG" in line["reason"]


# ------------------------------------------------------------------------------ the lock
_HOLDER = """
import sys, time
from pathlib import Path
from benchctl.run.lock import StandLock
lock = StandLock(sys.argv[1], Path(sys.argv[2]))
lock.acquire({"command": "benchctl run", "serial": "HOLD-1", "operator": "first",
              "start_utc": "2026-01-02T03:04:05+00:00"})
print("locked", flush=True)
time.sleep(600)
"""


@pytest.mark.realtime  # the stand lock across two processes
def test_a_second_run_is_refused_naming_the_holder_until_it_dies(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    locks = tmp_path / "locks"
    cfg = _cfg_file(tmp_path, lock_dir=str(locks))
    from benchctl.config import load_config

    key = endpoint_key(load_config(cfg).stand)
    assert key == "tcp localhost:1"
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, key, str(locks)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        assert _run_main(cfg) == 2
        err = capsys.readouterr().err
        line = err.strip().splitlines()[-1]
        assert line.startswith("benchctl run: error: stand tcp localhost:1 is in use by "), err
        for part in (
            f"pid {holder.pid}",
            "serial HOLD-1",
            "operator first",
            "since 2026-01-02T03:04:05+00:00",
            str(lock_file(locks, key)),
            "Refused before connecting",
        ):
            assert part in line, (part, line)
        assert not (tmp_path / "runs").exists()  # refused before any recording or connection
        holder.kill()  # kill -9: no cleanup at all; the kernel drops the lock
        holder.wait(timeout=10)
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
        if holder.stdout is not None:
            holder.stdout.close()
    # free again: this run gets past the lock and fails only where it connects (nothing there)
    assert _run_main(cfg) == 2
    err = capsys.readouterr().err
    assert "in use" not in err
    rec = recording_in(tmp_path / "runs")
    assert rec is not None and load_recording(rec).state == "aborted"
    assert not lock_file(locks, key).exists()  # released: removed by its holder


def test_lock_is_per_endpoint_and_reports_in_process_holders(tmp_path: Path) -> None:
    a = StandLock("tcp localhost:5020", tmp_path)
    a.acquire({"command": "benchctl run", "serial": "A"})
    try:
        with pytest.raises(StandInUse) as ei:
            StandLock("tcp localhost:5020", tmp_path).acquire({"serial": "B"})
        assert ei.value.holder["serial"] == "A" and ei.value.holder["pid"] == os.getpid()
        other = StandLock("tcp localhost:5021", tmp_path)  # another stand: free
        other.acquire({"serial": "C"})
        other.release()
    finally:
        a.release()
    assert a.holder() is None and not a.path.exists()  # released: the file removed


def test_benchctl_sim_refuses_an_endpoint_a_run_holds(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    locks = tmp_path / "locks"
    cfg = _sim_cfg_file(tmp_path, lock_dir=str(locks))
    from benchctl.config import load_config

    lock = StandLock(endpoint_key(load_config(cfg).stand), locks)
    lock.acquire({"command": "benchctl run", "serial": "RUN-1", "operator": "busy"})
    try:
        assert main(["sim", "--config", str(cfg)]) == 2
    finally:
        lock.release()
    err = capsys.readouterr().err
    assert "benchctl sim: error: stand tcp localhost:5020 is in use by benchctl run" in err
    assert "serial RUN-1" in err and "operator busy" in err


@pytest.mark.slow
def test_second_run_refused_while_the_first_one_finishes_untouched(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
    vclock: VirtualClock,
) -> None:
    """The issue's case: a second run against a stand in use used to connect, and its cleanup
    disabled the stand under the first run. Now it is refused before connecting. On simulated
    time: the first run in a thread of the clock, the second through the CLI in this thread
    once the first has moved for 1 s (the lock across two processes:
    ``test_a_second_run_is_refused_naming_the_holder_until_it_dies``)."""
    with live_bench(tmp_path, run={"lock_dir": str(tmp_path / "locks")},
                    stand={"mode": "buffered"}, clock=vclock) as b:
        runs = tmp_path / "runs"
        first: dict[str, Any] = {}

        def run_first() -> None:
            first["res"] = run_test(
                b.cfg, CI_SHORT, RunOptions("FIRST-1", "ci", duration_s=float(DURATION)),
                clock=vclock,
            )

        t = vclock.thread(run_first, name="first-run")
        t.start()
        try:
            while not motion_for(runs, 1.0, vclock)():
                assert t.is_alive(), "the first run ended before its motion"
                vclock.sleep(0.05)
            monkeypatch.setattr(benchctl.run, "run_test", partial(run_test, clock=vclock))
            assert _run_main(b.config_path) == 2
            err = capsys.readouterr().err
            assert f"is in use by benchctl run (pid {os.getpid()}" in err, err
            assert "serial FIRST-1" in err and "operator ci" in err
        finally:
            t.join()
        res = first["res"]
        assert res.exit_code == 0, res.reason
        rep = json.loads(dumps(res.to_dict()))
        assert rep["verdict"] == "PASS" and rep["state"] == "done"
    assert len(list(runs.glob("*/meta.json"))) == 1  # the second run made no recording


# ------------------------------------------------------------------------------ exceptions
def test_unexpected_exception_before_the_run_is_one_line_and_a_log(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def boom(*a: Any, **k: Any) -> Any:
        raise RuntimeError("boom in prepare")

    monkeypatch.setattr(session_mod, "prepare_motion", boom)
    cfg = _cfg_file(tmp_path, lock_dir=str(tmp_path / "locks"))
    (tmp_path / "runs").mkdir()
    assert _run_main(cfg) == 2
    err = capsys.readouterr().err
    log = tmp_path / "runs" / "benchctl.log"
    assert err.strip() == (
        f"benchctl run: error: unexpected RuntimeError: boom in prepare (traceback in {log})"
    )
    text = log.read_text()
    assert "Traceback" in text and "boom in prepare" in text and "def boom" not in err


def test_unexpected_exception_without_an_output_folder_logs_to_temp(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)

    def boom(args: Any) -> int:
        raise KeyError("nope")

    import benchctl.cli.run as run_cli

    monkeypatch.setattr(run_cli, "handle", boom)
    assert main(["run", "--config", "x", "--profile", "y"]) == 2
    err = capsys.readouterr().err.strip()
    m = re.fullmatch(r"benchctl run: error: unexpected KeyError: 'nope' \(traceback in (.+)\)", err)
    assert m, err
    log = Path(m.group(1))
    assert log.parent == tmp_path / "tmp" and "Traceback" in log.read_text()


@contextlib.contextmanager
def _fresh_console() -> Iterator[None]:
    """The root logger without this test process's handlers (pytest's log capture) while the
    block lasts, as in a process of its own: ``main`` then adds its console handler, and log
    lines go to stderr as on an operator's console."""
    root = logging.getLogger()
    saved = root.handlers[:]
    root.handlers.clear()
    try:
        yield
    finally:
        root.handlers[:] = saved


# The console of the two tests below is this process's stdout and stderr read at their file
# descriptors (``capfd``), the root logger as in a process of its own (``_fresh_console``):
# what Python itself would print there (a traceback from the interpreter's own hooks) is read
# too, as a child's console was.
def test_unexpected_exception_inside_a_run_no_traceback_on_the_console(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    def boom(self: Session) -> None:
        raise ZeroDivisionError("boom inside the run")

    monkeypatch.setattr(session_mod.Session, "_prechecks", boom)
    cfg = _cfg_file(tmp_path, lock_dir=str(tmp_path / "locks"))
    runs = tmp_path / "runs"
    argv = ["run", "--config", str(cfg), "--profile", str(CI_SHORT), "--duration", DURATION]
    with _fresh_console():
        code = main([*argv, "--serial", "B-1", "--operator", "o"])
    out, err = capfd.readouterr()
    assert code == 2, err
    assert "Traceback" not in err and "Traceback" not in out, err
    rec = recording_in(runs)
    assert rec is not None
    log = rec / "benchctl.log"
    assert "ABORTED: run (exception): unexpected ZeroDivisionError: boom inside the run" in out
    assert f"  log {log}" in out
    assert f"(traceback in {log})" in err  # the console's one line names the file
    text = log.read_text()
    assert "Traceback" in text and "ZeroDivisionError: boom inside the run" in text
    assert load_recording(rec).state == "aborted"


def test_exception_in_a_stray_thread_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capfd: pytest.CaptureFixture[str]
) -> None:
    import tempfile
    import threading

    import benchctl.cli.run as run_cli

    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr(tempfile, "tempdir", None)

    def handle(args: Any) -> int:
        t = threading.Thread(target=lambda: 1 / 0, name="stray")
        t.start()
        t.join()
        return 0

    monkeypatch.setattr(run_cli, "handle", handle)
    with _fresh_console():
        assert main(["run", "--config", "x", "--profile", "y"]) == 0
    _out, err = capfd.readouterr()
    assert "Traceback" not in err, err
    m = re.search(
        r"exception in thread stray: unexpected ZeroDivisionError: .* \(traceback in (\S+)\)",
        err,
    )
    assert m, err
    assert Path(m.group(1)).parent == tmp_path
    assert "Traceback" in Path(m.group(1)).read_text()
