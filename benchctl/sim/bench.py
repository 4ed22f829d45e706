"""The simulated bench: the simulated stand and the instrument on it, as one unit.

``SimBench(cfg)`` builds both simulators from a bench config's ``stand``, ``instrument`` and
``sim`` sections — the instrument measures the stand's true motion — starts them, and runs the
config's fault schedule (``sim.faults``, timed from the moment the stand first moves).

Two ways to place them:

- ``private=False`` (``benchctl sim``): where the config says — the Modbus TCP port in
  ``stand.port``, and stable symlinks to the ptys at ``stand.serial_port`` (RTU),
  ``instrument.channel`` (CAN over slcan) or ``instrument.serial_port`` (NMEA 0183) — so a
  hardware config pointed at them works unchanged;
- ``private=True`` (``benchctl run`` on a config with a ``sim:`` section): a free TCP port and
  private ptys; ``config`` is then the bench config pointed at them.
"""

from __future__ import annotations

import errno
import socket
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from benchctl.channels import free_name, register, unregister
from benchctl.clock import REAL, Clock
from benchctl.config import BenchConfig, SimConfig
from benchctl.errors import ConfigError, DeviceError
from benchctl.sim.instrument import SimInstrument
from benchctl.sim.stand import SimStand

if TYPE_CHECKING:
    from benchctl.sim.disturb import Disturbances


