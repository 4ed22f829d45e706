"""The stand outside a run: its state, a fault reset, the way home (``benchctl stand``).

- ``read_state(cfg)``: the stand's identity, status (ready, enabled, moving, fault with the
  register map's text, E-stop, limit), each axis's angle, rate and setpoint, and who holds its
  lock. Reads only: no lock taken, nothing written to the stand.
- ``reset_fault(cfg, confirm, who)``: clears a latched fault or E-stop (the stand's
  ``fault_reset`` command), e.g. the heartbeat watchdog's fault after a run was killed with
  ``kill -9``. Nothing moves: the servo stays off.
- ``home(cfg, confirm, who)``: from wherever it rests, the stand is switched on, ramped to zero
  within its configured rate and acceleration limits (the driver's ``ramp_to_zero``, as every
  run ends) and switched off again, then checked at rest at zero.

``reset_fault`` and ``home`` hold the stand's lock (``benchctl.run.lock``) from before they
connect to after they close, so no run can start meanwhile and neither runs while a run (or a
plan, or another ``benchctl stand``) holds the stand: ``StandInUse`` names the holder. Each asks
``confirm`` (the question → yes/no) after reading the stand's state and before acting. Each
action, its outcome included (done, declined, refused, failed), is one line appended to
``stand.log`` in the config's ``run.output_dir`` — beside the recordings, where a lab keeps its
records — and logged.
"""

from __future__ import annotations

import contextlib
import getpass
import logging
import os
import socket
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchctl.clock import REAL, Clock
from benchctl.config import BenchConfig
from benchctl.devices.base import DeviceIdentity, StandSample
from benchctl.devices.modbus.stand import ModbusStand, open_stand
from benchctl.errors import BenchError, DeviceError, SafetyAbort, StandFault, StandInUse
from benchctl.run import prechecks as pc
from benchctl.run.lock import (
    StandLock,
    describe_holder,
    endpoint_key,
    lock_dir_of,
    process_alive,
    stand_lock,
)

log = logging.getLogger(__name__)

STAND_LOG = "stand.log"
HOME_TIMEOUT_S = 120.0  # the way home: at rest at zero within this
RESET_TIMEOUT_S = 2.0  # a fault reset: cleared within this

Confirm = Callable[[str], bool]


@dataclass
class StandState:
    """What ``benchctl stand status`` shows."""

    endpoint: str  # the lock's key: ``tcp localhost:5020`` / ``rtu /dev/ttyUSB0``
    link: str  # the driver's endpoint
    identity: DeviceIdentity
    sample: StandSample  # read without raising on a fault
    fault_text: str  # the register map's text for the fault code ("" without a fault)
    holder: dict[str, Any] | None  # the lock file's details
    holder_alive: bool  # its process still runs (else: details left by a killed process)
    lock_file: Path

    @property
    def faulted(self) -> bool:
        st = self.sample.status
        return st.fault or st.estop

    def angles(self) -> str:
        return ", ".join(f"{a} {v:+.3f}°" for a, v in self.sample.angle_deg.items())

    def to_dict(self) -> dict[str, Any]:
        st = self.sample.status
        ident = self.identity
        return {
            "endpoint": self.endpoint,
            "link": self.link,
            "identity": {"vendor": ident.vendor, "model": ident.model, "serial": ident.serial,
                         "firmware": ident.firmware},
            "ready": st.ready,
            "enabled": st.enabled,
            "moving": st.moving,
            "fault": st.fault,
            "fault_code": st.fault_code,
            "fault_text": self.fault_text,
            "estop": st.estop,
            "limit": st.limit,
            "table_running": st.table_running,
            "trajectory_running": st.trajectory_running,
            "axes": {a: {"angle_deg": self.sample.angle_deg[a],
                         "rate_deg_s": self.sample.rate_deg_s[a],
                         "setpoint_deg": self.sample.setpoint_deg[a]}
                     for a in self.sample.angle_deg},
            "lock": {"file": str(self.lock_file),
                     "held": self.holder is not None and self.holder_alive,
                     "holder": self.holder},
        }


@dataclass
class ActionOutcome:
    """What ``reset_fault`` / ``home`` did: ``done`` False when nothing needed doing or the
    operator answered no (``declined``)."""

    action: str  # reset | home
    done: bool
    detail: str
    before: StandState
    after: StandState | None = None
    declined: bool = False
    log_file: Path | None = None


# ----------------------------------------------------------------------------- reading
@contextlib.contextmanager
def _connected(cfg: BenchConfig, *, clock: Clock = REAL) -> Iterator[ModbusStand]:
    stand = open_stand(cfg.stand, clock=clock)
    try:
        try:
            stand.connect()
        except BenchError as e:
            if cfg.sim is not None:  # a simulated bench: its stand lives in `benchctl sim`
                raise DeviceError(
                    f"{e}. {cfg.source} simulates its bench: its stand answers only while "
                    f"`benchctl sim --config {cfg.source}` runs (start it in another terminal)"
                ) from None
            raise
        yield stand
    finally:
        with contextlib.suppress(BenchError, OSError):
            stand.close()


