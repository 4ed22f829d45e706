"""The simulated stand's one entry point for request bytes: Modbus frames in, reply frames out.

:class:`StandWire` takes the bytes a master sent — MBAP (TCP) or RTU frames, whole, split or
several at once — frames them with pymodbus's framer and the stand's own request decoder (which
refuses what the specification says to refuse), executes each request on the stand's registers
through the same ``action`` the pymodbus server calls, and returns the reply frames. The stand's
communication faults act here as on the server: a stalled or dropped stand acts on nothing and
answers nothing; requests for another unit id are refused (TCP, exception 0x0B) or ignored
(RTU; a broadcast write is acted on, never answered).

:func:`serve_endpoint` is a device's server loop over an in-process link: it reads each request
as it arrives whole (an RTU slave sees a frame end by the line's silence) and writes the reply.
"""

from __future__ import annotations

import struct
from collections.abc import Coroutine
from typing import Any, Literal

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException
from pymodbus.framer import FramerRTU, FramerSocket
from pymodbus.pdu import ExceptionResponse
from pymodbus.pdu.register_message import (
    ReadHoldingRegistersRequest,
    ReadWriteMultipleRegistersRequest,
)
from pymodbus.simulator import SimDevice
from pymodbus.simulator.simcore import SimCore
from pymodbus.simulator.simutils import DataType, SimUtils

from benchctl.channels import Endpoint
from benchctl.clock import EventLike
from benchctl.sim.stand_firmware import StandFirmware
from benchctl.sim.stand_registers import MapDecoder, register_addresses


def run_sync(coro: Coroutine[Any, Any, Any]) -> Any:
    """Run a coroutine that never suspends (the register store's) to its result."""
    try:
        coro.send(None)
    except StopIteration as done:
        return done.value
    coro.close()
    raise RuntimeError("the simulated stand's register store suspended (it never should)")


class StandWire:
    """Request bytes → reply bytes for one connection (or one serial line) of a stand."""

    def __init__(self, stand: StandFirmware, framing: Literal["tcp", "rtu"]) -> None:
        self.stand = stand
        self.framing = framing
        simdata = stand.simdata()
        self._core = SimCore(SimDevice(stand.device_id, simdata=simdata, action=stand.action))
        decoder = MapDecoder(stand.map, register_addresses(simdata))
        self._framer = FramerSocket(decoder) if framing == "tcp" else FramerRTU(decoder)
        self._buf = b""
        # the register model's memory (SimRuntime's one shared block: start address, size,
        # registers, flags), which the fast path below reads and writes as pymodbus does
        self._fc23 = 23 in decoder.function_codes
        self._max_read = min(decoder.max_read, ReadHoldingRegistersRequest.MAX_COUNT)
        self._max_write = min(decoder.max_write, ReadWriteMultipleRegistersRequest.MAX_WRITE_COUNT)
        start, size, regs, flags = self._core.devices[stand.device_id].block["x"]
        self._start, self._regs = start, regs
        # per register offset: how many registers from it on may be read (not INVALID), and
        # written (neither INVALID nor read-only): SimRuntime's per-register checks at once
        self._readable = _runs(flags, size, readonly_too=False)
        self._writable = _runs(flags, size, readonly_too=True)

    def feed(self, data: bytes) -> bytes:
        """The reply bytes to ``data`` (empty when nothing is answered)."""
        stand = self.stand
        if not self._buf:
            fast = self._fast(data)
            if fast is not None:
                return fast
        self._buf += stand.trace(False, data)
        out = bytearray()
        while self._buf:
            try:
                used, pdu = self._framer.handleFrame(self._buf, 0, 0)
            except ModbusIOException as exc:  # as the pymodbus server: ILLEGAL FUNCTION
                self._buf = b""
                rsp = ExceptionResponse(exc.fcode or 0, ExcCodes.ILLEGAL_FUNCTION)
                rsp.dev_id, rsp.transaction_id = exc.dev_id or 0, exc.transaction_id or 0
                out += stand.trace(True, self._framer.buildFrame(rsp))
                break
            self._buf = self._buf[used:]
            if pdu is None:
                break
            req = stand.trace_pdu(False, pdu)
            if req is None:
                continue  # RTU: another unit's frame, or a broadcast read: silence
            if self.framing == "rtu" and req.dev_id == 0:  # a broadcast write: acted on
                for dev_id in self._core.device_ids():
                    run_sync(req.datastore_update(self._core, dev_id))  # type: ignore[arg-type]
                continue
            rsp = run_sync(
                req.datastore_update(self._core, stand.device_id)  # type: ignore[arg-type]
            )
            rsp.transaction_id, rsp.dev_id = req.transaction_id, req.dev_id
            out += stand.trace(True, self._framer.buildFrame(rsp))
        return bytes(out)


    def _fast(self, data: bytes) -> bytes | None:
        """The reply to ``data`` when it is exactly one well-formed read (FC3) or read/write
        (FC23) for this stand within its registers — what nearly every request of a run is —
        with no pymodbus objects on the way; None for anything else (nothing done: the general
        path then takes it). The same checks in the same order, the same action calls and the
        same reply bytes as the general path (framer, ``MapDecoder``, the PDU's
        ``datastore_update``, ``SimRuntime``)."""
        stand = self.stand
        n = len(data)
        if self.framing == "tcp":
            if n < 9 or data[2] or data[3] or ((data[4] << 8) | data[5]) + 6 != n:
                return None
            dev_id, pdu = data[6], data[7:]
        else:
            if n < 8 or FramerRTU.compute_CRC(data[:-2]) != (data[-2] << 8) | data[-1]:
                return None
            dev_id, pdu = data[0], data[1:-2]
        if dev_id != stand.device_id:
            return None
        fc, m = pdu[0], len(pdu)
        if fc == 3:
            if m != 5:
                return None
            address, count = _U16X2.unpack_from(pdu, 1)
            if not 1 <= count <= self._max_read:
                return None
            w_addr, w_values = 0, None
        elif fc == 23 and self._fc23:
            if m < 10:
                return None
            address, count, w_addr, w_count, nbytes = _FC23.unpack_from(pdu, 1)
            if not (1 <= count <= self._max_read and 1 <= w_count <= self._max_write
                    and nbytes == 2 * w_count == m - 10):
                return None
            w_values = list(struct.unpack_from(f">{w_count}H", pdu, 10))
        else:
            return None
        if self.framing == "rtu" and n != (8 if fc == 3 else pdu[9] + 13):
            return None  # not exactly the one frame the RTU framer would find
        start, regs = self._start, self._regs
        off = address - start
        if off < 0 or off >= len(self._readable) or self._readable[off] < count:
            return None  # ILLEGAL ADDRESS: the general path answers it
        if w_values is not None:
            w_off = w_addr - start
            if w_off < 0 or w_off >= len(self._writable) or self._writable[w_off] < len(w_values):
                return None
            code = stand.act(fc, start, w_addr, len(w_values), regs, w_values)
            if not code:
                regs[w_off : w_off + len(w_values)] = w_values
        else:
            code = None
        if not code:
            code = stand.act(fc, start, address, count, regs, None)
        if code:
            reply = bytes((fc | 0x80, int(code)))
        else:
            reply = bytes((fc, 2 * count)) + struct.pack(f">{count}H", *regs[off : off + count])
        if self.framing == "tcp":
            frame = data[:4] + (len(reply) + 1).to_bytes(2, "big") + bytes((dev_id,)) + reply
        else:
            frame = bytes((dev_id,)) + reply
            frame += FramerRTU.compute_CRC(frame).to_bytes(2, "big")
        return stand.trace(True, frame)


