"""After an abort: where the stand is, the cleanup's steps and the stand's samples through the
shutdown ramp — on the screen, in ``record.json`` and in ``report.html`` (simulated time: the
real drivers and simulators on the ``vclock`` fixture)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from live_bench import ROLL, ROOT, LiveBench, live_bench, motion_for, recording_in

from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.recording import load_recording
from benchctl.results.record import load_record
from benchctl.run import RunOptions, run_test
from benchctl.run.display import NullDisplay
from benchctl.run.supervisor import Supervisor

pytestmark = pytest.mark.slow


class Screen(NullDisplay):
    """A display that keeps what the run would print (its messages and its verdict)."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def message(self, text: str) -> None:
        self.lines.append(text)

    def verdict(self, verdict: str, detail: str = "") -> None:
        self.lines.append(verdict)
        self.lines.extend(detail.splitlines())

    @property
    def text(self) -> str:
        return "\n".join(self.lines)



def _fault_mid_run(tmp_path: Path, vclock: VirtualClock, b: LiveBench,
                   screen: Screen) -> Path:
    profile = tmp_path / "roll.yaml"
    profile.write_text(ROLL)
    runs = tmp_path / "runs"
    sup = Supervisor(clock=vclock)

    def watch() -> None:
        while not motion_for(runs, 1.5, vclock)():
            vclock.sleep(0.02)
        b.stand.inject("stand_fault", code=12)

    watcher = vclock.thread(watch, name="inject-fault")
    watcher.start()
    res = run_test(b.cfg, profile, RunOptions("SAFE-1", "ci"), screen, supervisor=sup,
                   clock=vclock)
    watcher.join()
    assert res.exit_code == 2 and "fault 12" in res.reason, res.reason
    rec = recording_in(runs)
    assert rec is not None
    return rec


