"""``benchctl stand status | reset | home`` against the simulated stand over Modbus TCP.

The scene after a ``kill -9``: the stand was following a command (here at roll 4°) when the
host's heartbeat stopped; its watchdog latched fault 2 and braked it there. ``stand status``
shows that (and the command that clears it), ``stand reset --yes`` clears the fault without
moving anything, ``stand home --yes`` brings it to zero within the configured limits and
switches it off; both are refused while another process holds the stand's lock (naming it) and
without a terminal or ``--yes``, and every action is a line in ``<output_dir>/stand.log``.
Then the same path through ``benchctl sim`` (the simulators standing alone) with a config that
has a ``sim:`` section, and a run's precheck naming the command that clears the fault.
"""

from __future__ import annotations

import io
import json
import os
import select
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from repo_paths import ROOT
from terminal import on_terminal

from benchctl.cli import main
from benchctl.clock import REAL, Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import BenchConfig, SimStandConfig, StandLimits, load_config
from benchctl.devices.modbus.regmap import pdu_address
from benchctl.devices.modbus.stand import open_stand
from benchctl.sim.stand import SimStand

pytestmark = pytest.mark.timeout(600)

LIMITS = {"angle_deg": 30.0, "rate_deg_s": 30.0, "accel_deg_s2": 60.0}
AT_DEG = 4.0


def _wait(cond: Callable[[], bool], seconds: float, what: str, clock: Clock = REAL) -> None:
    deadline = clock.monotonic() + seconds
    while not cond():
        if clock.monotonic() > deadline:
            raise AssertionError(f"not within {seconds} s: {what}")
        clock.sleep(0.05)


def latch_watchdog_at(cfg: BenchConfig, roll_deg: float, clock: Clock = REAL) -> None:
    """Drive the stand to ``roll_deg`` (a raw command: the simulated servo moves within its own
    physics) while heartbeating, then stop heartbeating as a killed host would: the watchdog
    latches its fault and the stand brakes where it is."""
    drv = open_stand(cfg.stand, clock=clock)
    drv.connect()
    try:
        drv.enable()
        f = drv.map.axes["roll"].command
        drv.link.write_registers(pdu_address(f.address), drv.map.encode(f, roll_deg))

        def there() -> bool:
            drv.heartbeat()
            s = drv.read_state()
            return abs(s.angle_deg["roll"] - roll_deg) < 0.01 and not s.status.moving

        _wait(there, 60, f"the stand at roll {roll_deg}°", clock)
        # the heartbeat stops here
        _wait(lambda: drv.read_state().status.fault_code == 2, 60, "the watchdog's fault", clock)
    finally:
        drv.close()


def _config(tmp_path: Path, port: int, sim: bool = False) -> Path:
    data: dict[str, Any] = {
        "station": "stand-cmd",
        "stand": {"driver": "modbus-tcp", "host": "127.0.0.1", "port": port, "timeout_s": 2.0,
                  "register_map": str(ROOT / "drivers/stand_generic.yaml"), "limits": LIMITS},
        "instrument": {"driver": "canopen", "interface": "slcan",
                       "channel": str(tmp_path / "slcan0"),
                       "eds": str(ROOT / "drivers/cia410_inclinometer.eds")},
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp_path / "runs"),
                "lock_dir": str(tmp_path / "locks")},
    }
    if sim:  # the simulated stand's watchdog: one exchange and a heartbeat fit inside it
        data["sim"] = {"stand": {"watchdog_s": 0.5}}
        data["stand"].update(timeout_s=0.2, retries=0)
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture
def bench(tmp_path: Path) -> Iterator[tuple[SimStand, Path]]:
    s = SimStand(SimStandConfig(watchdog_s=0.5), limits=StandLimits(**LIMITS),
                 register_map=ROOT / "drivers/stand_generic.yaml", port=0)
    s.start()
    try:
        yield s, _config(tmp_path, s.port)
    finally:
        s.stop()


