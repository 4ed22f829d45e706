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

from collections.abc import Coroutine
from typing import TYPE_CHECKING, Any, Literal

from pymodbus.constants import ExcCodes
from pymodbus.exceptions import ModbusIOException
from pymodbus.framer import FramerRTU, FramerSocket
from pymodbus.pdu import ExceptionResponse
from pymodbus.simulator import SimDevice
from pymodbus.simulator.simcore import SimCore

from benchctl.channels import Endpoint
from benchctl.clock import EventLike

if TYPE_CHECKING:
    from benchctl.sim.stand import SimStand


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

    def __init__(self, stand: SimStand, framing: Literal["tcp", "rtu"]) -> None:
        from benchctl.sim.stand import _MapDecoder, _register_addresses

        self.stand = stand
        self.framing = framing
        simdata = stand._simdata()
        self._core = SimCore(SimDevice(stand.device_id, simdata=simdata, action=stand._action))
        decoder = _MapDecoder(stand.map, _register_addresses(simdata))
        self._framer = FramerSocket(decoder) if framing == "tcp" else FramerRTU(decoder)
        self._buf = b""

    def feed(self, data: bytes) -> bytes:
        """The reply bytes to ``data`` (empty when nothing is answered)."""
        stand = self.stand
        self._buf += stand._trace(False, data)
        out = bytearray()
        while self._buf:
            try:
                used, pdu = self._framer.handleFrame(self._buf, 0, 0)
            except ModbusIOException as exc:  # as the pymodbus server: ILLEGAL FUNCTION
                self._buf = b""
                rsp = ExceptionResponse(exc.fcode or 0, ExcCodes.ILLEGAL_FUNCTION)
                rsp.dev_id, rsp.transaction_id = exc.dev_id or 0, exc.transaction_id or 0
                out += stand._trace(True, self._framer.buildFrame(rsp))
                break
            self._buf = self._buf[used:]
            if pdu is None:
                break
            req = stand._trace_pdu(False, pdu)
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
            out += stand._trace(True, self._framer.buildFrame(rsp))
        return bytes(out)


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
