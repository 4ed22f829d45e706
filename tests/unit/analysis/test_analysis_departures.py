"""A motion that was not the profile's is not judged as the profile: underruns and rejoins left
out of the analysis (``benchctl.analysis.departures``), σ on what is left, INCONCLUSIVE when too
little is left.

The synthetic run: a multisine profile (T_p = 20 s, lines 0.05 … 0.6 Hz, 5° rms) played for ten
whole periods; an instrument with gain 0.98 and a 50 ms delay on the stand, so that for the
profile's motion ``σ² = Σ (A_k²/2)·|1 − 0.98·e^{−j2πf_k·0.05}|² + σ_n²`` exactly, and for any
other motion its output is known exactly too (``y(t) = 0.98·x(t − 0.05) + n(t)``). At each
departure the stand does what a buffered stand does when its queue runs dry: from the last
point played it goes on at its rate and brakes at its acceleration limit, holds, and rejoins the
profile along a path (a raised cosine over 1.5 s). The recording holds what the run's loop
writes: the underrun and rejoin events, the setpoints queued 1 s ahead, none over the stall.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from analysis_synthetic import Multisine, orthogonal_noise

from benchctl.analysis import analyze
from benchctl.analysis.departures import SETTLE_S, departures_of, find_departures, settle_of
from benchctl.cli import main
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.evaluate import analyze_recording
from benchctl.recording import RecordingWriter, load_recording
from benchctl.results.measurements import INCONCLUSIVE, Limits, axis_measurements
from benchctl.run.report import Report, axis_verdict

TP, SPAN, T0 = 20.0, 200.0, 100.0  # ten whole periods from T0
MS = Multisine(period_s=TP, f_lo=0.05, f_hi=0.6, rms_deg=5.0)
GAIN, DELAY, NOISE = 0.98, 0.05, 0.02
ACC, HOLD, REJOIN = 50.0, 8.0, 1.5  # braking (deg/s²), hold and the path back (s)
T_POINT, LEAD = 0.02, 1.0  # setpoint period and how far ahead the queue is kept (s)
TOL = 0.002  # σ with the departures left out: within 0.2 % of the closed form


def truth() -> float:
    """The instrument's σ under the profile's motion (closed form, whole periods)."""
    return math.sqrt(MS.error_variance(lambda f: GAIN * np.exp(-2j * np.pi * f * DELAY))
                     + NOISE**2)


def x_profile(t: np.ndarray) -> np.ndarray:
    return MS.reference(np.asarray(t, dtype=float))


def rate_profile(t: float) -> float:
    return float(-np.sum(MS.amps * 2 * np.pi * MS.freqs
                         * np.sin(2 * np.pi * MS.freqs * t + MS.phases)))


@dataclass
class Departure:
    """The stand's own motion from ``start``: brake (``t_brake`` s) to ``x_stop``, hold
    (``hold`` s) to ``t_path``, the path back onto the profile to ``t_path + REJOIN``."""

    start: float
    hold: float = HOLD
    t_brake: float = field(init=False)
    x_stop: float = field(init=False)
    t_path: float = field(init=False)

    def __post_init__(self) -> None:
        v = rate_profile(self.start)
        self.t_brake = abs(v) / ACC
        self.x_stop = float(x_profile(np.array([self.start]))[0]) + 0.5 * v * self.t_brake
        self.t_path = math.ceil((self.start + self.t_brake + self.hold) / T_POINT) * T_POINT

    def apply(self, t: np.ndarray, x: np.ndarray) -> None:
        v, x0 = rate_profile(self.start), float(x_profile(np.array([self.start]))[0])
        m = (t > self.start) & (t <= self.start + self.t_brake)
        tau = t[m] - self.start
        x[m] = x0 + v * tau - 0.5 * math.copysign(ACC, v) * tau**2
        x[(t > self.start + self.t_brake) & (t <= self.t_path)] = self.x_stop
        m = (t > self.t_path) & (t < self.t_path + REJOIN)
        w = 0.5 * (1 + np.cos(np.pi * (t[m] - self.t_path) / REJOIN))
        x[m] = x_profile(t[m]) + (self.x_stop - float(x_profile(np.array([self.t_path]))[0])) * w


@dataclass
class Run:
    """One synthetic run with departures starting at ``starts`` (host clock, s)."""

    starts: list[float]
    hold: float = HOLD
    deps: list[Departure] = field(init=False)

    def __post_init__(self) -> None:
        self.deps = [Departure(s, self.hold) for s in self.starts]

    def x_stand(self, t: np.ndarray) -> np.ndarray:
        x = x_profile(t)
        for d in self.deps:
            d.apply(np.asarray(t, dtype=float), x)
        return x

    def streams(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        ts = T0 - 1 + np.arange(round((SPAN + 2) * 100)) / 100.0  # the stand at 100 Hz
        ti = T0 + np.arange(round(SPAN * 50)) / 50.0  # the instrument at 50 Hz
        y0 = GAIN * self.x_stand(ti - DELAY)
        y = y0 + orthogonal_noise(np.random.default_rng(5), NOISE, y0 - x_profile(ti))
        return ts, self.x_stand(ts), ti, y

    def events(self) -> list[dict[str, float | int | str]]:
        out: list[dict[str, float | int | str]] = []
        for d in self.deps:  # seen 0.6 s after the queue ran dry; the path planned at rest
            out.append({"kind": "underrun", "t_host": d.start + 0.6, "played": 0, "queued": 0})
            out.append({"kind": "rejoin", "t_host": d.t_path - 0.6, "t_slot": d.t_path - 0.6,
                        "slot": 0, "points": round(REJOIN / T_POINT), "duration_s": REJOIN})
        return out

    def setpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """(t_send, t_slot): queued LEAD ahead; none over a stall; a new queue at each rejoin."""
        slot = T0 - 3 + np.arange(round((SPAN + 5) / T_POINT)) * T_POINT
        keep = np.ones(slot.size, dtype=bool)
        for d in self.deps:
            keep &= ~((slot > d.start + 1e-9) & (slot < d.t_path - 1e-9))
        slot = slot[keep]
        send = slot - LEAD
        for d in self.deps:
            send[(slot >= d.t_path - 1e-9) & (slot < d.t_path + LEAD)] = d.t_path - 0.5
        return send, slot

    def departures(self):  # type: ignore[no-untyped-def]
        return find_departures(self.events(), *self.setpoints())

    def record(self, folder: Path) -> Path:
        """The run as a closed recording (what the loop and the recorder write)."""
        w = RecordingWriter(folder, ("roll",), {"serial": "D-1"})
        status = StandStatus(ready=True, enabled=True, moving=True, fault=False, estop=False,
                             limit=False)
        ts, xs, ti, y = self.streams()
        for t, x in zip(ts.tolist(), xs.tolist(), strict=True):
            w.write_stand(StandSample(t_host=t, rtt_s=0.004, angle_deg={"roll": x},
                                      rate_deg_s={"roll": 0.0}, setpoint_deg={"roll": x},
                                      status=status))
        for i, (t, v) in enumerate(zip(ti.tolist(), y.tolist(), strict=True)):
            w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": v}, counter=i))
        send, slot = self.setpoints()
        # the profile at every slot at once (elementwise: each value the one slot's alone)
        for a, b, x in zip(send.tolist(), slot.tolist(), x_profile(slot).tolist(), strict=True):
            w.write_setpoint(a, {"roll": x}, b)
        for e in self.events():
            fields = {k: v for k, v in e.items() if k != "kind"}
            w.event(str(e["kind"]), **fields)
        w.close("done")
        return folder


# four departures, in four of the ten periods: six whole periods untouched (60 % kept)
SOME = Run([125.0, 165.3, 225.7, 265.2])
# six long ones (15 s held): less than half of the samples left, too little
MOST = Run([105.0, 125.3, 145.0, 165.7, 185.2, 205.5], hold=15.0)


def test_intervals_from_last_point_played_to_settled_back_on_the_profile() -> None:
    """The rule: from the last point queued before the underrun (all of them played) to the
    end of the rejoin's path (its first point, the first setpoint sent after the event, plus
    its duration), plus the settling; an underrun and its rejoin make one interval."""
    deps = SOME.departures()
    assert len(deps) == 4
    for got, d in zip(deps.items, SOME.deps, strict=True):
        last_played = math.floor(d.start / T_POINT + 1e-9) * T_POINT
        assert got.start_s == pytest.approx(last_played, abs=1e-9)
        assert got.start_s <= d.start + 1e-9  # never after the stand left the profile
        assert got.back_s == pytest.approx(d.t_path + REJOIN, abs=1e-9)
        assert got.end_s == pytest.approx(d.t_path + REJOIN + SETTLE_S, abs=1e-9)
        assert got.kinds == ("underrun", "rejoin")
    # stream mode: slots missed, the stand held its last setpoint (due at 10.00 s); the path
    # (0.3 s) begins at the slot the loop rejoins at (10.50 s), sent then
    slot = np.r_[np.arange(0.0, 10.001, 0.01), np.arange(10.5, 20.0, 0.01)]
    ev = [{"kind": "rejoin", "t_host": 10.5, "t_slot": 10.5, "duration_s": 0.3}]
    (d,) = find_departures(ev, slot, slot).items
    assert (d.start_s, d.back_s, d.end_s) == pytest.approx((10.0, 10.8, 10.8 + SETTLE_S))
    # an underrun no rejoin follows (the run ended there): to the end of the record; the
    # points were queued 1 s ahead until the host stalled at 10.5 s, seen at 12 s
    slot = np.arange(0.0, 11.501, 0.01)
    (d,) = find_departures([{"kind": "underrun", "t_host": 12.0}], slot - 1.0, slot).items
    assert d.start_s == pytest.approx(11.5) and math.isinf(d.end_s)
    # the settling: the bench config's, as recorded with the run, else 3 s
    assert settle_of({"config": {"run": {"analysis": {"departure_settle_s": 0.5}}}}) == 0.5
    assert settle_of({"config": {"run": {}}}) == settle_of(None) == SETTLE_S == 3.0


def test_sigma_with_departures_left_out_is_the_profiles() -> None:
    """Left in, the departures bias σ (the stand holding still shakes the instrument less than
    the profile: σ 3 % low here, a bad unit could pass); left out, σ is the closed form's
    within 0.2 %, on the six whole periods no departure touches."""
    ts, xs, ti, y = SOME.streams()
    sigma = truth()
    left_in = analyze(ts, xs, ti, y, period_s=TP)
    assert abs(left_in.sigma / sigma - 1) > 0.03
    assert left_in.departures is None
    res = analyze(ts, xs, ti, y, period_s=TP, departures=SOME.departures())
    assert res.sigma == pytest.approx(sigma, rel=TOL)
    assert res.sigma_ci95[0] <= sigma <= res.sigma_ci95[1]
    assert res.lines is not None and res.lines.sigma == pytest.approx(sigma, rel=TOL)
    dep = res.departures
    assert dep is not None and res.judgeable
    assert (dep["count"], dep["underruns"], dep["rejoins"]) == (4, 4, 4)
    assert dep["line_periods"] == {"used": 6, "of": 10, "period_s": TP}
    assert dep["sigma_over"] == "whole_periods" and dep["too_little"] is False
    assert dep["kept_share"] == pytest.approx(0.6)
    expect_s = sum(d.t_path + REJOIN + SETTLE_S - math.floor(d.start / T_POINT + 1e-9) * T_POINT
                   for d in SOME.deps)
    assert dep["excluded_s"] == pytest.approx(expect_s, abs=1e-6)
    assert res.n_samples == round(0.6 * SPAN * 50)
    assert any("not the profile's in 4 interval(s)" in w for w in res.warnings)
    assert not any("outside the line-wise interval" in w for w in res.warnings)


def test_without_whole_periods_on_the_samples_outside_the_departures() -> None:
    """A record not known to hold whole periods (no line set): σ on the samples outside the
    departures — three quarters of them here, so it is judged — the interval from the lag
    window; never a line-wise fit over parts of periods."""
    ts, xs, ti, y = SOME.streams()
    deps = SOME.departures()
    res = analyze(ts, xs, ti, y, lines="off", departures=deps)
    dep = res.departures
    assert dep is not None and dep["sigma_over"] == "samples" and res.judgeable
    assert dep["line_periods"] is None and res.lines is None
    assert res.uncertainty["method"] == "lag_window"
    assert dep["excluded_samples"] == np.count_nonzero(deps.inside(ti))
    assert res.n_samples == round(SPAN * 50) - dep["excluded_samples"]
    assert dep["kept_share"] == pytest.approx(1 - dep["excluded_s"] / SPAN, abs=1e-3)


@pytest.mark.parametrize(("period", "why"), [
    (SPAN, "departed from the profile in every one of the 1 whole period(s) of 200 s: σ is "
           "judged on whole periods of the profile only"),
    (TP, "40 % of the samples are left in the whole periods no departure touches (less than "
         "the 50 % needed)"),
])
def test_too_few_whole_periods_left_is_not_judged(period: float, why: str) -> None:
    """Over a record of one whole period (every period touched), σ is not judged: over the
    samples outside the departures — shown for information — it is 8.8 % off the profile's,
    the parts of the periods left being an uneven sample of a multisine of few lines. Nor when
    the periods left hold less than half of the samples (σ on them, exact but not judged)."""
    run = SOME if period == SPAN else Run(MOST.starts)
    ts, xs, ti, y = run.streams()
    res = analyze(ts, xs, ti, y, period_s=period, departures=run.departures())
    dep = res.departures
    assert dep is not None and dep["too_little"] and not res.judgeable
    assert why in dep["too_little_reason"]
    if period == SPAN:
        assert dep["sigma_over"] == "samples" and res.lines is None
        assert res.sigma / truth() - 1 > 0.05
    else:
        assert dep["sigma_over"] == "whole_periods"
        assert dep["line_periods"] == {"used": 4, "of": 10, "period_s": TP}
        assert res.sigma == pytest.approx(truth(), rel=TOL)


def test_too_little_left_is_inconclusive_whatever_the_sigma() -> None:
    """Six long departures: less than half of the samples left, σ is not judged. Under either
    rule, with a limit it would pass and one it would fail, σ's outcome is INCONCLUSIVE with
    the reason, and so is the run's verdict (exit 3)."""
    ts, xs, ti, y = MOST.streams()
    res = analyze(ts, xs, ti, y, period_s=TP, departures=MOST.departures())
    dep = res.departures
    assert dep is not None and dep["too_little"] is True and not res.judgeable
    assert dep["kept_share"] < 0.5 and dep["sigma_over"] == "whole_periods"
    assert f"{100 * dep['kept_share']:.3g} % of the samples are left" in dep["too_little_reason"]
    assert any("σ not to be judged (INCONCLUSIVE)" in w for w in res.warnings)
    for limit in (10 * res.sigma, 0.1 * res.sigma):
        for rule in ("simple", "guarded"):
            v = axis_verdict("roll", res, limit, rule)
            assert v.sigma_outcome == INCONCLUSIVE and v.outcome == INCONCLUSIVE
            assert v.sigma_inconclusive and "too much of the window" in v.sigma_inconclusive
            ms = axis_measurements("roll", v.to_dict(full=True), Limits(sigma_deg=limit), rule)
            m = next(m for m in ms if m.name == "sigma")
            assert m.outcome == INCONCLUSIVE and m.decisive and "not judged" in (m.note or "")
            rep = Report({"roll": v}, Path("."), {}, {}, (0.0, 1.0), decision_rule=rule,
                         measurements=ms)
            assert rep.verdict == INCONCLUSIVE and rep.exit_code == 3