def _state(cfg: BenchConfig, stand: ModbusStand) -> StandState:
    lock = StandLock(endpoint_key(cfg.stand), lock_dir_of(cfg))
    holder = lock.holder()
    sample = stand.read_state()
    code = sample.status.fault_code
    text = stand.map.fault_codes.get(code, "unknown fault") if code else ""
    assert stand.identity is not None
    return StandState(endpoint_key(cfg.stand), stand.link.endpoint, stand.identity, sample, text,
                      holder, holder is not None and process_alive(holder.get("pid")), lock.path)


def read_state(cfg: BenchConfig, *, clock: Clock = REAL) -> StandState:
    """The stand's state and its lock's holder; takes no lock and writes nothing.

    A Modbus RTU stand held by a running process is not read: a second master on its serial
    line would collide with the run's frames (``StandInUse`` names the holder). Over TCP each
    client has its own connection, and the state is read beside the run."""
    if cfg.stand.driver == "modbus-rtu":
        key = endpoint_key(cfg.stand)
        holder = StandLock(key, lock_dir_of(cfg)).holder()
        if holder is not None and process_alive(holder.get("pid")):
            raise StandInUse(
                f"stand {key} is in use by {describe_holder(holder)}: its serial line is not "
                "opened while a run holds it (a second Modbus master would collide with the "
                "run's frames); the run's own display shows the stand", holder)
    with _connected(cfg, clock=clock) as stand:
        return _state(cfg, stand)


def describe(state: StandState, config: Path | str | None = None) -> list[str]:
    """``benchctl stand status`` as lines of text."""
    st = state.sample.status
    ident = state.identity
    flags = ["ready" if st.ready else "NOT READY", "enabled" if st.enabled else "servo off",
             "moving" if st.moving else "at rest"]
    if st.table_running:
        flags.append("table running")
    if st.trajectory_running:
        flags.append("trajectory running")
    lines = [f"stand {state.endpoint} ({state.link}): {ident.vendor} {ident.model}, serial "
             f"{ident.serial or '?'}, firmware {ident.firmware or '?'}",
             f"  state    {', '.join(flags)}"]
    if st.fault:
        lines.append(f"  FAULT    code {st.fault_code} ({state.fault_text})")
    if st.estop:
        lines.append("  E-STOP   engaged")
    if st.limit:
        lines.append("  LIMIT    a limit switch is active")
    for a in state.sample.angle_deg:
        lines.append(f"  {a:<8} {state.sample.angle_deg[a]:+8.3f}°   rate "
                     f"{state.sample.rate_deg_s[a]:+7.3f}°/s   setpoint "
                     f"{state.sample.setpoint_deg[a]:+8.3f}°")
    if state.holder is None:
        lines.append(f"  lock     free ({state.lock_file})")
    elif state.holder_alive:
        lines.append(f"  lock     held by {describe_holder(state.holder)}")
    else:
        lines.append(f"  lock     free (left by {describe_holder(state.holder)}, which has "
                     "ended)")
    if state.faulted:
        lines.append(f"  note     {pc.clear_fault_hint(config)}")
    return lines


# ----------------------------------------------------------------------------- acting
def _who(who: Mapping[str, Any]) -> str:
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = str(os.getuid())
    op = f", operator {who['operator']}" if who.get("operator") else ""
    return f"{user}@{socket.gethostname()} (pid {os.getpid()}{op})"


def stand_log(cfg: BenchConfig, action: str, endpoint: str, who: Mapping[str, Any],
              outcome: str, *, clock: Clock = REAL) -> Path | None:
    """Append one line to ``<run.output_dir>/stand.log`` (and log it); the file, or None when
    it cannot be written (a warning: the action itself stands)."""
    stamp = clock.now_utc().isoformat(timespec="milliseconds").replace("+00:00", "Z")
    line = f"{stamp} stand {action} {endpoint} by {_who(who)}: {outcome}"
    log.info("%s", line)
    path = Path(cfg.run.output_dir) / STAND_LOG
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a", encoding="utf-8") as f:
            f.write(line.replace("\n", " ") + "\n")
    except OSError as e:
        log.warning("stand log not written: %s: %s", path, e.strerror)
        return None
    return path


