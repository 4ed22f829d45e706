"""Where the stand was left: the cleanup reads a faulted stand's state instead of failing on it."""

from __future__ import annotations

from run_fakes import FakeSensor, FakeStand

from benchctl.devices.base import StandSample
from benchctl.errors import StandFault
from benchctl.run.supervisor import shutdown


class FaultedStand(FakeStand):
    """A stand that latched a fault at +1.787°: every ordinary read raises, as a driver does."""

    def __init__(self) -> None:
        super().__init__()
        self.fault = True
        self.offset_deg = 0.0

    def true_angle(self) -> dict[str, float]:
        return {"roll": 1.787}

    def read_sample(self) -> StandSample:
        raise StandFault("stand fault 7", code=7)

    def read_state(self) -> StandSample:
        return super().read_sample()

    def ramp_to_zero(self, timeout_s: float) -> None:
        raise StandFault("stand fault 7", code=7)


def test_a_faulted_stands_final_state_is_read_and_reported() -> None:
    stand = FaultedStand()
    rep = shutdown(stop_loops=lambda: None, stand=stand, sensor=FakeSensor(stand), writer=None,
                   state="aborted", reason="stand fault")
    steps = {s["step"]: s for s in rep.steps}
    assert steps["ramp to zero"]["ok"] is False
    assert steps["read final state"]["ok"] is True  # before: failed on the fault it reports
    assert steps["final angle"]["detail"] == "roll=1.787° (servo off, fault 7)"
    assert rep.final_state == {"angle_deg": {"roll": 1.787}, "rate_deg_s": {"roll": 0.0},
                               "enabled": False, "fault_code": 7, "estop": False,
                               "fault_text": "", "moving": False}  # no register map: no text
