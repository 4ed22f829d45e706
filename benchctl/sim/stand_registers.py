"""The simulated stand's register model for pymodbus: its register blocks, and the request
decoder that refuses what lies outside the register map as the Modbus specification says."""

from __future__ import annotations

from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.simulator import DataType, SimData

from benchctl.devices.modbus.regmap import RegisterMap


def register_blocks(words: dict[int, int], *, readonly: bool) -> list[SimData]:
    """Contiguous SimData register blocks holding ``words`` (address → value)."""
    out: list[SimData] = []
    addrs = sorted(words)
    i = 0
    while i < len(addrs):
        j = i
        while j + 1 < len(addrs) and addrs[j + 1] == addrs[j] + 1:
            j += 1
        vals = [words[a] for a in addrs[i : j + 1]]
        out.append(SimData(addrs[i], values=vals, datatype=DataType.REGISTERS, readonly=readonly))
        i = j + 1
    return out


def register_addresses(simdata: list[SimData]) -> frozenset[int]:
    """Every register address the SimData blocks give the stand (blocks marked invalid aside)."""
    return frozenset(
        d.address + i
        for d in simdata
        if d.datatype != DataType.INVALID
        for i in range(len(d.build_registers(False)) * d.count)
    )


class Refused(ModbusPDU):
    """A request the stand refuses: handling it yields the exception response (FC | 0x80, code)."""

    def __init__(self, function_code: int, code: ExcCodes) -> None:
        super().__init__()
        self.function_code = function_code
        self.code = code

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        return ExceptionResponse(self.function_code, self.code)


class WholeFrame(ModbusPDU):
    """RTU framing of a function code pymodbus has no layout for: the CRC-checked bytes so far."""

    @classmethod
    def calculateRtuFrameSize(cls, data: bytes) -> int:
        return len(data)


class MapDecoder(DecodePDU):
    """The simulated stand's request decoder: it refuses requests the way the specification says.

    pymodbus alone decodes every function code it knows (coils, input registers, diagnostics…)
    and answers a request it cannot decode with function byte 0x80 whatever the request's. This
    decoder replaces the server's (each connection's framer decodes with ``server.decoder``) and
    checks a request in the order of the specification's state diagrams (Modbus Application
    Protocol V1.1b3, 6.x); a refused request becomes a :class:`Refused`, answered ``FC | 0x80``:

    1. a function code outside the register map — holding registers: 3, 6, 16, and 23 when the
       map says ``read_write_multiple`` — → 01 ILLEGAL FUNCTION (serial-only 7, 8, 11, 12, 17 too);
    2. a quantity or byte count out of range — FC3 1..``max_read_registers``, FC16
       1..``max_write_registers`` with byte count 2·N, FC23 both (write ≤ 121) — or a PDU of
       the wrong length → 03 ILLEGAL DATA VALUE;
    3. addresses outside the map are the SimDevice model's → 02 ILLEGAL DATA ADDRESS — but
       for FC23 the read span is checked here: pymodbus would write first and then refuse the
       read, where the specification checks both spans before anything is written.
    """

    def __init__(self, m: RegisterMap, addresses: frozenset[int]) -> None:
        super().__init__(True)
        self.addresses = addresses  # every register the stand has
        self.function_codes = {3, 6, 16} | ({23} if m.read_write_multiple else set())
        self.max_read = m.max_read
        self.max_write = m.max_write

    def lookupPduClass(self, data: bytes) -> type[ModbusPDU] | None:
        # RTU: pymodbus finds where a frame ends from its function code's layout (a real slave
        # from the 3.5-character silence, which a pty does not carry). For a function code it
        # has no layout for, the bytes received so far are the frame if they end in a valid CRC
        # — so such a request is answered too; otherwise pymodbus hunts on, as it always did.
        cls = super().lookupPduClass(data)
        if (
            cls is None
            and len(data) >= 4
            and FramerRTU.check_CRC(data[:-2], int.from_bytes(data[-2:], "big"))
        ):
            return WholeFrame
        return cls

    def decode(self, frame: bytes) -> ModbusPDU | None:
        fc = frame[0]
        if fc not in self.function_codes:
            return Refused(fc, ExcCodes.ILLEGAL_FUNCTION)
        if not self._quantity_ok(fc, frame):
            return Refused(fc, ExcCodes.ILLEGAL_VALUE)
        if fc == 23:
            start, count = int.from_bytes(frame[1:3], "big"), int.from_bytes(frame[3:5], "big")
            if not all(a in self.addresses for a in range(start, start + count)):
                return Refused(fc, ExcCodes.ILLEGAL_ADDRESS)
        pdu = super().decode(frame)
        return pdu if pdu is not None else Refused(fc, ExcCodes.ILLEGAL_VALUE)

    def _quantity_ok(self, fc: int, pdu: bytes) -> bool:
        n = len(pdu)

        def u16(i: int) -> int:
            return int.from_bytes(pdu[i : i + 2], "big")

        if fc == 3:
            return n == 5 and 1 <= u16(3) <= self.max_read
        if fc == 6:
            return n == 5
        if fc == 16:
            return n >= 6 and 1 <= u16(3) <= self.max_write and pdu[5] == 2 * u16(3) == n - 6
        return (  # 23: read address, read count, write address, write count, byte count, values
            n >= 10
            and 1 <= u16(3) <= self.max_read
            and 1 <= u16(7) <= min(self.max_write, 121)
            and pdu[9] == 2 * u16(7) == n - 10
        )
