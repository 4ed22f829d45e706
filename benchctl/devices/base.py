"""Capability interfaces the run layer depends on, never a protocol.

A driver speaks one protocol over a transport handed to it. The run layer sees only these
small interfaces (in the spirit of bluesky's ``Movable``/``Readable``): ``Stand`` and
``AngleSensor``. Every time here is the host's monotonic clock, seconds: the ``monotonic()`` of
the clock the driver was handed (``benchctl.clock``; the operating system's by default).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from benchctl.harmonics import HarmonicTable

AXES: tuple[str, ...] = ("roll", "pitch")


@dataclass(frozen=True)
class DeviceIdentity:
    """What a device says it is: recorded in every recording's metadata."""

    vendor: str
    model: str
    serial: str = ""
    firmware: str = ""
    protocol: str = ""
    extra: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class StandStatus:
    """Decoded status word of the stand."""

    ready: bool
    enabled: bool
    moving: bool
    fault: bool
    estop: bool
    limit: bool
    table_running: bool = False
    trajectory_running: bool = False
    fault_code: int = 0
    heartbeat: int = 0


@dataclass(frozen=True)
class TrajectoryStatus:
    """A buffered stand's trajectory queue, as read with every sample.

    ``level`` points queued and not yet played, ``next_index`` the index the next push must
    start with, ``played`` the index being played, ``underruns`` times the queue ran dry while
    the stand moved (it then stopped itself within its limits).
    """

    level: int
    next_index: int
    played: int
    underruns: int


@dataclass(frozen=True)
class StandSample:
    """One read of the stand's measured state.

    ``t_host`` is when the stand took the state, on the monotonic clock: the midpoint of request
    and reply (Modbus TCP) or the end of the request on the wire (Modbus RTU, from the frame's
    byte times); ``rtt_s`` the round trip. Angles are the encoder's (the reference x(t)), never
    the commanded ones.
    """

    t_host: float
    rtt_s: float
    angle_deg: dict[str, float]
    rate_deg_s: dict[str, float]
    setpoint_deg: dict[str, float]
    status: StandStatus
    trajectory: TrajectoryStatus | None = None  # stands with a trajectory queue
    #: the stand's own clock when it took the state (s, wrapping), where its map offers one
    t_stand: float | None = None
    #: (earliest, latest) host time the stand can have taken the state: TCP request sent to
    #: reply received; RTU the end of the request on the wire to the start of the reply
    t_window: tuple[float, float] | None = None


@dataclass(frozen=True)
class InstrumentSample:
    """One decoded instrument output.

    ``t_host`` is the receipt time on the monotonic clock. ``device_time_s`` and ``counter`` are
    the device's own time or counter where the protocol carries one (else None);
    ``adapter_time_s`` the CAN adapter's timestamp of the frame (slcan ``Z1``: its own clock, in
    seconds, unwrapped; None without one). Angles for the axes the instrument reports
    (``roll``, ``pitch``).
    """

    t_host: float
    angle_deg: dict[str, float]
    device_time_s: float | None = None
    counter: int | None = None
    adapter_time_s: float | None = None


@dataclass
class FrameStats:
    """Counts of frames a reader saw. Bad frames are counted and skipped, never passed as data."""

    good: int = 0
    bad: dict[str, int] = field(
        default_factory=dict
    )  # reason -> count (checksum, length, range, id)

    def count_bad(self, reason: str) -> None:
        self.bad[reason] = self.bad.get(reason, 0) + 1

    @property
    def bad_total(self) -> int:
        return sum(self.bad.values())


@dataclass(frozen=True)
class StandLimitsView:
    """The limits a driver enforces at the point of sending (per axis)."""

    angle_deg: float
    rate_deg_s: float
    accel_deg_s2: float


@runtime_checkable
class Stand(Protocol):
    """A two-axis roll/pitch stand. Public methods hold the safety checks; errors raise."""

    axes: tuple[str, ...]
    limits: StandLimitsView
    # listeners the recorder sets: every feedback block decoded, every setpoint sent
    # (t_send, angles, t_slot); a listener's failure never stops the driver
    on_sample: Callable[[StandSample], None] | None
    on_setpoint: Callable[[float, dict[str, float], float | None], None] | None

    def connect(self) -> DeviceIdentity: ...
    def close(self) -> None: ...
    def read_status(self) -> StandStatus: ...
    def read_sample(self) -> StandSample: ...
    def enable(self) -> None: ...
    def disable(self) -> None: ...
    def heartbeat(self) -> None: ...
    def send_setpoint(  # returns the send time
        self, angle_deg: dict[str, float], *, t_slot: float | None = None
    ) -> float: ...
    def send_setpoint_and_read(
        self, angle_deg: dict[str, float], *, t_slot: float | None = None
    ) -> tuple[float, StandSample]: ...
    def upload_table(self, tables: dict[str, HarmonicTable]) -> None: ...
    def start_table(self) -> float: ...  # returns the host time the stand was told to start
    def stop_table(self) -> None: ...
    def go_to_zero(self, timeout_s: float = 30.0) -> None: ...
    def ramp_to_zero(self, timeout_s: float = 30.0) -> None: ...
    def stop(self) -> None: ...
    def estop(self) -> None: ...
    def reset_fault(self) -> None: ...


@runtime_checkable
class TrajectoryStand(Stand, Protocol):
    """A stand with a trajectory queue (``stand.mode: buffered``): the host pushes points
    ahead, one per period, and the stand plays them on its own clock."""

    @property
    def trajectory_limits(self) -> tuple[int, int]:  # (the queue's capacity, points per push)
        ...

    def begin_trajectory(self) -> None: ...
    def push_points(  # the feedback block read in the same transaction with ``read``
        self, first_index: int, points: Mapping[str, NDArray[np.float64]], *, read: bool = True
    ) -> StandSample | None: ...
    def start_trajectory(self) -> float: ...  # returns the host time the stand was told to start


SampleCallback = Callable[[InstrumentSample], None]
ErrorCallback = Callable[[BaseException], None]


@runtime_checkable
class AngleSensor(Protocol):
    """An instrument under test that streams angles.

    ``start`` begins delivering samples to ``on_sample`` from a background reader; a fault in
    that reader is passed to ``on_error`` at once (it never dies quietly).
    """

    axes: tuple[str, ...]
    stats: FrameStats

    def connect(self) -> DeviceIdentity: ...
    def start(self, on_sample: SampleCallback, on_error: ErrorCallback) -> None: ...
    def stop(self) -> None: ...
    def close(self) -> None: ...