def test_a_stand_fault_mid_run_shows_the_shutdown_steps(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    screen = Screen()
    with live_bench(tmp_path, clock=vclock) as b:
        rec = _fault_mid_run(tmp_path, vclock, b, screen)
    record = load_record(rec)
    steps = record["abort"]["shutdown"]
    names = [s["step"] for s in steps]
    assert names[:2] == ["stop loops", "ramp to zero"] and "close recording" in names
    ramp = steps[names.index("ramp to zero")]
    assert ramp["ok"] is False and ramp["detail"]  # the stand is in fault: the ramp is refused
    html = (rec / "report.html").read_text()
    assert 'id="shutdown"' in html
    at = html.index('id="shutdown"')
    section = html[at:html.index("</section>", at)]
    for s in steps:
        assert s["step"] in section
    assert "FAILED" in section
    assert "ramp to zero: FAILED" in screen.text


def test_a_stand_fault_mid_run_says_where_the_stand_is_and_how_to_zero_it(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    screen = Screen()
    with live_bench(tmp_path, clock=vclock) as b:
        rec = _fault_mid_run(tmp_path, vclock, b, screen)
        true = b.stand.true_angles(vclock.monotonic())["roll"]
    cfg = str(b.cfg.source)
    reset, home = f"benchctl stand reset --config {cfg}", f"benchctl stand home --config {cfg}"
    where = load_record(rec)["abort"]["stand"]  # validated against the schema
    assert where["known"] and where["fault_code"] == 12 and where["fault_text"]
    assert where["enabled"] is False and where["at_rest"] is True
    angle = where["axes"]["roll"]["angle_deg"]
    assert abs(angle) > 0.05 and angle == pytest.approx(true, abs=0.01)  # braked off zero
    assert where["at_zero"] is False and where["commands"] == [reset, home]
    # the terminal: the stand's line and the commands, under the ABORTED banner
    text = screen.text
    banner = text[text.rindex("ABORTED"):]
    assert f"roll {angle:+.3f}°" in banner and "fault 12" in banner and "NOT at zero" in banner
    assert f"to bring it to rest at zero, in this order:\n  {reset}\n  {home}\n" in banner
    html = (rec / "report.html").read_text()
    assert 'id="stand-after"' in html and f"roll {angle:+.3f}°" in html
    assert f"<code>{reset}</code>, then <code>{home}</code>" in html
    print(text)


def test_a_ctrl_c_records_the_stand_through_the_shutdown_ramp(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """The operator's Ctrl-C (``Supervisor.interrupt_after``, on simulated time) mid-motion:
    the stand's samples go on into stand.csv through the ramp to zero, as during the motion."""
    profile = tmp_path / "roll.yaml"
    profile.write_text(ROLL)
    runs = tmp_path / "runs"
    screen = Screen()
    with live_bench(tmp_path, clock=vclock) as b:
        sup = Supervisor(clock=vclock)

        def watch() -> None:
            while not motion_for(runs, 1.5, vclock)():
                vclock.sleep(0.02)
            sup.interrupt_after(0.013)

        watcher = vclock.thread(watch, name="operator")
        watcher.start()
        res = run_test(b.cfg, profile, RunOptions("SAFE-2", "ci"), screen, supervisor=sup,
                       clock=vclock)
        watcher.join()
        period = 1.0 / b.cfg.stand.sample_rate_hz
    assert res.exit_code == 2 and "interrupted by SIGINT" in res.reason
    rec = recording_in(runs)
    assert rec is not None
    r = load_recording(rec)
    t_abort = next(e["t_host"] for e in r.events
                   if e["kind"] == "state" and e["to"] == "aborted")
    sp = r.streams["setpoints"]
    ramp = sp["t_send"][np.isnan(sp["t_slot"]) & (sp["t_send"] >= t_abort)]
    assert len(ramp) >= 20  # the ramp to zero was streamed (not a stand at zero already)
    t = r.streams["stand"]["t_host"]
    during = t[(t >= t_abort) & (t <= ramp[-1] + period)]
    assert during.size and during[0] - t_abort <= 5 * period
    gaps = np.diff(np.concatenate([[t_abort], during, [ramp[-1]]]))
    assert gaps.max() <= 5 * period, (gaps.max(), period)  # no hole in the stand's record
    assert abs(r.streams["stand"]["roll_deg"][-1]) <= b.cfg.stand.zero_tolerance_deg
    where = load_record(rec)["abort"]["stand"]
    assert where["at_zero"] and where["commands"] == [] and where["fault_code"] == 0
    assert "to bring it to rest at zero" not in screen.text


def test_benchctl_run_ends_its_screen_with_where_the_stand_is(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`benchctl run` on simulated time (``sim.clock: virtual``), the simulated stand faulting
    by itself 2 s into the motion: the last lines printed say where the stand is and name the
    commands, with the config the run was given."""
    data = yaml.safe_load((ROOT / "config/sim_virtual.yaml").read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["run"]["output_dir"] = str(tmp_path / "runs")
    data["run"]["figures"] = False  # the screen is what is checked, not the report's figures
    data["sim"]["faults"] = [{"target": "stand", "kind": "stand_fault", "after_motion_s": 2.0,
                              "params": {"code": 2}}]
    cfg = tmp_path / "bench.yaml"
    cfg.write_text(yaml.safe_dump(data))
    code = main(["run", "--config", str(cfg), "--profile", str(ROOT / "profiles/ci_short.yaml"),
                 "--serial", "20260001", "--operator", "ci", "--duration", "20"])
    out = capsys.readouterr().out
    print(out)
    assert code == 2 and "stand fault 2" in out
    tail = out.strip().splitlines()[-4:]
    assert tail[0].startswith("  stand: roll ") and "fault 2 (" in tail[0], tail
    assert "NOT at zero" in tail[0]
    assert tail[1:] == ["  to bring it to rest at zero, in this order:",
                        f"    benchctl stand reset --config {cfg}",
                        f"    benchctl stand home --config {cfg}"]