@contextlib.contextmanager
def _held(cfg: BenchConfig, action: str, who: Mapping[str, Any],
          clock: Clock = REAL) -> Iterator[None]:
    """The stand's lock for ``action``; a refusal (the stand in use) is logged and raised."""
    holder = {**who, "command": f"benchctl stand {action}",
              "config": None if cfg.source is None else str(cfg.source)}
    try:
        with stand_lock(cfg, holder):
            yield
    except StandInUse as e:
        stand_log(cfg, action, endpoint_key(cfg.stand), who, f"refused: {e}", clock=clock)
        raise


def reset_fault(cfg: BenchConfig, confirm: Confirm, who: Mapping[str, Any], *,
                clock: Clock = REAL) -> ActionOutcome:
    """Clear the stand's latched fault or E-stop (see the module notes). The servo stays off."""
    with _held(cfg, "reset", who, clock), _connected(cfg, clock=clock) as stand:
        before = _state(cfg, stand)
        st = before.sample.status
        if not before.faulted:
            return ActionOutcome("reset", False, "no fault or E-stop latched: nothing to reset",
                                 before)
        what = (f"fault {st.fault_code} ({before.fault_text})" if st.fault else "") + (
            " and " if st.fault and st.estop else "") + ("the E-stop" if st.estop else "")
        question = (f"Reset {what} of stand {before.endpoint} (at {before.angles()}; the servo "
                    "stays off)?")
        out = ActionOutcome("reset", False, "", before)
        try:
            if not confirm(question):
                out.declined, out.detail = True, f"not reset: the operator answered no ({what})"
            else:
                try:
                    stand.reset_fault(RESET_TIMEOUT_S)
                except StandFault as e:
                    raise StandFault(f"{what} not cleared: {e} (is its cause still there? an "
                                     "E-stop button still pressed?)", e.code) from None
                out.after = _state(cfg, stand)
                out.done, out.detail = True, f"{what} cleared; at {out.after.angles()}"
        except BaseException as e:
            stand_log(cfg, "reset", before.endpoint, who, f"FAILED: {what}: {_err(e)}", clock=clock)
            raise
        out.log_file = stand_log(cfg, "reset", before.endpoint, who, out.detail, clock=clock)
        return out


def home(cfg: BenchConfig, confirm: Confirm, who: Mapping[str, Any], *,
         clock: Clock = REAL) -> ActionOutcome:
    """Bring the stand to zero within its limits: enable, ramp, disable (module notes)."""
    with _held(cfg, "home", who, clock), _connected(cfg, clock=clock) as stand:
        before = _state(cfg, stand)
        if before.faulted:
            st = before.sample.status
            what = f"fault {st.fault_code} ({before.fault_text})" if st.fault else "the E-stop"
            msg = f"stand {before.endpoint} reports {what}: it cannot move; " + (
                pc.clear_fault_hint(cfg.source))
            stand_log(cfg, "home", before.endpoint, who, f"refused: {msg}", clock=clock)
            raise SafetyAbort(msg)
        tol = cfg.stand.zero_tolerance_deg
        zero = pc.check_stand_at_zero(before.sample, tol)
        ready = pc.check_stand_ready(before.sample.status, before.sample,
                                     list(before.sample.angle_deg))
        if zero.ok and ready.ok:
            return ActionOutcome("home", False, f"already at rest at zero ({before.angles()}): "
                                 "nothing moved", before)
        lim = cfg.stand.limits
        question = (f"Move stand {before.endpoint} from {before.angles()} to zero (servo on, a "
                    f"ramp within {lim.rate_deg_s:g}°/s and {lim.accel_deg_s2:g}°/s², servo "
                    "off)? Is the area around the stand clear of people?")
        out = ActionOutcome("home", False, "", before)
        try:
            if not confirm(question):
                out.declined = True
                out.detail = f"not moved: the operator answered no (at {before.angles()})"
            else:
                try:
                    stand.ramp_to_zero(HOME_TIMEOUT_S)
                finally:
                    with contextlib.suppress(BenchError, OSError):
                        stand.disable()
                out.after = after = _state(cfg, stand)
                ok = pc.check_stand_at_zero(after.sample, tol)
                if not ok.ok or after.faulted:
                    raise SafetyAbort(f"stand not at rest at zero after the ramp: {ok.detail}")
                out.done = True
                out.detail = f"from {before.angles()} to {after.angles()}; servo off"
        except BaseException as e:
            stand_log(cfg, "home", before.endpoint, who,
                      f"FAILED from {before.angles()}: {_err(e)}", clock=clock)
            raise
        out.log_file = stand_log(cfg, "home", before.endpoint, who, out.detail, clock=clock)
        return out


def _err(e: BaseException) -> str:
    if isinstance(e, KeyboardInterrupt):
        return str(e) or "interrupted by SIGINT"
    return f"{type(e).__name__}: {e}"


__all__ = [
    "STAND_LOG",
    "ActionOutcome",
    "StandState",
    "describe",
    "home",
    "read_state",
    "reset_fault",
    "stand_log",
]
