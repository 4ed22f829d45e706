"""The simulated instrument on the stand: a real protocol peer on a pseudo-terminal.

It samples the true motion at its own output instants (``rate_hz`` on its own clock, a fixed
grid from ``start``), passes it through ``InstrumentModel`` (gain, dynamics, latency, bias,
drift, noise, quantisation) and publishes, by ``instrument_cfg.driver``:

- ``canopen``: a slcan adapter carrying a CiA 410 node (``instrument_cfg.node_id``, the EDS in
  ``instrument_cfg.eds``): TPDO1 = 6010h pitch, 6020h roll (INTEGER16, ``raw · res/1000`` deg,
  saturating at the integer's extremes) sent in OPERATIONAL only; SDO and NMT are answered by
  ``canopen``'s ``LocalNode`` (a write to 6000h changes the resolution);
- ``j1939``: a slcan adapter carrying PGN 61459 frames (priority 3, source address
  ``source_address`` or 0x80; latency byte = the model's latency);
- ``nmea2000``: a slcan adapter carrying PGN 127257 (priority 2, SID = sample number mod 253,
  yaw not available);
- ``nmea0183``: a talker writing ``sentence`` (default PASHR) lines.

Faults, by ``inject(kind, **params)`` and undone by ``clear_faults()`` (except ``drop``):

``garbled`` (``fraction`` = 0.1, ``how``)
    each output frame is damaged with probability ``fraction``. CAN ``how``: ``length`` (last
    byte cut, the default), ``range`` (every angle "not available"/overflow), ``id`` (sent on an
    id the driver does not expect), ``line`` (the slcan text corrupted). NMEA 0183: ``checksum``
    (default), ``truncated``, ``range`` (roll 999.99°). Both: ``bytes``, arbitrary damage on
    the wire (``damage_bytes``): 1–3 bytes of the slcan line or sentence replaced or inserted,
    any byte value (control characters, bytes beyond ASCII) except a line end (CR, LF, BEL),
    and always at least one byte beyond ASCII, so the damage stays one line and is always
    detectable: the driver counts it ``decode``.
``silent``
    the instrument sends nothing (and a CANopen node answers no SDO); the model keeps running.
``stuck``
    the output freezes at its last value; frames keep coming.
``drop``
    the pty is hung up (the driver's reads fail) and the symlink removed; irreversible.

``send_raw(data)`` writes exact bytes on the wire between two output frames (the instrument's
own frames go on unchanged): a test's way to put one chosen bad frame, sentence or line noise
in front of the driver. ``counts["raw"]`` counts the writes done.

On an in-process link (simulated time) the port and the loop run by the clock are
``instrument_channel``'s.
"""

from __future__ import annotations

import contextlib
import math
import random
import select
import struct
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig, SimInstrumentConfig
from benchctl.devices.base import AXES
from benchctl.errors import ConfigError
from benchctl.faultspec import FaultSpecError, check_params
from benchctl.sim import nmea_talker
from benchctl.sim.instrument_channel import _ChannelPort, _Loop
from benchctl.sim.instrument_model import InstrumentModel
from benchctl.sim.motion import MotionSource
from benchctl.sim.pty_port import PtyPort
from benchctl.sim.slcan import SlcanAdapter, frame_bits

FAULTS = ("garbled", "silent", "stuck", "drop")
CAN_GARBLING = ("length", "range", "id", "line", "bytes")
NMEA_GARBLING = ("checksum", "truncated", "range", "bytes")
#: what the ``bytes`` garbling may write: anything but a line end (slcan CR, BEL; NMEA CR LF)
_NOISE = bytes(b for b in range(256) if b not in b"\r\n\a")
DEFAULT_SOURCE_ADDRESS = 0x80
J1939_PRIORITY = 3
N2K_PRIORITY = 2
PGN_SSI = 61459
PGN_ATTITUDE = 127257
_MAX_CATCH_UP_S = 0.5  # further behind than this, the simulator skips instants (counted)
_AXES = frozenset(AXES)


def _clamp(v: int, lo: int, hi: int) -> int:
    return lo if v < lo else hi if v > hi else v