def test_benchctl_analyze_leaves_the_departures_out(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """End to end: a recording with underruns and rejoins in its events.jsonl; ``benchctl
    analyze`` finds them, leaves them out and says so (JSON and the summary)."""
    rec = SOME.record(tmp_path / "rec")
    assert len(departures_of(load_recording(rec))) == 4
    assert main(["analyze", str(rec), "--json", "--axis", "roll", "--period", str(TP)]) == 0
    d = json.loads(capsys.readouterr().out)
    sigma = truth()
    assert d["sigma"] == pytest.approx(sigma, rel=TOL)
    dep = d["departures"]
    assert (dep["count"], dep["underruns"], dep["rejoins"]) == (4, 4, 4)
    assert dep["line_periods"]["used"] == 6 and dep["too_little"] is False
    assert dep["settle_s"] == SETTLE_S and "last point the stand played" in dep["rule"]
    assert main(["analyze", str(rec), "--period", str(TP)]) == 0
    out = capsys.readouterr().out
    assert "motion not the profile's: 4 interval(s) (4 underrun(s), 4 rejoin(s))" in out
    assert "σ on the 6 of 10 whole period(s) no departure touches" in out
    api = analyze_recording(rec, "roll", period_s=TP)
    assert api.sigma == d["sigma"]
    whole = analyze_recording(rec, "roll", period_s=TP, departures=None)
    assert whole.departures is None and abs(whole.sigma / sigma - 1) > 0.03
    too_little = MOST.record(tmp_path / "most")
    assert main(["analyze", str(too_little), "--period", str(TP)]) == 0
    assert "σ NOT TO BE JUDGED" in capsys.readouterr().out
