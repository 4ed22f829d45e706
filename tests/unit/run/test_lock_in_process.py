"""The stand lock of a simulated stand on an in-process link (simulated time, ``simchan://``).

Such a stand exists only in the process that made it, and every process names its first one
``sim-stand``: the lock must not make two processes' simulated stands one stand (two pytest
workers running simulated benches refused each other: "stand tcp simchan://sim-stand:502 is in
use by benchctl run (pid …)"), while two runs on the one stand of a process still exclude each
other.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchctl.config import StandConfig, StandLimits
from benchctl.errors import StandInUse
from benchctl.run.lock import StandLock, endpoint_key

LIMITS = StandLimits(angle_deg=25.0, rate_deg_s=40.0, accel_deg_s2=200.0)
TCP = StandConfig(driver="modbus-tcp", host="simchan://sim-stand", limits=LIMITS)
RTU = StandConfig(driver="modbus-rtu", serial_port="simchan://sim-stand", limits=LIMITS)

_HOLDER = """
import sys
from pathlib import Path
from benchctl.config import StandConfig, StandLimits
from benchctl.run.lock import StandLock, endpoint_key
limits = StandLimits(angle_deg=25.0, rate_deg_s=40.0, accel_deg_s2=200.0)
stand = StandConfig(driver="modbus-tcp", host="simchan://sim-stand", limits=limits)
lock = StandLock(endpoint_key(stand), Path(sys.argv[1]))
lock.acquire({"command": "benchctl run", "serial": "HOLD-1", "operator": "other process"})
print("locked", flush=True)
sys.stdin.read()
"""


def test_an_in_process_stand_is_keyed_by_its_process() -> None:
    pid = os.getpid()
    assert endpoint_key(TCP) == f"tcp simchan://sim-stand:502 pid {pid}"
    assert endpoint_key(RTU) == f"rtu simchan://sim-stand pid {pid}"
    # a stand on a socket or a serial line is the machine's, whoever runs
    real = StandConfig(driver="modbus-tcp", host="127.0.0.1", port=5020, limits=LIMITS)
    assert endpoint_key(real) == "tcp localhost:5020"


def test_two_processes_simulated_stands_do_not_lock_each_other(tmp_path: Path) -> None:
    locks = tmp_path / "locks"
    locks.mkdir(mode=0o755)
    other = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(locks)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert other.stdout is not None and other.stdout.readline().strip() == "locked"
        mine = StandLock(endpoint_key(TCP), locks)
        mine.acquire({"command": "test"})  # the other process's sim-stand is not this one
        try:
            second = StandLock(endpoint_key(TCP), locks)
            with pytest.raises(StandInUse, match="in use by"):  # but one run per stand here
                second.acquire({"command": "test 2"})
        finally:
            mine.release()
    finally:
        other.communicate("", timeout=30)
