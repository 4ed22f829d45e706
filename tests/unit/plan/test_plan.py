"""Acceptance plans without a bench: the plan file's validation (errors naming the file, the
field, the value and the expectation), the refusals before anything opens (prompts with no
terminal and no --yes, a step's profile over the stand limits, limits that do not fit the
config), a setup prompt answered no (nothing moves, cleanup still runs, exit 2), the terminal
prompt, and the shipped plans."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from junitparser import Error, Failure, JUnitXml, Skipped
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.errors import ConfigError, DataError, InputError, LimitError
from benchctl.plan import load_plan, parse_plan, run_plan
from benchctl.plan.prompts import terminal_asker
from benchctl.plan.record import load_plan_record

# a bench config whose stand is not there: nothing in these tests may reach it
BENCH = {
    "station": "unit",
    "stand": {
        "driver": "modbus-tcp",
        "host": "127.0.0.1",
        "port": 9,  # discard: nothing listens
        "timeout_s": 0.5,
        "register_map": str(ROOT / "drivers/stand_generic.yaml"),
        "limits": {"angle_deg": 30, "rate_deg_s": 30, "accel_deg_s2": 60},
    },
    "instrument": {
        "driver": "canopen",
        "interface": "slcan",
        "channel": "/nonexistent/slcan0",
        "eds": str(ROOT / "drivers/cia410_inclinometer.eds"),
    },
    "run": {"limit_sigma_deg": 0.4, "limits": {"gain_max": 1.0}},
}


def _plan(**over: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "name": "unit_plan",
        "config": "bench.yaml",
        "operator": "tester",
        "steps": [{"name": "roll", "profile": str(ROOT / "profiles/ci_short.yaml")}],
    }
    data.update(over)
    return data


def _write(tmp_path: Path, data: dict[str, Any]) -> Path:
    (tmp_path / "bench.yaml").write_text(yaml.safe_dump(BENCH))
    p = tmp_path / "plan.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


@pytest.mark.parametrize(
    ("over", "words"),
    [
        ({"colour": "red"}, ["field colour = 'red'", "Extra inputs"]),
        ({"steps": []}, ["field steps", "at least 1"]),
        ({"steps": [{"name": "a", "profile": "x.yaml", "on_fail": "ignore"}]},
         ["field steps[0].on_fail = 'ignore'", "'stop' or 'continue'"]),
        ({"steps": [{"name": "a", "profile": "x.yaml", "timeout_s": -5}]},
         ["field steps[0].timeout_s = -5", "greater than 0"]),
        ({"steps": [{"name": "a", "profile": "x.yaml",
                     "limits": {"gain_min": 1.0, "gain_max": 0.99}}]},
         ["steps[0].limits", "gain_min = 1: expected below gain_max (0.99)"]),
        ({"steps": [{"name": "a", "profile": "x.yaml", "limits": {"sigma": 0.4}}]},
         ["field steps[0].limits.sigma = 0.4", "Extra inputs"]),
        ({"steps": [{"name": "a", "profile": "x.yaml"}, {"name": "a", "profile": "y.yaml"}]},
         ["steps[1].name = 'a': expected a name no other step has"]),
        ({"setup": [{}]}, ["field setup[0]", "prompt and/or check"]),
        ({"cleanup": [{"check": "levitate"}]},
         ["field cleanup[0].check = 'levitate'", "'stand_at_rest' or 'ramp_to_zero'"]),
        ({"timeout_s": float("nan")}, ["field timeout_s = nan"]),
        ({"steps": [{"name": "a", "profile": "x.yaml", "decision_rule": "lenient"}]},
         ["field steps[0].decision_rule = 'lenient'", "'simple' or 'guarded'"]),
    ],
)
def test_plan_file_errors_name_file_field_value_and_expectation(
    tmp_path: Path, over: dict[str, Any], words: list[str]
) -> None:
    p = _write(tmp_path, _plan(**over))
    with pytest.raises(ConfigError) as e:
        load_plan(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: invalid plan: "), msg
    for w in words:
        assert w in msg, msg


def test_plan_file_not_a_mapping_and_not_yaml(tmp_path: Path) -> None:
    p = tmp_path / "plan.yaml"
    p.write_text("- just\n- a list\n")
    with pytest.raises(ConfigError, match="expected a YAML mapping at the top level, got list"):
        load_plan(p)
    p.write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_plan(p)


def test_paths_resolve_against_the_plan_file(tmp_path: Path) -> None:
    p = _write(tmp_path, _plan(steps=[{"name": "a", "profile": "profiles/x.yaml"}]))
    plan = load_plan(p)
    assert plan.config == (tmp_path / "bench.yaml").resolve()
    assert plan.steps[0].profile == (tmp_path / "profiles/x.yaml").resolve()
    assert plan.steps[0].on_fail == "stop" and plan.steps[0].timeout_s is None


def test_shipped_plans_are_valid_and_of_the_same_shape() -> None:
    paper = load_plan(ROOT / "plans/paper_procedure.yaml")
    ci = load_plan(ROOT / "plans/ci_short.yaml")
    assert [s.name for s in paper.steps] == [s.name for s in ci.steps]
    assert [s.profile.name for s in paper.steps] == [
        "linearity_sine_steps.yaml", "paper_vessel_roll.yaml"]
    assert [s.profile.name for s in ci.steps] == ["ci_sine_steps.yaml", "ci_short.yaml"]
    lin = paper.steps[0].limits
    assert (lin.gain_min, lin.gain_max, lin.linearity_spread) == (0.990, 1.000, 0.01)
    assert paper.steps[1].limits.sigma_deg == 0.4
    for plan in (paper, ci):
        assert plan.config is not None and plan.config.is_file()
        assert all(s.profile.is_file() for s in plan.steps)
        assert [a.check for a in plan.cleanup if a.check] == ["ramp_to_zero"]
        assert plan.prompts


def test_prompts_without_a_terminal_or_yes_are_refused_before_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    p = _write(tmp_path, _plan(setup=[{"prompt": "Area clear?", "check": "stand_at_rest"}]))
    out = tmp_path / "out"
    with pytest.raises(InputError, match="no terminal to answer them on: answer them with --yes"):
        run_plan(p, serial="SN1", out_dir=out)
    monkeypatch.setattr("sys.stdin", io.StringIO("y\n"))  # not a terminal: never read
    code = main(["plan", str(p), "--serial", "SN1", "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert "operator prompt(s) and there is no terminal" in err
    assert not out.exists()  # no plan folder, no recording: nothing opened


def test_a_step_over_the_stand_limits_is_refused_before_anything(tmp_path: Path) -> None:
    steep = tmp_path / "steep.yaml"
    steep.write_text((ROOT / "profiles/ci_sine_steps.yaml").read_text().replace(
        "amplitudes_deg: [2, 4]", "amplitudes_deg: [2, 25]"))
    p = _write(tmp_path, _plan(steps=[
        {"name": "fine", "profile": str(ROOT / "profiles/ci_short.yaml")},
        {"name": "steep", "profile": str(steep)},
    ]))
    out = tmp_path / "out"
    with pytest.raises(LimitError) as e:
        run_plan(p, serial="SN1", yes=True, out_dir=out)
    assert "step 'steep'" in str(e.value) and "exceeds the stand limits" in str(e.value)
    assert not out.exists()


def test_step_limits_that_do_not_fit_the_config_are_refused(tmp_path: Path) -> None:
    # the bench config sets gain_max 1.0: a step's gain_min of 1.05 cannot be met
    p = _write(tmp_path, _plan(steps=[{"name": "g", "profile": str(ROOT / "profiles/ci_short.yaml"),
                                       "limits": {"gain_min": 1.05}}]))
    with pytest.raises(ConfigError, match=r"step 'g': its limits do not fit .*gain_min = 1.05"):
        run_plan(p, serial="SN1", yes=True, out_dir=tmp_path / "out")


def test_setup_declined_moves_nothing_runs_cleanup_and_exits_2(tmp_path: Path) -> None:
    """The operator answers no to 'area clear?': no step runs, the stand is never touched (its
    config points nowhere: any stand action would fail), the cleanup runs — its ramp skipped,
    its prompt asked — and the JUnit XML and plan.json say so."""
    p = _write(tmp_path, _plan(
        setup=[{"prompt": "Instrument mounted?"}, {"prompt": "Area clear?",
                                                   "check": "stand_at_rest"}],
        steps=[{"name": "one", "profile": str(ROOT / "profiles/ci_short.yaml")},
               {"name": "two", "profile": str(ROOT / "profiles/ci_sine_steps.yaml")}],
        cleanup=[{"check": "ramp_to_zero"}, {"prompt": "Remove the instrument"}],
    ))
    asked: list[str] = []

    def ask(text: str) -> bool:
        asked.append(text)
        return text != "Area clear?"

    res = run_plan(p, serial="SN1", ask=ask, out_dir=tmp_path / "out",
                   junit=tmp_path / "j.xml")
    assert asked == ["Instrument mounted?", "Area clear?", "Remove the instrument"]
    assert (res.outcome, res.exit_code) == ("ABORTED", 2)
    assert "answered no to 'Area clear?'" in res.reason
    assert [s.status for s in res.steps] == ["SKIPPED", "SKIPPED"]
    assert all(s.recording is None for s in res.steps)
    assert [a.status for a in res.setup] == ["ok", "declined"]
    assert [a.status for a in res.cleanup] == ["skipped", "ok"]
    assert not list((tmp_path / "out").glob("2*"))  # no recording
    rec = load_plan_record(res.record_path or "")
    assert rec["outcome"] == "ABORTED" and rec["exit_code"] == 2
    xml = JUnitXml.fromfile(str(tmp_path / "j.xml"))
    kinds: dict[str, list[str]] = {}
    for suite in xml:
        kinds[suite.name] = [type(r).__name__ for c in suite for r in c.result] or ["pass"]
    assert kinds == {"setup": ["Failure"], "one": ["Skipped"], "two": ["Skipped"],
                     "cleanup": ["Skipped"]}
    assert (xml.tests, xml.failures, xml.errors, xml.skipped) == (6, 1, 0, 3)
    assert all(isinstance(r, Failure | Skipped | Error) for s in xml for c in s for r in c.result)


def test_terminal_prompt_reads_yes_or_no() -> None:
    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    err = Tty()
    ask = terminal_asker(Tty("y\nno\n\nYES\n"), err)
    assert ask is not None
    assert [ask("Area clear?") for _ in range(4)] == [True, False, False, True]
    assert err.getvalue().count("Area clear? [y/N]: ") == 4
    assert terminal_asker(io.StringIO(""), err) is None  # stdin not a terminal


def test_parse_plan_refuses_a_source_key() -> None:
    with pytest.raises(ConfigError, match="field source: not a plan field"):
        parse_plan(_plan(source="x"))


def test_schema_command_prints_the_plan_schema(capsys: pytest.CaptureFixture[str]) -> None:
    from jsonschema import Draft202012Validator

    from benchctl.plan.record import plan_schema, validate_plan_record

    assert main(["schema", "plan"]) == 0
    schema = json.loads(capsys.readouterr().out)
    Draft202012Validator.check_schema(schema)
    assert schema == plan_schema()
    assert schema["properties"]["schema"]["const"] == "benchctl-plan/1"
    # a record the schema refuses: named where and what
    bad = {"schema": "benchctl-plan/1", "steps": [{"status": "GREEN"}]}
    with pytest.raises(DataError, match="plan record not valid against benchctl-plan/1"):
        validate_plan_record(bad)


def test_terminal_prompt_times_out_and_ends_at_eof_or_a_hung_up_terminal() -> None:
    import contextlib
    import os
    import pty
    import time

    master, slave = pty.openpty()
    tin = open(slave, encoding="utf-8", closefd=False)  # noqa: SIM115
    tout = open(slave, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
    try:
        ask = terminal_asker(tin, tout, timeout_s=0.3)
        assert ask is not None
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match=r"no answer within 0.3 s"):
            ask("Area clear?")
        assert time.monotonic() - t0 < 30
        os.write(master, b"yes\n")
        assert ask("Area clear?") is True
        os.write(master, b"\x04")  # Ctrl-D
        with pytest.raises(EOFError, match="end of input"):
            ask("Area clear?")
        os.close(master)  # the terminal hangs up
        master = -1
        with pytest.raises(EOFError):
            ask("Area clear?")
    finally:
        tin.close()
        with contextlib.suppress(OSError):  # a hung-up terminal refuses the last flush
            tout.close()
        os.close(slave)
        if master >= 0:
            os.close(master)
