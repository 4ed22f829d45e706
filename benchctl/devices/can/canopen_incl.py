"""CANopen CiA 410 inclinometer through the ``canopen`` library and an EDS file.

``connect`` reads the identity by SDO (1008h name, 1009h hardware, 100Ah software versions,
1018h vendor-ID, product code, revision, serial number) and the resolution 6000h (units of
0.001°), reads TPDO1's mapping from the EDS, and switches the node to OPERATIONAL (NMT start).
Samples come from TPDO1 (COB-ID 0x180 + node id): 6010h slope long16 is pitch, 6020h slope
lateral16 is roll (INTEGER16; 6110h/6120h INTEGER32 if an EDS maps those), in degrees
``raw · resolution / 1000``. CiA 410 carries no counter or time.

Every frame is a sample, a counted bad frame or one of the node's service frames (counted in
``service_frames`` and handed to ``canopen``): an SDO answer (0x580 + id) or EMCY (0x80 + id) of
exactly 8 bytes, a heartbeat / node-guarding answer (0x700 + id) of 1 byte with an NMT state
(0 boot-up, 4 stopped, 5 operational, 127 pre-operational; bit 7 the toggle). Bad: a TPDO, SDO
answer, EMCY or heartbeat of another length is ``length``; a slope at the integer's extreme
(overflow marker) or beyond ±180°, or a heartbeat with no NMT state, is ``range``; a 29-bit
frame or any other id is ``id``; anything ``canopen`` raises on a frame is ``decode``.

The reader thread feeds ``canopen.Network.notify`` (the library's hook for a custom receive
loop) with the node's service frames, so the SDO client is the library's own. TPDO1 is decoded
from the mapping the library read from the EDS: where each slope is a whole, byte-aligned integer
(the CiA 410 objects are), by ``struct`` straight from the frame — the value the library's
``PdoMap`` would give, without its generic per-frame machinery; any other mapping through the
library's ``PdoMap`` (``notify``, then its callback).
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import can
import canopen
from canopen.objectdictionary.datatypes import INTEGER_TYPES

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig
from benchctl.devices.base import DeviceIdentity, InstrumentSample
from benchctl.devices.can.reader import (
    BAD_DECODE,
    BAD_ID,
    BAD_LENGTH,
    BAD_RANGE,
    DECODE_ERRORS,
    BadFrame,
    CanInstrument,
)
from benchctl.errors import ConfigError, DeviceTimeout, ProtocolError
from benchctl.textfile import MAX_YAML_BYTES, check_input_file

#: CiA 410 slope objects by axis: (16-bit, 32-bit)
SLOPE_OBJECTS = {"pitch": (0x6010, 0x6110), "roll": (0x6020, 0x6120)}
RESOLUTION_INDEX = 0x6000
MAX_ABS_DEG = 180.0
#: NMT states a heartbeat or node-guarding answer reports (its bit 7 is the guarding toggle)
NMT_STATES = frozenset({0x00, 0x04, 0x05, 0x7F})
#: CiA 301: SDO and EMCY frames always carry 8 bytes
SERVICE_DLC = 8


def _sdo_on_clock(sdo: Any, clock: Clock) -> None:
    """Make the library's SDO client wait for its answers on ``clock``.

    canopen 2.4's ``SdoClient`` keeps the answers in ``responses`` (a ``queue.Queue`` the
    reader thread fills through ``on_response``; ``read_response`` waits on it with
    ``RESPONSE_TIMEOUT``): it becomes the clock's queue. ``request_response`` replaces a
    non-empty queue by a new ``queue.Queue``; emptying ours first keeps it the clock's. Its
    other real-time calls stay: ``PAUSE_BEFORE_SEND`` (0 by default) and ``RETRY_DELAY``
    (after a failed send only) sleep on ``time``, and a block upload's retransmission
    (``_retransmit``, not used here: uploads are expedited or segmented) times out on
    ``time.time``."""
    responses = clock.queue()
    sdo.responses = responses
    original = sdo.request_response

    def request_response(request: Any) -> Any:
        while not sdo.responses.empty():  # stale answers: dropped, as the library does
            sdo.responses.get_nowait()
        sdo.responses = responses
        return original(request)

    sdo.request_response = request_response


def _slope_deg(raw: int, markers: tuple[int, int], resolution_deg: float) -> float:
    """A slope's raw value in degrees; ``BadFrame(range)`` at an overflow marker (the integer's
    extremes) or beyond ±``MAX_ABS_DEG``."""
    if raw in markers:
        raise BadFrame(BAD_RANGE)
    deg = raw * resolution_deg
    if abs(deg) > MAX_ABS_DEG:
        raise BadFrame(BAD_RANGE)
    return deg


class CanopenInclinometer(CanInstrument):
    """A CiA 410 inclinometer on CANopen; implements ``AngleSensor``."""

    protocol = "CANopen CiA 410"

    def __init__(
        self,
        bus: can.BusABC,
        cfg: InstrumentConfig,
        *,
        can_log_path: Path | None = None,
        owns_bus: bool = True,
        clock: Clock = REAL,
    ) -> None:
        if cfg.eds is None:
            raise ConfigError("instrument driver canopen: needs eds (an EDS file in drivers/)")
        check_input_file(cfg.eds, "EDS file", ConfigError, MAX_YAML_BYTES)  # canopen reads it
        self._net = canopen.Network(bus)  # never .connect(): our reader feeds notify()
        try:
            self._node = self._net.add_node(cfg.node_id, str(cfg.eds))
        except (OSError, KeyError, ValueError) as e:
            raise ConfigError(f"{cfg.eds}: cannot load EDS: {e}") from e
        # each SDO answer within connect_timeout_s, as the config says (it was capped at 1 s:
        # a segmented upload of 1008h then failed a plan's step on a loaded host)
        self._node.sdo.RESPONSE_TIMEOUT = cfg.connect_timeout_s
        _sdo_on_clock(self._node.sdo, clock)
        self._tpdo = self._node.tpdo[1]
        try:
            self._node.tpdo.read(from_od=True)
        except (KeyError, ValueError) as e:
            raise ConfigError(f"{cfg.eds}: cannot read the TPDO1 mapping: {e}") from e
        self._slopes: dict[str, Any] = {}
        for axis in cfg.outputs:
            var = next((v for v in self._tpdo if v.index in SLOPE_OBJECTS[axis]), None)
            if var is None:
                raise ConfigError(
                    f"{cfg.eds}: TPDO1 maps no slope for axis {axis} "
                    f"(expected {SLOPE_OBJECTS[axis][0]:04X}h or {SLOPE_OBJECTS[axis][1]:04X}h)"
                )
            self._slopes[axis] = var
        self._tpdo_len = (self._tpdo.length + 7) // 8
        n = cfg.node_id
        self._tpdo_id = self._tpdo.cob_id
        self._slope_fields = self._struct_slopes()
        self._known_ids = {0x580 + n, 0x80 + n, 0x700 + n}
        self.resolution_deg = self._od_resolution() / 1000.0
        self._rx_t = 0.0
        self._rx_adapter_s: float | None = None
        self._last: InstrumentSample | None = None
        self._tpdo.add_callback(self._on_tpdo)
        super().__init__(bus, cfg, can_log_path=can_log_path, owns_bus=owns_bus, clock=clock)

    def _struct_slopes(self) -> list[tuple[str, Any, int, tuple[int, int]]] | None:
        """Each slope of TPDO1 as (axis, its ``struct`` unpack_from, byte offset, overflow
        markers) when ``struct`` reads them as the library's ``PdoMap`` does: the map receives
        TPDO1 (enabled, subscribed) and every slope is an integer the library unpacks with a
        ``struct`` format, mapped whole at a byte boundary inside the frame. None otherwise:
        the frames then go through the library (``_on_tpdo``)."""
        if self._tpdo.on_message not in self._net.subscribers.get(self._tpdo_id, ()):
            return None
        fields = []
        for axis, var in self._slopes.items():
            od = var.od
            fmt = od.STRUCT_TYPES.get(od.data_type)
            if (od.data_type not in INTEGER_TYPES or not isinstance(fmt, struct.Struct)
                    or var.offset is None or var.offset % 8 or var.length != 8 * fmt.size
                    or var.offset // 8 + fmt.size > self._tpdo_len):
                return None
            bits = var.length
            fields.append((axis, fmt.unpack_from, var.offset // 8,
                           (2 ** (bits - 1) - 1, -(2 ** (bits - 1)))))
        return fields

    def _od_resolution(self) -> int:
        od = self._node.object_dictionary
        default = getattr(od[RESOLUTION_INDEX], "default", None) if RESOLUTION_INDEX in od else None
        return int(default or 10)

    # ------------------------------------------------------------------ identification
    def _upload(self, index: int, sub: int | None = None, *, required: bool = True) -> Any:
        try:
            obj = self._node.sdo[index] if sub is None else self._node.sdo[index][sub]
            return obj.raw
        except canopen.SdoAbortedError as e:
            if not required:
                return None
            raise ProtocolError(
                f"instrument CANopen node {self.cfg.node_id} on {self._where}: SDO upload "
                f"{index:04X}h{'' if sub is None else f' sub {sub}'} aborted: {e}"
            ) from e
        except canopen.SdoCommunicationError as e:
            if self._fault is not None:
                raise self._fault from e
            raise DeviceTimeout(
                f"instrument CANopen node {self.cfg.node_id} on {self._where}: no SDO answer "
                f"for {index:04X}h{'' if sub is None else f' sub {sub}'}: {e}"
            ) from e

    def _identify(self) -> DeviceIdentity:
        name = self._upload(0x1008, required=False) or ""
        hw = self._upload(0x1009, required=False) or ""
        sw = self._upload(0x100A, required=False) or ""
        vendor = int(self._upload(0x1018, 1))
        product = int(self._upload(0x1018, 2))
        revision = int(self._upload(0x1018, 3))
        serial = int(self._upload(0x1018, 4))
        resolution = self._upload(RESOLUTION_INDEX, required=False)
        if resolution is not None:
            if int(resolution) <= 0:
                raise ProtocolError(
                    f"instrument CANopen node {self.cfg.node_id}: resolution 6000h = "
                    f"{resolution}, expected a positive number of 0.001° units"
                )
            self.resolution_deg = int(resolution) / 1000.0
        self._node.nmt.state = "OPERATIONAL"
        return DeviceIdentity(
            vendor=f"CiA vendor-ID 0x{vendor:08X}",
            model=str(name),
            serial=str(serial),
            firmware=str(sw),
            protocol=self.protocol,
            extra={
                "hardware": str(hw),
                "product_code": f"0x{product:08X}",
                "revision": f"0x{revision:08X}",
                "node_id": str(self.cfg.node_id),
                "resolution_deg": repr(self.resolution_deg),
            },
        )

    # ------------------------------------------------------------------ decoding
    def _notify(self, cid: int, data: bytes, timestamp: float) -> None:
        """Hand a frame to ``canopen``; what it raises on a malformed one is ``decode``."""
        try:
            self._net.notify(cid, bytearray(data), timestamp)
        except BadFrame:  # from our own TPDO callback
            raise
        except DECODE_ERRORS:
            raise BadFrame(BAD_DECODE) from None

    def decode_tpdo(self, data: bytes, t_host: float,
                    adapter_time_s: float | None = None) -> InstrumentSample:
        """Decode a TPDO1 payload (the sample's ``adapter_time_s``: the frame's adapter time, if
        known); ``BadFrame`` for a wrong length or an out-of-range slope."""
        if len(data) != self._tpdo_len:
            raise BadFrame(BAD_LENGTH)
        fields = self._slope_fields
        if fields is not None:  # struct reads the slopes as the library would
            resolution = self.resolution_deg
            angles: dict[str, float] = {}
            for axis, unpack_from, offset, markers in fields:
                angles[axis] = _slope_deg(unpack_from(data, offset)[0], markers, resolution)
            return InstrumentSample(t_host=t_host, angle_deg=angles,
                                    adapter_time_s=adapter_time_s)
        self._rx_t = t_host
        self._rx_adapter_s = adapter_time_s
        self._last = None
        self._notify(self._tpdo_id, data, t_host)
        if self._last is None:  # the library did not call back: not our TPDO's map
            raise BadFrame(BAD_ID)
        return self._last

    def decode_service(self, cid: int, data: bytes, timestamp: float) -> None:
        """Check a service frame of the node (SDO answer, EMCY, heartbeat) and hand it to
        ``canopen``; ``BadFrame`` for another id or a malformed frame."""
        if cid not in self._known_ids:
            raise BadFrame(BAD_ID)
        if cid == 0x700 + self.cfg.node_id:
            if len(data) != 1:
                raise BadFrame(BAD_LENGTH)
            if data[0] & 0x7F not in NMT_STATES:
                raise BadFrame(BAD_RANGE)
        elif len(data) != SERVICE_DLC:
            raise BadFrame(BAD_LENGTH)
        self._notify(cid, data, timestamp)
        self.service_frames += 1

    def _on_tpdo(self, pdo_map: Any) -> None:
        angles: dict[str, float] = {}
        for axis, var in self._slopes.items():
            bits = var.length
            angles[axis] = _slope_deg(int(var.raw), (2 ** (bits - 1) - 1, -(2 ** (bits - 1))),
                                      self.resolution_deg)
        self._last = InstrumentSample(t_host=self._rx_t, angle_deg=angles,
                                      adapter_time_s=self._rx_adapter_s)

    def _handle(self, msg: can.Message, t_host: float) -> None:
        cid = msg.arbitration_id
        if msg.is_extended_id:
            raise BadFrame(BAD_ID)
        if cid == self._tpdo_id:
            self._emit(self.decode_tpdo(bytes(msg.data), t_host, self._adapter_s))
        else:
            self.decode_service(cid, bytes(msg.data), msg.timestamp)

    def _close_protocol(self) -> None:
        self._tpdo.callbacks.clear()
