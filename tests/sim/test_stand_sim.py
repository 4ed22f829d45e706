"""Back-to-back: the real stand driver against the simulated stand over Modbus TCP and RTU.

On simulated time (the ``vclock`` fixture): the stand simulator and the driver over an
in-process link carrying Modbus TCP or RTU frames (pymodbus's own client and framing on the
driver's side, the simulator's wire on the other), its physics, watchdog, stalls and timeouts
exact. Over a real socket and a real pty (``realtime``): a TCP connection the stand drops is
``ConnectionLost``, and a stopped simulator leaves no pty, symlink or descriptor behind. (The
driver connecting to it and identifying it over a real socket and a real pty: the realtime runs
of tests/e2e/test_run_exits.py, SIGTERM over TCP, and tests/e2e/test_run_e2e.py, over an RTU
pty.)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import psutil
import pytest
from stand_rig import LIMITS, MAP, SLOW, TIMEOUT_S, connect, simulated, wait_for

from benchctl.analysis.timebase import stand_clock
from benchctl.clock import REAL, Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import SimStandConfig, SimStandFault
from benchctl.devices.base import Stand, StandSample
from benchctl.devices.modbus import ModbusStand
from benchctl.errors import (
    ConnectionLost,
    DeviceError,
    DeviceTimeout,
    LimitError,
    ModbusException,
    StandFault,
)
from benchctl.harmonics import HarmonicTable
from benchctl.sim.stand import FAULT_ESTOP, FAULT_SOFT_LIMIT, FAULT_WATCHDOG, SimStand


@pytest.fixture(params=["tcp", "rtu"])
def rig(
    request: pytest.FixtureRequest, vclock: VirtualClock
) -> Iterator[tuple[SimStand, ModbusStand]]:
    """On simulated time: Modbus TCP, then RTU frames over an in-process link."""
    with simulated(SLOW, request.param, vclock) as r:
        yield r


def stream(
    stand: ModbusStand,
    motion: Callable[[float], float],
    duration_s: float,
    rate_hz: float = 50.0,
    *,
    return_after_s: float | None = None,
) -> tuple[float, list[StandSample]]:
    """Play ``motion(k/rate_hz)`` on roll through the stand's trajectory queue (sent ahead, so
    a loaded host does not change the motion) and poll the stand until it has played it.

    Returns the start time t0 (point k is played at host time t0 + k/rate_hz) and the samples.
    ``return_after_s``: return that long after the start, while the stand still plays.
    """
    period = 1.0 / rate_hz
    pts = np.array([motion(k * period) for k in range(round(duration_s * rate_hz) + 1)])
    if abs(pts[-1] - pts[-2]) <= LIMITS.accel_deg_s2 * period**2:  # ends (nearly) at rest: the
        pts = np.concatenate([pts, pts[-1:], pts[-1:]])  # queue ends with its last point held
    n = pts.size
    stand.begin_trajectory()
    _, per_push = stand.trajectory_limits
    j = 0

    def push(read: bool) -> StandSample | None:
        nonlocal j
        m = min(per_push, n - j)
        s = stand.push_points(j, {"roll": pts[j : j + m]}, read=read)
        j += m
        return s

    capacity, _ = stand.trajectory_limits
    while j < n and j < max(4 * per_push, capacity - 2 * per_push):  # as much ahead as fits
        push(read=False)
    t0 = stand.start_trajectory()
    clock = stand.clock
    samples: list[StandSample] = []
    k = 0
    while True:
        k += 1
        due = t0 + k * period
        now = clock.monotonic()
        if due > now:
            clock.sleep(due - now)
        last = samples[-1].trajectory if samples else None
        s = None
        if j < n and last is not None and last.level < 2 * per_push:
            s = push(read=True)
        s = s or stand.read_sample()
        samples.append(s)
        if k % 5 == 0:
            stand.heartbeat()
        if return_after_s is not None and clock.monotonic() - t0 >= return_after_s:
            return t0, samples
        if j >= n and not s.status.trajectory_running:
            return t0, samples


def stand_instants(stand: ModbusStand, samples: list[StandSample]) -> np.ndarray:
    """The samples' host instants from the stand's own clock (its map's ``sample_time``) and
    the exchanges' windows, as a recording's analysis dates them: a reply held up on a busy
    host does not move its sample (stamped at receipt, 50 ms rms of such jitter takes 5 % off
    a 1 Hz sine's fitted amplitude)."""
    assert stand.map.sample_time is not None
    assert all(s.t_stand is not None and s.t_window is not None for s in samples)
    t, _, info = stand_clock([s.t_stand for s in samples], stand.map.sample_time_wrap_s,
                             [s.t_window[0] for s in samples],  # type: ignore[index]
                             [s.t_window[1] for s in samples])  # type: ignore[index]
    assert info["consistent"], info
    return t


def fit_phasor(t: np.ndarray, x: np.ndarray, f_hz: float) -> complex:
    """Least-squares complex amplitude c of x(t) ≈ Re(c e^{j2πft}) + offset."""
    w = 2 * np.pi * f_hz
    a = np.column_stack([np.cos(w * t), -np.sin(w * t), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(a, x, rcond=None)
    return complex(coef[0], coef[1])


def test_driver_satisfies_the_stand_protocol(rig: tuple[SimStand, ModbusStand]) -> None:
    _satisfies_the_stand_protocol(rig[1])


def _satisfies_the_stand_protocol(stand: ModbusStand) -> None:
    assert isinstance(stand, Stand)
    ident = stand.identity
    assert ident is not None and ident.vendor == "benchctl" and ident.serial == "SIM-0001"
    st = stand.read_status()
    assert st.ready and not st.enabled and not st.fault


def test_streamed_sine_follows_the_servo_response(rig: tuple[SimStand, ModbusStand]) -> None:
    sim, stand = rig
    stand.enable()
    f, amp = 1.0, 2.0
    motion = HarmonicTable(
        np.array([f]),
        np.array([amp]),
        np.array([-np.pi / 2]),
        duration_s=3.5,
        fade_in_s=0.5,
        fade_out_s=0.5,
    )  # a sine, faded in and out
    t0, samples = stream(stand, lambda t: motion.at(t), 3.5)
    t = stand_instants(stand, samples) - t0
    assert samples[-1].trajectory is not None and samples[-1].trajectory.underruns == 0
    x = np.array([s.angle_deg["roll"] for s in samples])
    steady = (t > 1.2) & (t < 2.9)
    measured = fit_phasor(t[steady], x[steady], f)
    # the stand plays the queued points linearly interpolated on its own clock: the servo's
    # response alone (no host timing in it)
    expected = amp * np.exp(-1j * np.pi / 2) * sim.servo_response(f)
    assert abs(measured) == pytest.approx(abs(expected), rel=0.04)
    phase_err = math.degrees(np.angle(measured / expected))
    assert abs(phase_err) < 4.0, (
        f"phase {math.degrees(np.angle(measured)):.1f}° vs expected "
        f"{math.degrees(np.angle(expected)):.1f}°"
    )
    # and the ideal (no dynamics) answer is clearly rejected: arg H(1 Hz) ≈ −43°
    assert abs(math.degrees(np.angle(measured / (amp * np.exp(-1j * np.pi / 2))))) > 30
    stand.ramp_to_zero(timeout_s=10)
    assert abs(stand.read_sample().angle_deg["roll"]) <= stand.zero_tolerance_deg


def test_harmonic_table_runs_in_the_stand(rig: tuple[SimStand, ModbusStand]) -> None:
    sim, stand = rig
    stand.enable()
    f = 1.0
    roll = HarmonicTable(
        np.array([f]),
        np.array([2.0]),
        np.array([0.3]),
        duration_s=2.5,
        fade_in_s=0.5,
        fade_out_s=0.5,
    )
    pitch = HarmonicTable(
        np.array([0.5, 1.5]),
        np.array([1.0, 0.5]),
        np.array([0.0, 1.0]),
        duration_s=2.5,
        fade_in_s=0.5,
        fade_out_s=0.5,
    )
    stand.upload_table({"roll": roll, "pitch": pitch})
    t_start = stand.start_table()
    clock = stand.clock
    samples: list[StandSample] = []
    while clock.monotonic() - t_start < 2.7:
        samples.append(stand.read_sample())
        stand.heartbeat()
        clock.sleep(0.02)
    assert any(s.status.table_running for s in samples)

    def ended() -> bool:
        stand.heartbeat()  # the watchdog (1.5 s) must not fire while we wait on a busy machine
        return not stand.read_status().table_running

    wait_for(ended, 2.0, "the table to end", clock)
    stand.heartbeat()
    h = sim.servo_response(f)
    checked = 0
    for s in samples:
        t = s.t_host - t_start
        # a sample is stamped at its request/reply midpoint: its time is known to ±rtt/2 (a
        # busy host or a slow wire widens that), so the motion over that span is allowed for
        half = s.rtt_s / 2 + 0.002
        # the stand's active setpoint is the table itself (pitch moves ≤ 7.9°/s)
        assert s.setpoint_deg["pitch"] == pytest.approx(float(pitch.at(t)), abs=0.03 + 7.9 * half)
        if 1.0 < t < 1.9:  # steady part of the roll line: angle = Re(H · A e^{j(ωt+φ)})
            pred = float(np.real(h * 2.0 * np.exp(1j * (2 * np.pi * f * t + 0.3))))
            assert s.angle_deg["roll"] == pytest.approx(pred, abs=0.1 + 12.6 * half)
            checked += 1
    assert checked >= 15
    final = stand.read_sample()
    assert abs(final.angle_deg["roll"]) < 0.05 and abs(final.angle_deg["pitch"]) < 0.05


def test_true_angles_match_the_encoder(rig: tuple[SimStand, ModbusStand]) -> None:
    sim, stand = rig
    stand.enable()
    stream(stand, lambda t: 2.0 * (1 - math.cos(2 * math.pi * t)) / 2, 0.6)
    s = stand.read_sample()
    true = sim.true_angles(s.t_host)["roll"]
    # the read is stamped at the request/reply midpoint; the stand moves ≤ 6.3°/s here
    assert s.angle_deg["roll"] == pytest.approx(true, abs=0.001 + 6.3 * (s.rtt_s / 2 + 0.001))


def test_table_beyond_limits_is_rejected_before_upload(rig: tuple[SimStand, ModbusStand]) -> None:
    _, stand = rig
    fast = HarmonicTable(
        np.array([3.0]),
        np.array([5.0]),
        np.array([0.0]),
        duration_s=2.0,
        fade_in_s=0.5,
        fade_out_s=0.5,
    )  # needs ~94°/s
    with pytest.raises(LimitError, match="needs rate"):
        stand.upload_table({"roll": fast})
    with pytest.raises(DeviceError, match="without an uploaded table"):
        stand.start_table()


def test_ramp_to_zero_from_motion_respects_limits(rig: tuple[SimStand, ModbusStand]) -> None:
    _, stand = rig
    stand.enable()
    # accelerating away (8 °/s after 0.5 s, 2° out), the ramp called while it still plays
    stream(stand, lambda t: 8.0 * t * t, 1.0, return_after_s=0.5)
    assert stand.read_sample().status.trajectory_running
    stand.ramp_to_zero(timeout_s=10)
    s = stand.read_sample()
    assert abs(s.angle_deg["roll"]) <= stand.zero_tolerance_deg and not s.status.moving


def test_setpoint_and_read_in_one_transaction(rig: tuple[SimStand, ModbusStand]) -> None:
    _, stand = rig
    stand.enable()
    clock = stand.clock
    t0 = clock.monotonic()
    k = 0
    while clock.monotonic() - t0 < 0.6:
        k += 1
        x = 0.01 * k  # 0.5 °/s at 50 Hz: within the limits even from rest after a host stall
        t_send, s = stand.send_setpoint_and_read({"roll": x})
        # the write precedes the read in the same request: the stand already holds it
        assert s.setpoint_deg["roll"] == pytest.approx(x, rel=1e-6, abs=1e-6)
        assert t_send <= s.t_host
        stand.heartbeat()
        clock.sleep(0.02)


def test_two_threads_share_one_driver(rig: tuple[SimStand, ModbusStand]) -> None:
    """A heartbeat thread and a streaming loop interleave their requests on one link."""
    _, stand = rig
    stand.enable()
    clock = stand.clock
    stop = clock.event()
    errors: list[BaseException] = []

    def beat() -> None:
        while not stop.wait(0.013):
            try:
                stand.heartbeat()
            except BaseException as e:  # surfaced below, never lost
                errors.append(e)
                return

    hb = clock.thread(beat, name="test-heartbeat")
    hb.start()
    try:
        _, samples = stream(stand, lambda t: 1.0 * (1 - math.cos(2 * math.pi * t)) / 2, 0.8)
    finally:
        stop.set()
        hb.join()
    assert not errors
    echoes = [s.status.heartbeat for s in samples]
    assert echoes[-1] > echoes[0] + 10  # the stand saw the other thread's heartbeats


# -- faults --------------------------------------------------------------------------------
def expect_within(
    exc: type[BaseException], fn: Callable[[], object], bound_s: float, clock: Clock
) -> BaseException:
    """``fn`` must raise ``exc`` (repeating until it does) within ``bound_s`` on ``clock``."""
    t0 = clock.monotonic()
    while True:
        try:
            fn()
        except exc as e:
            return e
        if clock.monotonic() - t0 > bound_s:
            raise AssertionError(f"no {exc.__name__} within {bound_s} s")
        clock.sleep(0.01)


def test_stall_gives_timeout_then_recovers(rig: tuple[SimStand, ModbusStand]) -> None:
    sim, stand = rig
    stall_s = TIMEOUT_S + 0.5
    sim.inject("stall", duration_s=stall_s)
    clock = stand.clock
    t0 = clock.monotonic()
    expect_within(DeviceTimeout, stand.read_sample, TIMEOUT_S + 1.0, clock)
    assert clock.monotonic() - t0 < TIMEOUT_S + 1.0
    wait_for(lambda: clock.monotonic() - t0 > stall_s + 0.1, stall_s + 2.0, "the stall to end",
             clock)
    assert stand.read_status().ready


def test_modbus_exception_is_typed(rig: tuple[SimStand, ModbusStand]) -> None:
    sim, stand = rig
    sim.inject("modbus_exception", code=6, count=1)
    err = expect_within(ModbusException, stand.read_sample, 1.0, stand.clock)
    assert isinstance(err, ModbusException) and err.exception_code == 6 and err.function_code == 3
    assert stand.read_status().ready  # one exception only


def _dropped_connection(sim: SimStand, stand: ModbusStand) -> None:
    sim.inject("drop_connection")
    # TCP: the server closes the connection; RTU: the line goes dead
    expected = ConnectionLost if sim.framing == "tcp" else DeviceTimeout
    expect_within(expected, stand.read_sample, TIMEOUT_S + 1.5, stand.clock)
    sim.clear_faults()
    wait_for(lambda: _answers(stand), 3.0, "the link to come back", stand.clock)


def test_dropped_rtu_line(vclock: VirtualClock) -> None:
    with simulated(SLOW, "rtu", vclock) as (sim, stand):
        _dropped_connection(sim, stand)


# over an in-process link the simulator's drop_connection is silence (the link stays open), so
# a TCP connection that the stand closes is tested on a real socket
@pytest.mark.realtime  # a real TCP connection closed by the server
def test_dropped_tcp_connection_over_a_real_socket() -> None:
    with simulated(SLOW, "tcp", REAL) as (sim, stand):
        _dropped_connection(sim, stand)


def _answers(stand: ModbusStand) -> bool:
    try:
        stand.read_status()
    except DeviceError:
        return False
    return True


@pytest.mark.parametrize(("kind", "code"), [("stand_fault", 10), ("estop", FAULT_ESTOP)])
def test_stand_fault_and_estop(rig: tuple[SimStand, ModbusStand], kind: str, code: int) -> None:
    sim, stand = rig
    stand.enable()
    if kind == "stand_fault":
        sim.inject(kind, code=code)
    else:
        sim.inject(kind)
    err = expect_within(StandFault, stand.read_sample, 1.0, stand.clock)
    assert isinstance(err, StandFault) and err.code == code
    st = stand.read_status()
    assert st.fault and not st.enabled and st.estop == (kind == "estop")
    with pytest.raises(StandFault):
        stand.enable()
    stand.reset_fault()
    stand.enable()
    assert stand.read_status().enabled


def test_estop_over_modbus(rig: tuple[SimStand, ModbusStand]) -> None:
    _, stand = rig
    stand.enable()
    stand.estop()
    err = expect_within(StandFault, stand.read_sample, 1.0, stand.clock)
    assert isinstance(err, StandFault) and err.code == FAULT_ESTOP


def test_watchdog_stops_the_stand_when_heartbeat_stops(rig: tuple[SimStand, ModbusStand]) -> None:
    _, stand = rig
    stand.enable()
    stream(
        stand, lambda t: 3.0 * (1 - math.cos(2 * math.pi * 0.5 * t)) / 2, 0.5
    )  # moving, heartbeat kept
    clock = stand.clock
    t_last = clock.monotonic()  # no heartbeat from here on
    err = expect_within(StandFault, stand.read_sample, SLOW.watchdog_s + 1.0, clock)
    assert isinstance(err, StandFault) and err.code == FAULT_WATCHDOG
    assert (
        clock.monotonic() - t_last >= SLOW.watchdog_s - 0.15
    )  # not before its time (heartbeat at k%5)
    wait_for(lambda: not stand.read_status().moving, 2.0, "the stand to brake to rest", clock)
    assert not stand.read_status().enabled


def test_soft_limit_faults_the_stand(vclock: VirtualClock) -> None:
    # tighter than the driver's 20° limit, and a lightly damped servo that overshoots
    cfg = SimStandConfig(soft_limit_deg=3.0, bandwidth_hz=2.0, damping=0.2)
    with simulated(cfg, "tcp", vclock) as (_sim, stand):
        stand.enable()
        with pytest.raises(ModbusException) as exc:  # a setpoint beyond it: illegal value
            stand.link.write_registers(300, [0x4120, 0x0000])  # roll 10.0°
        assert exc.value.exception_code == 3
        move = HarmonicTable(
            np.array([0.0, 1 / 0.6]), np.array([1.475, -1.475]), np.zeros(2), duration_s=0.3
        )  # 0 → 2.95° in 0.3 s, smooth
        with pytest.raises(StandFault) as err:  # the overshoot passes 3°
            stream(stand, lambda t: float(move.at(min(t, 0.3))), 2.0)
        assert err.value.code == FAULT_SOFT_LIMIT
        st = stand.read_status()
        assert st.limit and st.fault and not st.enabled


def test_scheduled_fault_from_config(vclock: VirtualClock) -> None:
    cfg = SimStandConfig(
        faults=(SimStandFault(kind="modbus_exception", after_s=0.3, duration_s=0.3, code=4),)
    )
    with simulated(cfg, "tcp", vclock) as (_sim, stand):
        stand.read_status()
        err = expect_within(ModbusException, stand.read_status, 2.0, vclock)
        assert isinstance(err, ModbusException) and err.exception_code == 4
        wait_for(lambda: _answers(stand), 2.0, "the scheduled fault to end", vclock)


@pytest.mark.realtime  # a real pty and its symlink
def test_stop_is_idempotent_and_leaves_nothing_behind(tmp_path: Path) -> None:
    link = tmp_path / "stand.pty"
    fds_before = psutil.Process().num_fds()
    sim = SimStand(
        SimStandConfig(), limits=LIMITS, register_map=MAP, transport="rtu", link_path=link
    )
    with sim:
        assert link.is_symlink() and str(link.resolve()) == sim.serial_port
        stand = connect(sim)
        stand.close()
        stand.close()
    sim.stop()
    assert not link.exists()
    assert psutil.Process().num_fds() == fds_before  # ptys, sockets, event loop: all closed


def test_trajectory_queue_plays_ahead_and_an_underrun_stops_within_limits(
    rig: tuple[SimStand, ModbusStand],
) -> None:
    """Points queued ahead are played on the stand's clock; when the host stops feeding the
    queue while the stand moves, the stand counts an underrun and stops itself at its
    acceleration limit (never a jump), then holds."""
    _sim, stand = rig
    stand.enable()
    _t0, samples = stream(stand, lambda t: 2.0 * math.sin(math.pi * t) ** 2, 1.0)
    assert samples[-1].trajectory is not None and samples[-1].trajectory.underruns == 0
    # now a motion that ends while moving at 10 °/s: the queue runs dry mid-motion
    stand.begin_trajectory()
    pts = 0.1 * np.arange(1, 61) ** 2 / 60  # accelerating to 10°/s over 60 points at 50 Hz
    stand.push_points(0, {"roll": pts[:24]}, read=False)
    stand.push_points(24, {"roll": pts[24:48]}, read=False)
    stand.push_points(48, {"roll": pts[48:]}, read=False)
    stand.start_trajectory()
    rates: list[tuple[float, float]] = []

    def stopped() -> bool:
        s = stand.read_sample()
        stand.heartbeat()
        rates.append((s.t_host, s.rate_deg_s["roll"]))
        tr = s.trajectory
        return tr is not None and tr.underruns == 1 and not s.status.trajectory_running and (
            not s.status.moving
        )

    wait_for(stopped, 5.0, "the stand to stop after the underrun", stand.clock)
    t = np.array([r[0] for r in rates])
    v = np.array([r[1] for r in rates])
    assert np.max(np.abs(v)) < 12.0
    # deceleration after the queue ran dry: at the stand's limit (200°/s²), not a jump
    dv = np.abs(np.diff(v)) / np.maximum(np.diff(t), 1e-3)
    assert np.max(dv) < 200.0 * 3  # sampled rates; a jump to rest would be ~10/0.001
    s = stand.read_sample()
    assert s.status.enabled and not s.status.fault


@pytest.mark.parametrize("end_rate", [5.0, 10.0, 20.0])
def test_an_underrun_stop_continues_the_queues_path_within_the_acceleration_limit(
    vclock: VirtualClock, end_rate: float
) -> None:
    """The stand's own motion — every physics tick, not sampled — stays within its
    acceleration limit when its queue runs dry mid-motion: the stop continues the path the
    queue was playing (its position and rate at that instant) and decelerates from there. An
    8 Hz servo (the shipped one) answers a step in its target of one tick's motion (0.01° at
    10 °/s) with 25 °/s² on top of the stop's deceleration: the limit then breaks."""
    fast = SimStandConfig(bandwidth_hz=8.0, damping=0.8, watchdog_s=1.5)
    with simulated(fast, "tcp", vclock) as (sim, stand):
        stand.enable()
        stand.begin_trajectory()
        n = 60  # accelerating at a constant rate to end_rate over 60 points at 50 Hz
        pts = end_rate * 0.02 * np.arange(1, n + 1) ** 2 / (2 * n)
        for j in range(0, n, 20):
            stand.push_points(j, {"roll": pts[j:j + 20]}, read=False)
        t_start = stand.start_trajectory()

        def stopped() -> bool:
            s = stand.read_sample()
            stand.heartbeat()
            tr = s.trajectory
            return tr is not None and tr.underruns == 1 and not s.status.moving

        wait_for(stopped, 3.0, "the stand to stop after the underrun", vclock)
        peak = sim.peaks(following="profile")["roll"]
        assert peak["rate_deg_s"] == pytest.approx(end_rate, rel=0.1)
        assert peak["accel_deg_s2"] <= LIMITS.accel_deg_s2, peak
        # the servo's acceleration tick by tick (its position's second difference) as the
        # queue runs dry: it turns smoothly towards the stop's deceleration, its change
        # growing by at most ωn² · (deceleration) · tick² = 0.45 °/s² a tick; a step of the
        # target would jump it by ωn² times the step at once (8.6 °/s² at 5 °/s)
        tick = 1.0 / fast.tick_hz
        t_dry = t_start + (n - 1) * 0.02
        ts = t_dry + tick * np.arange(-6, 7)
        x = np.array([sim.true_angles(float(t))["roll"] for t in ts])
        accel = np.diff(x, 2) / tick**2
        assert np.abs(np.diff(accel, 2)).max() < 1.0, (end_rate, np.diff(accel))
