"""The real stand driver and the simulated stand back to back (the tests of the driver, the
simulator and late replies share them): the simulator on an in-process link (simulated time),
a socket or a pty (real time), and the driver connected to it."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from repo_paths import ROOT

from benchctl.channels import free_name, register, unregister
from benchctl.clock import Clock
from benchctl.config import SimStandConfig, StandConfig, StandLimits
from benchctl.devices.modbus import ModbusStand, open_stand
from benchctl.sim.stand import SimStand

MAP = ROOT / "drivers" / "stand_generic.yaml"
LIMITS = StandLimits(angle_deg=20.0, rate_deg_s=30.0, accel_deg_s2=200.0)
# a slow servo, so its dynamics are plainly visible at 1 Hz: |H| ≈ 0.97, arg H ≈ −43°
# a 1.5 s watchdog: a test's own polling loop (heartbeat every 100 ms) can stall for half a
# second beside two CPU-bound processes (seen: fault 2 mid-stream with a 0.5 s watchdog)
SLOW = SimStandConfig(bandwidth_hz=2.0, damping=0.7, watchdog_s=1.5)
# generous: replies on a loaded 2-core machine can take a few hundred ms (real time)
TIMEOUT_S = 1.0


def wait_for(cond: Callable[[], bool], timeout_s: float, what: str, clock: Clock) -> None:
    deadline = clock.monotonic() + timeout_s
    while not cond():
        if clock.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        clock.sleep(0.01)


def connect(sim: SimStand, url: str | None = None) -> ModbusStand:
    """The driver connected to ``sim``, on its clock: over its in-process link registered as
    ``url`` (simulated time, the simulator's framing), its socket or its pty."""
    common = {
        "limits": LIMITS,
        "register_map": MAP,
        "timeout_s": TIMEOUT_S,
        "retries": 0,
        "setpoint_rate_hz": 50.0,
    }
    if sim.transport == "channel":
        assert url is not None
        where = {"serial_port": url} if sim.framing == "rtu" else {"host": url}
        cfg = StandConfig.model_validate({"driver": f"modbus-{sim.framing}", **where, **common})
    elif sim.transport == "tcp":
        cfg = StandConfig.model_validate({"driver": "modbus-tcp", "port": sim.port, **common})
    else:
        cfg = StandConfig.model_validate(
            {"driver": "modbus-rtu", "serial_port": sim.serial_port, **common}
        )
    stand = open_stand(cfg, clock=sim.clock)
    stand.connect()
    return stand


@contextmanager
def sim_stand(cfg: SimStandConfig, framing: Any, clock: Clock) -> Iterator[tuple[SimStand, str]]:
    """The simulated stand, and where the driver finds it: on a virtual ``clock`` an
    in-process link carrying ``framing`` frames (its ``simchan://`` URL), on the real one a
    socket or a pty."""
    transport: Any = "channel" if clock.virtual else framing
    with SimStand(cfg, limits=LIMITS, register_map=MAP, transport=transport, framing=framing,
                  clock=clock) as sim:
        if sim.client_endpoint is None:
            yield sim, ""
            return
        url = register(free_name("sim-stand"), sim.client_endpoint)
        try:
            yield sim, url
        finally:
            unregister(url)


@contextmanager
def simulated(cfg: SimStandConfig, framing: Any, clock: Clock,
              ) -> Iterator[tuple[SimStand, ModbusStand]]:
    """The simulated stand (``sim_stand``) and the driver connected to it."""
    with sim_stand(cfg, framing, clock) as (sim, url):
        stand = connect(sim, url)
        try:
            yield sim, stand
        finally:
            stand.close()
