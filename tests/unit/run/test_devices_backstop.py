"""The devices' backstop: the stand and the instrument closed as the run's ExitStack unwinds,
after the one cleanup path has closed them (a second close is safe), a failing close logged."""

from __future__ import annotations

import contextlib
import logging

import pytest
from run_fakes import FakeSensor, FakeStand

from benchctl.run.devices import close_at_exit
from benchctl.run.supervisor import shutdown


class Counting(FakeStand):
    def __init__(self, order: list[str]) -> None:
        super().__init__()
        self.order = order

    def close(self) -> None:
        self.order.append("stand")
        super().close()


class CountingSensor(FakeSensor):
    def __init__(self, stand: FakeStand, order: list[str]) -> None:
        super().__init__(stand)
        self.order = order

    def close(self) -> None:
        self.order.append("instrument")
        super().close()


def test_the_stack_closes_the_devices_the_stand_first() -> None:
    order: list[str] = []
    stand = Counting(order)
    sensor = CountingSensor(stand, order)
    with contextlib.ExitStack() as stack:
        close_at_exit(stack, stand, sensor)
        assert order == []
    assert order == ["stand", "instrument"]
    assert stand.closed and sensor.closed


def test_after_the_cleanup_path_the_second_close_is_safe() -> None:
    order: list[str] = []
    stand = Counting(order)
    sensor = CountingSensor(stand, order)
    with contextlib.ExitStack() as stack:
        close_at_exit(stack, stand, sensor)
        rep = shutdown(stop_loops=lambda: None, stand=stand, sensor=sensor, writer=None,
                       state="done", reason="", moved=False)
        assert all(s["ok"] for s in rep.steps), rep.steps
        assert order == ["stand", "instrument"]
    assert order == ["stand", "instrument", "stand", "instrument"]
    assert stand.closed and sensor.closed and stand.enabled is False


def test_a_failing_close_is_logged_never_raised(caplog: pytest.LogCaptureFixture) -> None:
    stand = FakeStand()
    sensor = FakeSensor(stand)

    def broken() -> None:
        raise OSError("link gone")

    stand.close = broken  # type: ignore[method-assign]
    with caplog.at_level(logging.WARNING), contextlib.ExitStack() as stack:
        close_at_exit(stack, stand, sensor)
    assert sensor.closed
    assert "stand not closed: OSError: link gone" in caplog.text
