"""A reply the client had given up on arrives late (a loaded machine, a slow line).

- the link drops a reply to another function code than its request's (a late reply to an
  earlier request) and sends the request once more; twice in a row is a ``ProtocolError``;
- the simulated stand acknowledges a trajectory push sent again (it reaches back into the
  points already queued): only its new points are appended, none twice, none refused — so the
  client's own retry of a push whose reply was late is harmless.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from stand_rig import SLOW, simulated

from benchctl.clock.virtual import VirtualClock
from benchctl.devices.modbus.link import ModbusLink
from benchctl.errors import ProtocolError


class _Reply:
    def __init__(self, fc: int, registers: list[int] | None = None) -> None:
        self.function_code = fc
        self.registers = registers or []

    def isError(self) -> bool:  # pymodbus's name
        return False


class _Client:
    """A pymodbus client stand-in answering from a script of replies."""

    def __init__(self, replies: list[_Reply]) -> None:
        self.replies = replies
        self.sent = 0

    def read_holding_registers(self, address: int, count: int, device_id: int) -> Any:
        self.sent += 1
        return self.replies.pop(0)


def _link(replies: list[_Reply]) -> tuple[ModbusLink, _Client]:
    client = _Client(replies)
    return ModbusLink(lambda trace: client, device_id=1, endpoint="fake", timeout_s=1.0), client


def test_a_late_reply_is_dropped_and_the_request_sent_again() -> None:
    link, client = _link([_Reply(23, [9] * 26), _Reply(3, [1, 2])])
    assert link.read_registers(200, 2) == [1, 2]
    assert client.sent == 2
    link, client = _link([_Reply(23), _Reply(6)])
    with pytest.raises(ProtocolError, match="function code 6 for a request of function code 3"):
        link.read_registers(200, 2)


def test_a_push_sent_again_is_acknowledged_and_not_applied_twice(vclock: VirtualClock) -> None:
    """On simulated time: the stand over an in-process link carrying Modbus TCP."""
    with simulated(SLOW, "tcp", vclock) as (_sim, stand):
        stand.enable()
        stand.begin_trajectory()
        sent: list[tuple[Any, ...]] = []
        rw = stand.link.read_write_registers

        def spy(*a: Any) -> list[int]:
            sent.append(a)
            return rw(*a)

        stand.link.read_write_registers = spy  # type: ignore[method-assign]
        stand.push_points(0, {"roll": np.zeros(10)}, read=True)
        again = rw(*sent[0])  # the same push once more, as a client's retry would send it
        s = stand.push_points(10, {"roll": np.zeros(5)}, read=True)
        assert s is not None and s.trajectory is not None
        assert s.trajectory.next_index == 15  # 10 + 5: the repeated 10 not appended again
        assert len(again) == sent[0][1]  # acknowledged: the feedback block read back