_U16X2 = struct.Struct(">HH")
_FC23 = struct.Struct(">HHHHB")


def _runs(flags: list[int], size: int, *, readonly_too: bool) -> list[int]:
    """For each register offset, how many registers from it on pass SimRuntime's check (not
    INVALID; for a write, not read-only either)."""
    out = [0] * (size + 1)
    for i in range(size - 1, -1, -1):
        f = flags[i]
        bad = f & SimUtils.RunTimeFlag_TYPE == DataType.INVALID or (
            readonly_too and f & SimUtils.RunTimeFlag_READONLY)
        out[i] = 0 if bad else out[i + 1] + 1
    return out[:size]


def serve_on_arrival(wire: StandWire, ep: Endpoint, stop: EventLike, name: str) -> None:
    """:func:`serve_endpoint` without its thread, on a virtual clock: the clock runs the loop's
    body at each request's arrival (``Endpoint.serve``) — where the thread, waiting in its
    read, would have been woken — so the stand answers the same bytes at the same instants in
    the same order, without two hand-overs of the baton per request."""
    dead = False

    def handle() -> None:
        nonlocal dead
        if dead:
            return
        try:
            while not stop.is_set():  # serve_endpoint's loop, up to its next wait
                data = ep.read(1 << 16, 0.0)
                if not data:
                    return
                reply = wire.feed(data)
                if reply and not ep.closed:
                    ep.write(reply)
        except BaseException:
            dead = True  # as the thread would have ended: no more answers
            raise

    ep.serve(handle, name)


def serve_endpoint(wire: StandWire, ep: Endpoint, stop: EventLike) -> None:
    """A device's server loop on an in-process link: each request in (a write arrives whole,
    as a frame ends with the line's silence), its reply out."""
    while not stop.is_set():
        data = ep.read(1 << 16)
        if not data:
            if ep.closed:
                return
            continue
        reply = wire.feed(data)
        if reply and not ep.closed:
            ep.write(reply)
