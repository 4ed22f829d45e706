"""The stand driver's register side: the link and the register map, and what travels on them.

``StandIO`` connects and reads the identity, reads the feedback block and decodes it into a
``StandSample`` (stamped by the link, passed to the sample listener, its fault or E-stop raised as
``StandFault``), and writes registers in as few requests as the map allows. It holds no
setpoint history and checks no limit: that is ``ModbusStand`` (``stand.py``), built on it.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping

from benchctl.clock import REAL, Clock
from benchctl.devices.base import (
    DeviceIdentity,
    StandSample,
    StandStatus,
    TrajectoryStatus,
)
from benchctl.devices.modbus.link import ModbusLink
from benchctl.devices.modbus.regmap import Field, RegisterMap, pdu_address
from benchctl.errors import ConfigError, DeviceTimeout, StandFault

# the driver's one logger: its messages keep the name they have always been logged under
log = logging.getLogger("benchctl.devices.modbus.stand")

SetpointListener = Callable[[float, dict[str, float], float | None], None]
SampleListener = Callable[[StandSample], None]


class StandIO:
    """A stand's registers over a Modbus link, as the register map lays them out.

    Parameters
    ----------
    link
        A :class:`ModbusLink` (not yet connected); the driver never opens a transport itself.
    regmap
        The validated register map.
    axes
        The axes driven (a subset of the map's axes): the feedback block decodes theirs.
    clock
        The run's clock (``benchctl.clock``): its ``monotonic`` (seconds) stamps the samples,
        its ``sleep`` paces the waits; the real one by default.
    """

    def __init__(
        self,
        link: ModbusLink,
        regmap: RegisterMap,
        *,
        axes: tuple[str, ...] = ("roll", "pitch"),
        clock: Clock = REAL,
    ) -> None:
        for a in axes:
            if a not in regmap.axes:
                raise ConfigError(
                    f"{regmap.source}: axes: axis {a!r} is driven but not in the map "
                    f"(map has {list(regmap.axes)})"
                )
        self.link = link
        self.map = regmap
        self.axes = tuple(axes)
        self.identity: DeviceIdentity | None = None
        self.last_sample: StandSample | None = None
        self.clock = clock
        self._clock = clock.monotonic
        self._sleep = clock.sleep
        self.on_setpoint: SetpointListener | None = None  # every setpoint sent (ramps included)
        self.on_sample: SampleListener | None = None  # every feedback block decoded
        self._closed = False
        self._fb_addr, self._fb_count = regmap.feedback_span()
        # the feedback block's values as _decode_feedback takes them: status word, fault code,
        # heartbeat echo, [sample time], each driven axis's angle, rate and setpoint,
        # [the trajectory queue's level, next index, played, underruns]
        m = regmap
        fb = [m.status_word, m.fault_code, m.heartbeat_echo]
        fb += [m.sample_time] if m.sample_time is not None else []
        for a in self.axes:
            fb += [m.axes[a].angle, m.axes[a].rate, m.axes[a].setpoint]
        tr = m.trajectory
        fb += [tr.level, tr.next_index, tr.played, tr.underruns] if tr is not None else []
        self._fb_decode = regmap.block_decoder(fb, self._fb_addr, self._fb_count)
        self._read_chunks: dict[tuple[int, int], list[tuple[int, int]]] = {}

    # -- connection -----------------------------------------------------------------------
    def connect(self) -> DeviceIdentity:
        """Open the link and read the identity registers."""
        self.link.connect()
        self._closed = False
        values: dict[str, str] = {}
        for name, f in self.map.identity.items():
            values[name] = str(self.map.decode(f, self._read(f.address, f.n_registers)))
        extra = {
            k: v for k, v in values.items() if k not in ("vendor", "model", "serial", "firmware")
        }
        extra["register_map"] = self.map.name
        if self.map.sample_time is not None:  # the recording needs it to unwrap stand_time_s
            extra["sample_time_wrap_s"] = repr(self.map.sample_time_wrap_s)
        self.identity = DeviceIdentity(
            vendor=values["vendor"],
            model=values["model"],
            serial=values.get("serial", ""),
            firmware=values.get("firmware", ""),
            protocol=self.link.endpoint,
            extra=extra,
        )
        return self.identity

    def close(self) -> None:
        """Close the link. Idempotent; does not move or disable the stand."""
        if not self._closed:
            self._closed = True
            self.link.close()

    # -- reading --------------------------------------------------------------------------
    def read_status(self) -> StandStatus:
        """The decoded status word, fault code and heartbeat echo. Never raises on a fault."""
        return self._read_feedback()[1].status

    def read_sample(self) -> StandSample:
        """Encoder angles, rates and active setpoints, stamped when the stand took them: the
        request/reply midpoint on TCP, the end of the request on the wire on RTU
        (``ModbusLink.sample_stamp``).

        Raises
        ------
        StandFault
            When the stand reports a fault or an E-stop (``code`` is its fault code).
        """
        _, sample = self._read_feedback()
        self._raise_fault(sample.status)
        return sample

    def read_state(self) -> StandSample:
        """As :meth:`read_sample` but never raises on a fault or an E-stop: the state of a
        faulted stand, for a status display (``benchctl stand status``)."""
        return self._read_feedback()[1]

    def _read_feedback(self) -> tuple[list[int], StandSample]:
        t0 = self._clock()
        regs = self._read(self._fb_addr, self._fb_count)
        t1 = self._clock()
        return regs, self._decode_feedback(regs, t0, t1)

    def _decode_feedback(self, regs: list[int], t0: float, t1: float) -> StandSample:
        m = self.map
        v = self._fb_decode(regs)
        word, code, echo = int(v[0]), int(v[1]), int(v[2])
        status = StandStatus(**m.status_from_word(word), fault_code=code, heartbeat=echo)
        k = 3
        t_stand = None
        if m.sample_time is not None:
            t_stand, k = v[3], 4
        axes = self.axes
        angle: dict[str, float] = {}
        rate: dict[str, float] = {}
        setpoint: dict[str, float] = {}
        for a in axes:
            angle[a], rate[a], setpoint[a] = v[k], v[k + 1], v[k + 2]
            k += 3
        traj = None
        if m.trajectory is not None:
            traj = TrajectoryStatus(
                level=int(v[k]), next_index=int(v[k + 1]), played=int(v[k + 2]),
                underruns=int(v[k + 3]),
            )
        link = self.link
        stamp = getattr(link, "sample_stamp", None)
        window = getattr(link, "sample_window", None)
        sample = StandSample(
            t_host=stamp(t0, t1) if stamp is not None else 0.5 * (t0 + t1),
            rtt_s=t1 - t0,
            t_stand=t_stand,
            t_window=window(t0, t1) if window is not None else (t0, t1),
            angle_deg=angle,
            rate_deg_s=rate,
            setpoint_deg=setpoint,
            status=status,
            trajectory=traj,
        )
        self.last_sample = sample
        self._notify_sample(sample)
        return sample

    def _notify_sample(self, sample: StandSample) -> None:
        """Pass a sample to the listener; a listener's failure never stops the driver."""
        cb = self.on_sample
        if cb is not None:
            try:
                cb(sample)
            except Exception:
                log.exception("stand sample listener failed")

    def _notify_setpoint(
        self, t: float, angle_deg: Mapping[str, float], t_slot: float | None
    ) -> None:
        cb = self.on_setpoint
        if cb is not None:
            try:
                cb(t, dict(angle_deg), t_slot)
            except Exception:
                log.exception("stand setpoint listener failed")

    def _raise_fault(self, st: StandStatus) -> None:
        if st.estop:
            raise StandFault(
                f"{self.link.endpoint}: E-stop is active (fault code {st.fault_code})",
                st.fault_code or None,
            )
        if st.fault:
            text = self.map.fault_codes.get(st.fault_code, "unknown fault")
            raise StandFault(
                f"{self.link.endpoint}: stand fault {st.fault_code} ({text})", st.fault_code
            )

    def _check_deadline(self, deadline: float, what: str) -> None:
        if self._clock() > deadline:
            raise DeviceTimeout(f"{self.link.endpoint}: timed out {what}")

    # -- low level --------------------------------------------------------------------------
    def _control(self, *bits: str) -> None:
        word = self.map.word_from_bits(self.map.control_bits, bits)
        self._write_field(self.map.control_word, word)

    def _write_field(self, f: Field, value: float) -> None:
        self._write_words({f.address + i: w for i, w in enumerate(self.map.encode(f, value))})

    def _write_words(self, words: Mapping[int, int]) -> None:
        """Write registers (address → word) in as few requests as the map allows (FC6 for one)."""
        for addr, count in register_runs(words, self.map.max_write):
            vals = [words[addr + i] for i in range(count)]
            if count == 1:
                self.link.write_register(pdu_address(addr), vals[0])
            else:
                self.link.write_registers(pdu_address(addr), vals)

    def _read(self, addr: int, count: int) -> list[int]:
        chunks = self._read_chunks.get((addr, count))
        if chunks is None:  # the same few spans every cycle: worked out once
            chunks = register_runs({addr + i: 0 for i in range(count)}, self.map.max_read)
            self._read_chunks[(addr, count)] = chunks
        out: list[int] = []
        for a, c in chunks:
            out += self.link.read_registers(pdu_address(a), c)
        return out


def register_runs(words: Mapping[int, int], max_count: int) -> list[tuple[int, int]]:
    """(address, count) runs of consecutive addresses, each at most ``max_count`` long."""
    out: list[tuple[int, int]] = []
    for a in sorted(words):
        if out and out[-1][0] + out[-1][1] == a and out[-1][1] < max_count:
            out[-1] = (out[-1][0], out[-1][1] + 1)
        else:
            out.append((a, 1))
    return out


__all__ = ["SampleListener", "SetpointListener", "StandIO"]