class SimBench:
    """Simulated stand + simulated instrument on it, started and stopped together."""

    def __init__(
        self, cfg: BenchConfig, *, private: bool = False, clock: Clock = REAL
    ) -> None:
        if cfg.sim is None:
            raise ConfigError(
                f"{cfg.source}: field sim: missing; the simulators need a sim: section "
                "(see config/sim.yaml)"
            )
        self.cfg = cfg
        self.sim: SimConfig = cfg.sim
        self.private = private
        self.clock = clock
        #: in-process links on ``clock`` instead of a socket and ptys (always on simulated time)
        self.in_process = clock.virtual
        sc = cfg.stand
        rtu = sc.driver == "modbus-rtu"
        stand_link = None if private or not rtu else _link(sc.serial_port)
        self.stand = SimStand(
            self.sim.stand,
            limits=sc.limits,
            register_map=sc.register_map,
            transport="channel" if self.in_process else ("rtu" if rtu else "tcp"),
            framing="rtu" if rtu else "tcp",
            host=sc.host if not private else "127.0.0.1",
            port=0 if private else sc.port,
            link_path=stand_link,
            device_id=sc.device_id,
            clock=clock,
            channel_latency_s=self.sim.link_latency_s,
        )
        ic = cfg.instrument
        where = ic.serial_port if ic.driver == "nmea0183" else ic.channel
        self.instrument = SimInstrument(
            self.sim.instrument,
            ic,
            self.stand,
            link_path=None if private or self.in_process else _link(where),
            clock=clock,
            channel=free_name("sim-instrument") if self.in_process else None,
        )
        self._stop = clock.event()
        self._scheduler: Any = None
        self._stand_url: str | None = None
        self.motion_started_at: float | None = None
        self.injected: list[tuple[float, str, str]] = []  # (time, target, kind)

    # -- life cycle -------------------------------------------------------------------------
    def start(self) -> SimBench:
        """Start both simulators and the fault schedule. ``ConfigError`` naming ``stand.port``
        (or ``stand.host``) when the stand cannot listen where the config says."""
        self._check_listen()
        try:
            self.stand.start()
            if self.stand.client_endpoint is not None:
                self._stand_url = register(free_name("sim-stand"), self.stand.client_endpoint)
        except (OSError, RuntimeError) as e:  # pymodbus: "Could not start listen" (a race)
            self._check_listen()
            raise DeviceError(f"the simulated stand did not start: {e}") from None
        try:
            self.instrument.start()
        except BaseException:
            self.stand.stop()
            raise
        if self.sim.faults:
            self._scheduler = self.clock.thread(self._run_schedule, name="sim-fault-schedule")
            self._scheduler.start()
        return self

    def _check_listen(self) -> None:
        """Can the stand's TCP server bind ``stand.host:stand.port``? (``ConfigError`` if not.)"""
        if self.stand.transport != "tcp" or self.private or self.cfg.stand.port == 0:
            return
        host, port, src = self.cfg.stand.host, self.cfg.stand.port, self.cfg.source
        try:
            family, kind, proto, _, addr = socket.getaddrinfo(
                host, port, type=socket.SOCK_STREAM
            )[0]
        except (OSError, UnicodeError) as e:
            raise ConfigError(
                f"{src}: field stand.host = {host!r}: cannot listen there ({e}); expected a "
                "local address such as 127.0.0.1"
            ) from None
        with socket.socket(family, kind, proto) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server does
            try:
                s.bind(addr)
            except OSError as e:
                if e.errno == errno.EADDRINUSE:
                    raise ConfigError(
                        f"{src}: field stand.port = {port}: TCP port {port} on {host} is already "
                        "in use (another benchctl sim, or another program); stop it or choose "
                        "a free port in stand.port"
                    ) from None
                raise ConfigError(
                    f"{src}: field stand.port = {port} (stand.host {host!r}): cannot listen "
                    f"there: {e.strerror or e}"
                ) from None

    def stop(self) -> None:
        """Stop both simulators and the fault schedule; idempotent."""
        self._stop.set()
        if self._scheduler is not None:
            self._scheduler.join(timeout=5)
            self._scheduler = None
        self.instrument.stop()
        self.stand.stop()
        if self._stand_url is not None:
            unregister(self._stand_url)
        if self.instrument.channel_name is not None:
            unregister(self.instrument.channel_name)

    def __enter__(self) -> SimBench:
        return self.start()

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    def disturb(self, plan: Disturbances) -> None:
        """Apply seeded disturbances (``benchctl.sim.disturb``) from now: host stalls on the
        clock, jitter on the host's requests, slow or lost replies, lost or garbled instrument
        frames (the faults are already in ``sim.faults``). Simulated time only."""
        if not self.in_process:
            raise ConfigError(f"{self.cfg.source}: field sim.disturb: needs sim.clock: virtual")
        t0 = self.clock.monotonic()
        stall = getattr(self.clock, "stall_host", None)
        if stall is not None:
            for t, d in plan.stalls:
                stall(t0 + t, d)
        start = t0 + plan.spec.from_s
        clock = self.clock

        def after(f: Callable[[bytes], Any], before: Callable[[bytes], Any]
                  ) -> Callable[[bytes], Any]:
            """``f`` from ``start`` on (its draws too), ``before`` until then."""
            if plan.spec.from_s <= 0.0:
                return f
            return lambda data: f(data) if clock.monotonic() >= start else before(data)

        host = self.stand.client_endpoint
        device = self.stand.device_endpoint
        if host is not None and device is not None:
            host.delay = after(plan.send_delay(), lambda _d: 0.0)
            device.delay = after(plan.reply_delay(), lambda _d: 0.0)
        frames = self.instrument.device_endpoint
        if frames is not None:
            frames.damage = after(plan.frame_damage(), lambda d: d)

    def config(self) -> BenchConfig:
        """The bench config pointed at these simulators (``private``: a run's own)."""
        ep = self.endpoints()
        stand = self.cfg.stand.model_copy(update=ep["stand"])
        instrument = self.cfg.instrument.model_copy(update=ep["instrument"])
        return self.cfg.model_copy(update={"stand": stand, "instrument": instrument})

    # -- where they are -------------------------------------------------------------------
    def endpoints(self) -> dict[str, dict[str, Any]]:
        """Where the drivers should connect: {"stand": {...}, "instrument": {...}}."""
        if self.stand.transport == "channel":
            key = "serial_port" if self.stand.framing == "rtu" else "host"
            stand: dict[str, Any] = {key: self._stand_url}
        elif self.stand.transport == "tcp":
            stand = {"host": self.stand.host, "port": self.stand.port}
        else:
            stand = {"serial_port": self.stand.serial_port}
        if self.instrument.is_can:
            instrument: dict[str, Any] = {"interface": "slcan", "channel": self.instrument.channel}
        else:
            instrument = {"serial_port": self.instrument.serial_port}
        return {"stand": stand, "instrument": instrument}

    def describe(self) -> list[str]:
        """Human lines: what listens where."""
        ep = self.endpoints()
        lines = [f"stand:      {self.stand.endpoint}"]
        if self.stand.transport == "rtu" and self.stand.link_path is not None:
            lines[-1] += f" (linked at {self.stand.link_path})"
        where = ep["instrument"].get("channel") or ep["instrument"].get("serial_port")
        kind = "slcan" if self.instrument.is_can else "serial"
        line = f"instrument: {self.instrument.driver} over {kind} {where}"
        if self.instrument.link_path is not None:
            line += f" (linked at {self.instrument.link_path})"
        lines.append(line)
        return lines

    # -- fault schedule -----------------------------------------------------------------------
    def _moving(self) -> bool:
        angles = self.stand.true_angles(self.clock.monotonic())
        return any(abs(v) > self.sim.motion_threshold_deg for v in angles.values())

    def _run_schedule(self) -> None:
        while not self._stop.wait(0.005):
            if self._moving():
                self.motion_started_at = self.clock.monotonic()
                break
        else:
            return
        for fault in sorted(self.sim.faults, key=lambda f: f.after_motion_s):
            due = self.motion_started_at + fault.after_motion_s
            if self._stop.wait(max(0.0, due - self.clock.monotonic())):
                return
            target = self.stand if fault.target == "stand" else self.instrument
            target.inject(fault.kind, **fault.params)
            self.injected.append((self.clock.monotonic(), fault.target, fault.kind))


def _link(where: str | None) -> Path | None:
    """A config's device path becomes a stable symlink to the simulator's pty."""
    if not where or "://" in where:
        return None
    return Path(where)
