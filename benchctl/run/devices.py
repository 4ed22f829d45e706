"""A run's devices and folders: the stand and the instrument opened from the bench config
(``open_devices``) and closed as the run's ``ExitStack`` unwinds, the backstop of the one cleanup
path (``close_at_exit``), the simulators of a simulated bench (``simulators``; their seeded
disturbances recorded and shown: ``announce_disturbances``), the recording's
folder (``recording_dir``) and a device's identity as the record keeps it."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from benchctl.clock import REAL, Clock
from benchctl.config import BenchConfig
from benchctl.devices.base import AngleSensor, DeviceIdentity, Stand
from benchctl.devices.instrument import open_instrument
from benchctl.devices.modbus import open_stand
from benchctl.errors import ConfigError
from benchctl.recording import RecordingWriter
from benchctl.run.display import Display
from benchctl.run.supervisor import Supervisor
from benchctl.sim.bench import SimBench
from benchctl.sim.disturb import Disturbances
from benchctl.sim.launch import start_simulators
from benchctl.text import (
    file_name_part,
    from_device,
)

log = logging.getLogger(__name__)

SIM_LOG = "sim.log"  # the simulators' output, in the recording


DeviceFactory = Callable[[BenchConfig, Path], tuple[Stand, AngleSensor]]


def open_devices(
    cfg: BenchConfig, recording: Path, *, clock: Clock = REAL
) -> tuple[Stand, AngleSensor]:
    """The real drivers for this config (also what talks to the simulators), on ``clock``."""

    can_log = None
    if cfg.instrument.driver != "nmea0183" and cfg.instrument.can_log:
        can_log = recording / cfg.instrument.can_log
    stand = open_stand(cfg.stand, clock=clock)
    try:
        sensor = open_instrument(cfg.instrument, can_log_path=can_log, clock=clock)
    except BaseException:
        stand.close()
        raise
    return stand, sensor


@contextlib.contextmanager
def simulators(
    cfg: BenchConfig,
    log_path: Path | None = None,
    clock: Clock = REAL,
    disturb: Callable[[Disturbances], None] | None = None,
    horizon_s: float = 3600.0,
) -> Iterator[BenchConfig]:
    """With a ``sim:`` section, run the simulators for the length of the run: a child process
    (its output to ``log_path``, the recording's ``sim.log``), or, on simulated time
    (``sim.clock: virtual``, ``clock`` a virtual clock), in this process on ``clock`` over
    in-process links. Yields the config pointed at them.

    On simulated time with ``sim.disturb``, the seeded disturbances (``benchctl.sim.disturb``)
    over ``horizon_s`` seconds are applied to the clock, the links and the simulators' fault
    schedule, and handed to ``disturb`` (the run records them and takes the operator's stop)."""
    if cfg.sim is None:
        yield cfg
        return
    if cfg.sim.clock == "virtual":
        if not clock.virtual:
            raise ConfigError(
                f"{cfg.source}: field sim.clock = virtual: the run needs a virtual clock "
                "(benchctl run makes one; a caller of Session passes one)"
            )

        plan = None
        if cfg.sim.disturb is not None:
            plan = Disturbances(cfg.sim.disturb, horizon_s)
            cfg = plan.with_faults(cfg)
        with SimBench(cfg, private=True, clock=clock) as bench:
            if plan is not None:
                bench.disturb(plan)
                if disturb is not None:
                    disturb(plan)
            yield bench.config()
        return

    with start_simulators(cfg, log_path=log_path) as sim:
        yield sim.config


def announce_disturbances(plan: Disturbances, *, writer: RecordingWriter, display: Display,
                          supervisor: Supervisor) -> None:
    """Simulated time with seeded disturbances: record and show the seed and the schedule,
    and press Ctrl-C (the SIGINT path) at the operator's drawn moment."""
    writer.event("disturbances", **plan.describe())
    writer.update_meta(disturbances=plan.describe())
    display.message(
        f"simulated disturbances: seed {plan.spec.seed} ({len(plan.stalls)} host stalls, "
        f"{len(plan.faults)} faults"
        + (f", operator stop at {plan.operator_stop_s:g} s" if plan.operator_stop_s else "")
        + "); the same seed replays this run exactly"
    )
    if plan.operator_stop_s is not None:
        supervisor.interrupt_after(plan.operator_stop_s)


def recording_dir(out_dir: Path, serial: str, prefix: str = "", *, clock: Clock = REAL) -> Path:
    """A new folder name in ``out_dir``: ``<prefix><UTC time>_<serial>`` (``_2``, ``_3`` … when
    taken), the serial as a safe file-name part of at most 64 bytes
    (``benchctl.text.file_name_part``); the time is ``clock``'s."""
    stamp = clock.now_utc().strftime("%Y%m%dT%H%M%SZ")
    base = out_dir / f"{prefix}{stamp}_{file_name_part(serial)}"
    p, i = base, 1
    while p.exists():
        i += 1
        p = base.with_name(f"{base.name}_{i}")
    return p


def identity_of(d: DeviceIdentity) -> dict[str, Any]:
    """A device's identity for the metadata: what it reports, never refused, each string cut
    to ``benchctl.text.DEVICE_TEXT_MAX`` (shown safe wherever it is printed)."""
    return {
        "vendor": from_device(d.vendor),
        "model": from_device(d.model),
        "serial": from_device(d.serial),
        "firmware": from_device(d.firmware),
        "protocol": from_device(d.protocol),
        "extra": {from_device(k): from_device(v) for k, v in d.extra.items()},
    }


def identity_text(d: dict[str, Any]) -> str:
    """A device's identity (``identity_of``) on one line, as its precheck shows it."""
    return " ".join(
        str(d[k]) for k in ("vendor", "model", "serial", "firmware", "protocol") if d.get(k)
    )


def close_at_exit(stack: contextlib.ExitStack, stand: Stand, sensor: AngleSensor) -> None:
    """The devices' backstop: each one closed as the run's ``stack`` unwinds (the stand first,
    as the cleanup closes them). The one cleanup path (``benchctl.run.supervisor.shutdown``:
    bring to rest, disable, close) has closed them by then: a second close does nothing, and a
    failing one is logged, never raised."""
    stack.callback(_close_quietly, "instrument", sensor)
    stack.callback(_close_quietly, "stand", stand)


def _close_quietly(name: str, device: Stand | AngleSensor) -> None:
    try:
        device.close()
    except Exception as e:
        log.warning("%s not closed: %s: %s", name, type(e).__name__, e)
