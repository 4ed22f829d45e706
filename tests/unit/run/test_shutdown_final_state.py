"""Where the stand was left: the cleanup reads a faulted stand's state instead of failing on it."""

from __future__ import annotations

from run_fakes import FakeSensor, FakeStand

from benchctl.devices.base import StandSample
from benchctl.errors import StandFault
from benchctl.run.outputs import stand_lines
from benchctl.run.result import stand_after
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


def test_where_the_stand_is_and_the_commands_that_bring_it_to_zero() -> None:
    base = {"angle_deg": {"roll": 0.01, "pitch": 0.0}, "rate_deg_s": {"roll": 0.0, "pitch": 0.0},
            "enabled": False, "fault_code": 0, "fault_text": "", "estop": False,
            "moving": False}
    cfg = "config/my bench.yaml"
    quoted = "'config/my bench.yaml'"
    home, reset = (f"benchctl stand home --config {quoted}",
                   f"benchctl stand reset --config {quoted}")
    at_zero = stand_after(base, zero_tolerance_deg=0.05, config=cfg)
    assert at_zero["at_zero"] and at_zero["commands"] == [] and len(stand_lines(at_zero)) == 1
    off = stand_after({**base, "angle_deg": {"roll": 1.787, "pitch": 0.0}},
                      zero_tolerance_deg=0.05, config=cfg)
    assert not off["at_zero"] and off["commands"] == [home]  # no fault: no reset
    assert "roll +1.787°" in off["text"] and "NOT at zero" in off["text"]
    faulted = stand_after({**base, "fault_code": 2, "fault_text": "heartbeat watchdog expired",
                           "angle_deg": {"roll": 1.787, "pitch": 0.0}},
                          zero_tolerance_deg=0.05, config=cfg)
    assert faulted["commands"] == [reset, home]
    assert "fault 2 (heartbeat watchdog expired)" in faulted["text"]
    assert stand_lines(faulted)[1:] == ["to bring it to rest at zero, in this order:",
                                        f"  {reset}", f"  {home}"]
    estop_at_zero = stand_after({**base, "estop": True, "fault_code": 3},
                                zero_tolerance_deg=0.05, config=cfg)
    assert estop_at_zero["commands"] == [reset] and "E-stop pressed" in estop_at_zero["text"]
    settling = stand_after({**base, "rate_deg_s": {"roll": 0.02, "pitch": 0.0}, "moving": True},
                           zero_tolerance_deg=0.05, config=cfg)  # just after the servo went off
    assert settling["at_rest"] and settling["at_zero"] and settling["commands"] == []
    moving = stand_after({**base, "rate_deg_s": {"roll": 4.0, "pitch": 0.0}, "moving": True},
                         zero_tolerance_deg=0.05, config=cfg)
    assert not moving["at_rest"] and "MOVING" in moving["text"] and moving["commands"] == [home]
    silent = stand_after(None, zero_tolerance_deg=0.05, config=cfg)
    assert not silent["known"] and silent["at_zero"] is None
    assert f"benchctl stand status --config {quoted}" in silent["text"]
    never = stand_after(None, zero_tolerance_deg=0.05, config=cfg, known=False)
    assert never["commands"] == [] and "not connected" in never["text"]