def damage_bytes(line: bytes, rng: random.Random) -> bytes:
    """``line`` (a slcan line or a sentence with its line end) damaged on the wire.

    1–3 times a random byte replaces one of the line or is inserted into it: any value but a
    line end, the last one always beyond ASCII (0x80–0xFF). The line end is kept, so the result
    is one line, and never a valid one.
    """
    n = len(line.rstrip(b"\r\n\a"))
    body, end = bytearray(line[:n]), line[n:]
    ops = rng.randint(1, 3)
    for i in range(ops):
        b = rng.randrange(0x80, 0x100) if i == ops - 1 else rng.choice(_NOISE)
        if body and rng.random() < 0.5:
            body[rng.randrange(len(body))] = b
        else:
            body.insert(rng.randrange(len(body) + 1), b)
    return bytes(body) + end


class _SimNetwork(canopen.Network):
    """A canopen network whose sends go to the simulated adapter (the library's documented hook)."""

    def __init__(self, send: Any) -> None:
        super().__init__(None)
        self._send = send

    def send_message(self, can_id: int, data: Any, remote: bool = False) -> None:
        self._send(can.Message(arbitration_id=can_id, is_extended_id=can_id > 0x7FF,
                               data=bytes(data), is_remote_frame=remote))


class SimInstrument:
    """A simulated instrument speaking ``instrument_cfg.driver``'s protocol on a pty.

    Parameters
    ----------
    model_cfg : SimInstrumentConfig
        Its measurement model and output rate.
    instrument_cfg : InstrumentConfig
        The protocol (driver), node id / source address / sentence, bitrate, EDS.
    motion : MotionSource
        The true stand angles at a host monotonic time.
    link_path : Path, optional
        A stable symlink to the pty.

    Attributes
    ----------
    serial_port, channel : str
        The pty path the driver opens (set by ``start``), for serial and CAN configs alike.
    counts : dict
        ``samples`` produced, ``sent`` data frames (TPDO / broadcast / sentence, garbled ones
        included; not SDO answers), ``garbled``, ``overflow`` (host not reading: frame lost),
        ``skipped`` instants (simulator stalled), ``sdo`` requests received, ``raw`` writes of
        ``send_raw`` done.
    """

    def __init__(
        self,
        model_cfg: SimInstrumentConfig,
        instrument_cfg: InstrumentConfig,
        motion: MotionSource,
        *,
        link_path: Path | None = None,
        clock: Clock = REAL,
        channel: str | None = None,
    ) -> None:
        self.clock = clock
        #: transport "channel": the name of the in-process link (``simchan://NAME``) the driver
        #: opens instead of a pty; its bytes take the serial byte time of ``instrument_cfg``
        self.channel_name = channel
        self.cfg = instrument_cfg
        self.model_cfg = model_cfg
        self.model = InstrumentModel(model_cfg, AXES)
        self.motion = motion
        self.link_path = link_path
        self.driver = instrument_cfg.driver
        self.is_can = self.driver != "nmea0183"
        self.sentence = instrument_cfg.sentence or "PASHR"
        self.source_address = (instrument_cfg.source_address
                               if instrument_cfg.source_address is not None
                               else DEFAULT_SOURCE_ADDRESS)
        self.serial_port: str | None = None
        self.channel: str | None = None
        self._wire_bytes = 0  # the outputs' bytes written (wire_delay_s)
        self._line_end = 0.0  # when the line being written is in at the host (pty: emulated)
        self.counts = {"samples": 0, "sent": 0, "garbled": 0, "overflow": 0, "skipped": 0,
                       "sdo": 0, "raw": 0}
        self._raw: deque[bytes] = deque()
        self._lock = clock.lock()
        self._faults: dict[str, dict[str, Any]] = {}
        self._rng = random.Random(model_cfg.seed + 7919)
        self._last_y: dict[str, float] | None = None
        self._port: Any = None  # a PtyPort, or a _ChannelPort on an in-process link
        self._adapter: SlcanAdapter | None = None
        self._thread: Any = None
        self._stop = clock.event()
        self._ready = clock.event()
        self._start_error: BaseException | None = None
        self._bus_out: list[can.Message] = []
        self._utc_offset = clock.time() - clock.monotonic()
        self._net: _SimNetwork | None = None
        self._node: Any = None
        self._res_mdeg = 10
        if self.driver == "canopen":
            self._setup_canopen()
        #: the true motion for the model: one instant at a time, and all of a step's sub-steps
        #: in one call when the motion source can (the simulated stand can)
        mount = model_cfg.mounting
        self._mounting: tuple[bool, dict[str, int]] | None = None
        if mount.swap_axes or mount.roll_sign != 1 or mount.pitch_sign != 1:
            self._mounting = (mount.swap_axes,
                              {"roll": mount.roll_sign, "pitch": mount.pitch_sign})
        self._motion_fn: Any = self._true
        if hasattr(motion, "true_angles_many"):
            self._motion_fn = _Motion(self._true, self._true_many)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Open the pty and start publishing; returns when the pty is ready."""
        if self._thread is not None:
            return
        run: Any = self._run
        if self.channel_name is not None:
            self._port = _ChannelPort(self.clock, self.channel_name, self.cfg.baudrate)
            run = self._run_channel
        else:
            if self.clock.virtual:
                raise ConfigError("SimInstrument: simulated time needs an in-process channel "
                                  "(a pty runs on the host's time)")
            self._port = PtyPort(self.link_path)
        self.serial_port = self.channel = self._port.path
        if self.is_can:
            self._adapter = SlcanAdapter(self.cfg.bitrate, self._on_host_frame,
                                         clock=self.clock.monotonic)
        self._stop.clear()
        name = f"sim-instrument-{self.driver}"
        if self.channel_name is not None and self.clock.virtual:
            # on simulated time the loop is run by the clock, at each output instant and each
            # arrival of the host's bytes, where its thread would have been woken (_Loop)
            self._thread = _Loop(self, name)
            self._thread.start()
        else:
            self._thread = self.clock.thread(run, name=name)
            self._thread.start()
        self._ready.wait(5.0)

    def stop(self) -> None:
        """Stop publishing, close the pty, remove the symlink (idempotent)."""
        self._stop.set()
        t = self._thread
        if t is not None:
            t.join(timeout=5.0)
        self._thread = None
        if self._port is not None:
            self._port.close()

    def __enter__(self) -> SimInstrument:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def instrument_config(self) -> InstrumentConfig:
        """``instrument_cfg`` pointed at this simulator's pty (slcan for CAN drivers)."""
        if self.serial_port is None:
            raise RuntimeError("SimInstrument.start() first")
        if self.is_can:
            return self.cfg.model_copy(update={"interface": "slcan", "channel": self.channel})
        return self.cfg.model_copy(update={"serial_port": self.serial_port})

    @property
    def wire_delay_s(self) -> float:
        """The mean time an output spends on its serial link (its bytes at the link's byte
        time, 10 bits a byte): the host has it that long after its output instant, as on a real
        serial line — on an in-process link by its byte time, on a pty by the simulator holding
        each line back that long (a pty has no byte time of its own). 0 before any output."""
        sent = self.counts["sent"]
        if not sent:
            return 0.0
        return self._wire_bytes / sent * 10.0 / self.cfg.baudrate

    @property
    def wire_resolution_deg(self) -> float:
        """Quantisation step of the angles on the wire (deg)."""
        if self.driver == "canopen":
            return self._res_mdeg / 1000.0
        if self.driver == "j1939":
            return 0.002
        if self.driver == "nmea2000":
            return math.degrees(1e-4)
        return nmea_talker.RESOLUTION_DEG

    # ------------------------------------------------------------------ faults
    def inject(self, kind: str, **params: Any) -> None:
        """Start a fault (see the module docstring); a bad kind or parameter is ``ConfigError``."""
        try:  # the one table of kinds and parameters, shared with the config validator
            params = check_params("instrument", kind, params, driver=self.driver)
        except FaultSpecError as e:
            raise ConfigError(f"SimInstrument.inject: fault {kind!r}: {e}") from None
        if kind == "garbled":
            fraction = float(params.get("fraction", 0.1))
            ways = CAN_GARBLING if self.is_can else NMEA_GARBLING
            how = params.get("how", ways[0])
            params = {"fraction": fraction, "how": how}
        with self._lock:
            if kind == "stuck":
                params = {"value": dict(self._last_y) if self._last_y else None}
            self._faults[kind] = params

    def send_raw(self, data: bytes) -> None:
        """Write ``data`` as it is on the wire, between two output frames (``counts["raw"]``
        counts it when done; lost, and counted ``overflow``, if the host is not reading)."""
        self._raw.append(bytes(data))

    def clear_faults(self) -> None:
        """End garbled, silent and stuck (a dropped link stays dropped)."""
        with self._lock:
            drop = self._faults.get("drop")
            self._faults = {"drop": drop} if drop is not None else {}

    # ------------------------------------------------------------------ CANopen node
    def _setup_canopen(self) -> None:
        if self.cfg.eds is None:
            raise ConfigError("SimInstrument: driver canopen needs eds (an EDS file in drivers/)")
        self._net = _SimNetwork(self._bus_out.append)
        try:
            self._node = self._net.create_node(self.cfg.node_id, str(self.cfg.eds))
        except (OSError, KeyError, ValueError) as e:
            raise ConfigError(f"{self.cfg.eds}: cannot load EDS: {e}") from e
        self._res_mdeg = int(self._node.sdo[0x6000].raw)
        if self.model_cfg.serial_number is not None:
            self._node.sdo[0x1018][4].raw = self.model_cfg.serial_number
        self._node.add_write_callback(self._on_sdo_write)

    def _on_sdo_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if index == 0x6000:
            value = struct.unpack_from("<H", data)[0]
            if value == 0:
                raise canopen.SdoAbortedError(0x06090030)  # value range exceeded
            self._res_mdeg = value

    def _on_host_frame(self, msg: can.Message) -> None:
        """A frame the host transmitted through the adapter (SDO request, NMT)."""
        if self._net is None or "silent" in self._faults:
            return
        if msg.arbitration_id == 0x600 + self.cfg.node_id:
            self.counts["sdo"] += 1
        self._net.notify(msg.arbitration_id, bytearray(msg.data), self.clock.time())

    # ------------------------------------------------------------------ encoding
    def _frames(self, k: int, t: float, y: Mapping[str, float]) -> list[can.Message]:
        roll, pitch = y["roll"], y["pitch"]
        if self.driver == "canopen":
            if self._node is None or self._node.nmt.state != "OPERATIONAL":
                return []
            res = self._res_mdeg / 1000.0
            p = _clamp(round(pitch / res), -32768, 32767)
            r = _clamp(round(roll / res), -32768, 32767)
            return [can.Message(arbitration_id=0x180 + self.cfg.node_id, is_extended_id=False,
                                data=struct.pack("<hh", p, r))]
        if self.driver == "j1939":
            def j(v: float) -> int:
                return _clamp(round((v + 64.0) / 0.002), 0, 0xFAFF)
            latency = _clamp(round(self.model_cfg.latency_s / 0.0005), 0, 250)
            fom = 0b11_11_00_00  # pitch ok, roll ok, pitch rate n/a, compensation n/a
            data = struct.pack("<HHHBB", j(pitch), j(roll), 0xFFFF, fom, latency)
            cid = J1939_PRIORITY << 26 | PGN_SSI << 8 | self.source_address
            return [can.Message(arbitration_id=cid, is_extended_id=True, data=data)]
        # nmea2000

        def n(v: float) -> int:
            raw = round(math.radians(v) / 1e-4)
            return raw if abs(raw) <= 31416 else 0x7FFE
        data = struct.pack("<BhhhB", k % 253, 0x7FFF, n(pitch), n(roll), 0xFF)
        cid = N2K_PRIORITY << 26 | PGN_ATTITUDE << 8 | self.source_address
        return [can.Message(arbitration_id=cid, is_extended_id=True, data=data)]

    def _garble_frame(self, msg: can.Message, how: str) -> can.Message | bytes:
        data = bytearray(msg.data)
        cid = msg.arbitration_id
        if how == "length":
            data = data[:-1]
        elif how == "range":
            if self.driver == "canopen":
                data[0:4] = struct.pack("<hh", 0x7FFF, 0x7FFF)
            elif self.driver == "j1939":
                data[0:4] = b"\xff\xff\xff\xff"
            else:
                data[3:7] = struct.pack("<hh", 0x7FFF, 0x7FFF)
        elif how == "id":
            if self.driver == "canopen":
                cid = 0x180 + (self.cfg.node_id % 127) + 1
            else:
                cid = (cid & ~0x03FFFF00) | ((cid + 0x100) & 0x03FFFF00)  # the next PGN
        out = can.Message(arbitration_id=cid, is_extended_id=msg.is_extended_id, data=bytes(data))
        if how == "line":
            assert self._adapter is not None
            line = bytearray(self._adapter.line_for(out) or b"")
            if line:
                line[1:2] = b"G"  # not a hex digit
            return bytes(line)
        if how == "bytes":
            assert self._adapter is not None
            return damage_bytes(self._adapter.line_for(out) or b"", self._rng)
        return out

    def _tick(self, k: int, t: float) -> None:
        """Produce the output for instant ``t`` and publish it."""
        self._line_end = t  # the serial line is free from the output instant on
        y = self.model.output(t, self._motion_fn)
        self.counts["samples"] += 1
        with self._lock:
            faults = dict(self._faults)
            stuck = faults.get("stuck")
            if stuck is not None:
                if stuck["value"] is None:
                    stuck["value"] = dict(y)
                y = stuck["value"]
            self._last_y = y  # the model's own new dict (or the stuck one): never changed
        if "silent" in faults:
            return
        garbled = faults.get("garbled")
        port = self._port
        assert port is not None
        if self.is_can:
            adapter = self._adapter
            assert adapter is not None
            if not adapter.forwarding:  # adapter closed or at another bitrate: nothing
                return
            for msg in self._frames(k, t, y):
                item: can.Message | bytes = msg
                bad = garbled is not None and self._rng.random() < garbled["fraction"]
                if bad:
                    item = self._garble_frame(msg, garbled["how"])  # type: ignore[index]
                # the adapter stamps a frame when it is complete on the bus: the instrument
                # sends it at its output instant (the simulator's own lateness is no bus time)
                t_bus = t + frame_bits(msg) / self.cfg.bitrate
                line = item if isinstance(item, bytes) else adapter.line_for(item, t_bus=t_bus)
                self._write(port, line, bad)
        else:
            line = nmea_talker.sentence(self.sentence, t + self._utc_offset, y["roll"], y["pitch"])
            bad = garbled is not None and self._rng.random() < garbled["fraction"]
            if bad:
                how = garbled["how"]  # type: ignore[index]
                line = (damage_bytes(line, self._rng) if how == "bytes"
                        else nmea_talker.garble(line, how, self._rng))
            self._write(port, line, bad)

    def _write(self, port: PtyPort, line: bytes | None, garbled: bool) -> None:
        if not line:
            return
        if self.channel_name is None:
            # a pty has no byte time: the line is handed over when its last byte would be in
            # at the serial line's rate, as the in-process link has it (wire_delay_s)
            self._line_end += len(line) * 10.0 / self.cfg.baudrate
            wait = self._line_end - self.clock.monotonic()
            if wait > 0:
                self.clock.sleep(wait)
        if port.write(line):
            self.counts["sent"] += 1
            self.counts["garbled"] += garbled
            self._wire_bytes += len(line)
        else:
            self.counts["overflow"] += 1

    def _true(self, t: float) -> dict[str, float]:
        a = self.motion.true_angles(t)
        return self._mounted({ax: float(a.get(ax, 0.0)) for ax in AXES})

    def _true_many(self, ts: Any) -> dict[str, Any]:
        """``_true`` at each of ``ts`` in one call (a motion with ``true_angles_many``)."""
        a = self.motion.true_angles_many(ts)  # type: ignore[attr-defined]
        if not _AXES.issubset(a):
            zero = np.zeros(len(ts))
            a = {ax: a.get(ax, zero) for ax in AXES}
        return self._mounted(a)

    def _mounted(self, a: Any) -> Any:
        """The stand's true angles as this unit senses them on its own axes, mounted as
        ``sim.instrument.mounting`` says: swapped (its roll senses the stand's pitch), then
        each output's sign. A correct mount: ``a`` itself, untouched."""
        m = self._mounting
        if m is None:
            return a
        swap, signs = m
        src = {"roll": "pitch", "pitch": "roll"} if swap else {"roll": "roll", "pitch": "pitch"}
        return {ax: a[src[ax]] if signs[ax] == 1 else -a[src[ax]] for ax in AXES}

    # ------------------------------------------------------------------ the loop
    def _serve_host(self, port: PtyPort | _ChannelPort) -> None:
        data = port.read()
        if not data or self._adapter is None:
            return
        answers = self._adapter.feed(data)
        port.write(answers)
        out, self._bus_out[:] = list(self._bus_out), []
        for msg in out:  # the node's answers (SDO) reach the host after the adapter's acks
            line = self._adapter.line_for(msg)
            if line:
                port.write(line)

    def _run(self) -> None:
        port = self._port
        assert port is not None
        period = self.model.period_s
        t0 = self.clock.monotonic()
        k = 1
        self._ready.set()
        try:
            while not self._stop.is_set():
                if "drop" in self._faults:
                    port.close()
                    return
                fd = port.master_fd
                assert fd is not None
                next_t = t0 + k * period
                wait = min(max(0.0, next_t - self.clock.monotonic()), 0.05)
                rlist, wlist, _ = select.select([fd], [fd] if port.has_pending else [], [], wait)
                if rlist:
                    self._serve_host(port)
                if wlist:
                    port.flush()
                self._send_raw(port)
                now = self.clock.monotonic()
                if now - next_t > _MAX_CATCH_UP_S:  # stalled: do not burst, skip (counted)
                    k_now = int((now - t0) / period)
                    self.counts["skipped"] += k_now - k
                    k = k_now
                k = self._tick_due(k, t0, period, now)
        except Exception as e:  # a simulator bug must not pass for a silent instrument
            self._start_error = e
            with contextlib.suppress(Exception):
                port.close()
            raise

    def _run_channel(self) -> None:
        """The loop on an in-process link: wait for the host's bytes or the next output
        instant on the clock; every instant is served (the clock never leaves one behind)."""
        port = self._port
        assert isinstance(port, _ChannelPort)
        clock = self.clock
        period = self.model.period_s
        t0 = clock.monotonic()
        k = 1
        self._ready.set()
        try:
            while not self._stop.is_set():
                if "drop" in self._faults:
                    port.close()
                    return
                next_t = t0 + k * period
                port.wait(max(0.0, next_t - clock.monotonic()))
                self._serve_host(port)
                self._send_raw(port)
                k = self._tick_due(k, t0, period, clock.monotonic())
        except Exception as e:  # a simulator bug must not pass for a silent instrument
            self._start_error = e
            port.close()
            raise

    def _send_raw(self, port: PtyPort | _ChannelPort) -> None:
        """Write the bytes ``send_raw`` queued (lost, and counted ``overflow``, when the port
        cannot take them)."""
        while self._raw:
            if port.write(self._raw.popleft()):
                self.counts["raw"] += 1
            else:
                self.counts["overflow"] += 1

    def _tick_due(self, k: int, t0: float, period: float, now: float) -> int:
        """Produce every output instant ``t0 + k·period`` up to ``now``; the next ``k``."""
        next_t = t0 + k * period
        while now >= next_t:
            self._tick(k, next_t)
            k += 1
            next_t = t0 + k * period
        return k

    @property
    def device_endpoint(self) -> Any:
        """The simulator's end of its in-process link (transport channel), else None."""
        return self._port._ep if isinstance(self._port, _ChannelPort) else None

    @property
    def error(self) -> BaseException | None:
        """The exception that ended the simulator's thread, if any."""
        return self._start_error


class _Motion:
    """A motion function with a ``many`` form (the instrument model's sub-steps at once)."""

    def __init__(self, one: Any, many: Any) -> None:
        self._one = one
        self.many = many

    def __call__(self, t: float) -> dict[str, float]:
        return self._one(t)