def _status(cfg: Path, capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    capsys.readouterr()
    assert main(["stand", "status", "--config", str(cfg), "--json"]) == 0
    out: dict[str, Any] = json.loads(capsys.readouterr().out)
    return out


def _log(cfg: Path) -> list[str]:
    return (load_config(cfg).run.output_dir / "stand.log").read_text().splitlines()


def test_status_reset_home_after_a_latched_watchdog_fault(
    bench: tuple[SimStand, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    sim, cfg_path = bench
    cfg = load_config(cfg_path)
    latch_watchdog_at(cfg, AT_DEG)
    # status: the fault, its text, where the stand is, the lock free; the way out named
    st = _status(cfg_path, capsys)
    assert (st["fault"], st["fault_code"], st["fault_text"]) == (
        True, 2, "heartbeat watchdog expired")
    assert st["enabled"] is False and st["lock"]["held"] is False
    assert abs(st["axes"]["roll"]["angle_deg"] - AT_DEG) < 0.05
    assert main(["stand", "status", "--config", str(cfg_path)]) == 0
    text = capsys.readouterr().out
    assert "FAULT    code 2 (heartbeat watchdog expired)" in text
    assert f"`benchctl stand reset --config {cfg_path}`" in text
    # home refuses a faulted stand and names the reset
    assert main(["stand", "home", "--config", str(cfg_path), "--yes"]) == 2
    err = capsys.readouterr().err
    assert "fault 2 (heartbeat watchdog expired): it cannot move" in err
    assert "benchctl stand reset" in err
    # reset: cleared, nothing moved, the servo still off
    enables = sim.enables
    assert main(["stand", "reset", "--config", str(cfg_path), "--yes",
                 "--operator", "A. Tech"]) == 0
    assert "fault 2 (heartbeat watchdog expired) cleared" in capsys.readouterr().err
    st = _status(cfg_path, capsys)
    assert (st["fault"], st["estop"], st["enabled"], st["ready"]) == (False, False, False, True)
    assert abs(st["axes"]["roll"]["angle_deg"] - AT_DEG) < 0.05 and sim.enables == enables
    # home: to zero within the limits, servo off
    sim.peaks(reset=True)
    assert main(["stand", "home", "--config", str(cfg_path), "--yes"]) == 0
    assert sim.enables == enables + 1
    st = _status(cfg_path, capsys)
    assert st["enabled"] is False and not st["moving"] and not st["fault"]
    assert all(abs(a) <= cfg.stand.zero_tolerance_deg for a in sim.true_angles(
        time.monotonic()).values())
    # the measured rate stayed within the limit (the ramp is planned at 80 % of the rate and
    # acceleration limits, and checked setpoint by setpoint by the driver); a 4° ramp at
    # 48°/s² peaks near √(2·48·2) ≈ 13.9°/s
    peaks = sim.peaks()["roll"]
    assert 5.0 < peaks["rate_deg_s"] <= LIMITS["rate_deg_s"], peaks
    # home again: nothing to do, nothing enabled
    assert main(["stand", "home", "--config", str(cfg_path), "--yes"]) == 0
    assert "already at rest at zero" in capsys.readouterr().err
    assert sim.enables == enables + 1
    # the log: one line per action, who and what
    lines = _log(cfg_path)
    assert len(lines) == 3, lines
    assert " stand home tcp localhost:" in lines[0] and "refused" in lines[0]
    assert " stand reset tcp localhost:" in lines[1] and "operator A. Tech" in lines[1]
    assert "fault 2 (heartbeat watchdog expired) cleared" in lines[1]
    assert " stand home " in lines[2] and "to roll +0.0" in lines[2] and "servo off" in lines[2]


def _hold_lock(cfg: Path) -> subprocess.Popen[str]:
    """Another process holding the stand's lock as a run does."""
    code = (
        "import sys\n"
        "from benchctl.config import load_config\n"
        "from benchctl.run.lock import stand_lock\n"
        f"cfg = load_config({str(cfg)!r})\n"
        "with stand_lock(cfg, {'command': 'benchctl run', 'serial': 'SN-9', "
        "'operator': 'night shift'}):\n"
        "    print('held', flush=True)\n"
        "    sys.stdin.read()\n"
    )
    p = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE,
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout is not None and p.stdout.readline().strip() == "held"
    return p


def test_reset_and_home_are_refused_while_another_process_holds_the_stand(
    bench: tuple[SimStand, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    sim, cfg_path = bench
    latch_watchdog_at(load_config(cfg_path), AT_DEG)
    holder = _hold_lock(cfg_path)
    try:
        enables = sim.enables
        st = _status(cfg_path, capsys)  # status needs no lock: it shows the holder
        assert st["lock"]["held"] is True and st["lock"]["holder"]["pid"] == holder.pid
        assert main(["stand", "status", "--config", str(cfg_path)]) == 0
        assert f"held by benchctl run (pid {holder.pid}" in capsys.readouterr().out
        for action in ("reset", "home"):
            assert main(["stand", action, "--config", str(cfg_path), "--yes"]) == 2
            err = capsys.readouterr().err
            assert f"is in use by benchctl run (pid {holder.pid}" in err
            assert "serial SN-9, operator night shift" in err
        st = _status(cfg_path, capsys)
        assert st["fault_code"] == 2 and sim.enables == enables  # nothing done
        assert abs(sim.true_angles(time.monotonic())["roll"] - AT_DEG) < 0.05
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=30)
    lines = _log(cfg_path)
    assert [("reset" in ln.split()[2], "refused" in ln) for ln in lines] == [
        (True, True), (False, True)]
    # the holder gone: reset goes through
    assert main(["stand", "reset", "--config", str(cfg_path), "--yes"]) == 0


def test_status_leaves_an_rtu_line_a_run_holds_alone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """On Modbus RTU a second master would collide with the run's frames on the serial line:
    status names the holder and never opens the line (here a path that does not exist: an
    attempt to open it would fail with another message)."""
    path = _config(tmp_path, 5020)
    data = yaml.safe_load(path.read_text())
    data["stand"] = {"driver": "modbus-rtu", "serial_port": str(tmp_path / "ttyNONE"),
                     "timeout_s": 0.5, "register_map": data["stand"]["register_map"],
                     "limits": LIMITS}
    path.write_text(yaml.safe_dump(data))
    holder = _hold_lock(path)
    try:
        assert main(["stand", "status", "--config", str(path)]) == 2
        err = capsys.readouterr().err
        assert f"is in use by benchctl run (pid {holder.pid}" in err
        assert "serial line is not opened while a run holds it" in err
    finally:
        assert holder.stdin is not None
        holder.stdin.close()
        holder.wait(timeout=30)
    assert main(["stand", "status", "--config", str(path)]) == 2  # free: it tries the line
    assert "in use" not in capsys.readouterr().err


def test_no_terminal_and_no_yes_is_refused_before_anything(
    bench: tuple[SimStand, Path], capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sim, cfg_path = bench
    latch_watchdog_at(load_config(cfg_path), AT_DEG)
    monkeypatch.setattr("sys.stdin", io.StringIO("y\n"))  # not a terminal: never read
    requests = sim.requests
    for action in ("reset", "home"):
        assert main(["stand", action, "--config", str(cfg_path)]) == 2
        assert "there is none: confirm with --yes" in capsys.readouterr().err
    assert sim.requests == requests  # not even connected
    assert not (load_config(cfg_path).run.output_dir / "stand.log").exists()


def test_home_asks_on_the_terminal_and_a_no_moves_nothing(
    bench: tuple[SimStand, Path], monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    sim, cfg_path = bench
    sim.place({"roll": AT_DEG})
    with on_terminal(monkeypatch) as master:
        os.write(master, b"n\n")
        code = main(["stand", "home", "--config", str(cfg_path)])
        seen = b""
        while select.select([master], [], [], 0.2)[0]:
            seen += os.read(master, 4096)
    assert code == 2
    assert b"Move stand tcp localhost:" in seen and b"clear of people? [y/N]: " in seen
    assert sim.enables == 0
    assert abs(sim.true_angles(time.monotonic())["roll"] - AT_DEG) < 1e-6
    assert "not moved: the operator answered no" in _log(cfg_path)[0]


def test_a_run_refused_by_a_latched_fault_names_the_command_that_clears_it(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """On simulated time (the simulators over in-process links)."""
    from live_bench import live_bench

    from benchctl.run import RunOptions, run_test

    with live_bench(tmp_path, sim_stand={"watchdog_s": 0.5}, clock=vclock) as b:
        latch_watchdog_at(b.cfg, AT_DEG, vclock)
        res = run_test(b.cfg, ROOT / "profiles/ci_short.yaml",
                       RunOptions(serial="SN1", operator="t", out_dir=tmp_path / "runs"),
                       clock=vclock)
        enables = b.stand.enables
    assert res.state == "aborted" and res.exit_code == 2
    assert "precheck 'stand ready and at rest' failed: fault code 2" in res.reason
    assert f"`benchctl stand reset --config {b.config_path}`" in res.reason
    assert enables == 1  # the test's own, before the watchdog: the run enabled nothing


# ------------------------------------------------------------- through `benchctl sim`
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_stand_commands_on_a_simulated_bench_through_benchctl_sim(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg_path = _config(tmp_path, _free_port(), sim=True)
    cfg = load_config(cfg_path)
    # no simulator running: the message says how to start it
    assert main(["stand", "status", "--config", str(cfg_path)]) == 2
    assert f"`benchctl sim --config {cfg_path}`" in capsys.readouterr().err
    log = (tmp_path / "sim.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "benchctl", "sim", "--config", str(cfg_path)],
                            stdout=log, stderr=subprocess.STDOUT)
    try:
        def answers() -> bool:
            assert proc.poll() is None, (tmp_path / "sim.log").read_text()
            try:
                with socket.create_connection(("127.0.0.1", cfg.stand.port), timeout=1):
                    return True
            except OSError:
                return False

        _wait(answers, 60, "benchctl sim listening")
        latch_watchdog_at(cfg, -AT_DEG)
        st = _status(cfg_path, capsys)
        assert (st["fault_code"], st["fault_text"]) == (2, "heartbeat watchdog expired")
        assert main(["stand", "reset", "--config", str(cfg_path), "--yes"]) == 0
        assert main(["stand", "home", "--config", str(cfg_path), "--yes"]) == 0
        st = _status(cfg_path, capsys)
        assert not st["fault"] and not st["enabled"]
        assert all(abs(a["angle_deg"]) <= cfg.stand.zero_tolerance_deg
                   for a in st["axes"].values()), st["axes"]
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        log.close()
    assert proc.returncode == 0
