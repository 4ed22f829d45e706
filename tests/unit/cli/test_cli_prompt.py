"""The serial and operator of ``benchctl run`` and ``benchctl plan``: Ctrl-D (end of input) at
a prompt ends the command saying so, with nothing run; a blank serial is refused, and one not
of the config's ``unit.serial_pattern``, naming the option, the value and the pattern."""

from __future__ import annotations

import io
import os
import re
import select
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from repo_paths import ROOT
from terminal import on_terminal

from benchctl import text
from benchctl.cli import main
from benchctl.cli.run import ask_value
from benchctl.errors import InputError
from benchctl.run.prepare import RunOptions
from benchctl.text import check_serial


class Tty(io.StringIO):
    """A terminal's stream: text in memory that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def _cfg(tmp_path: Path, **unit: Any) -> Path:
    data = {
        "station": "cli-test",
        "unit": unit,
        "stand": {"driver": "modbus-tcp", "host": "127.0.0.1", "port": 1,
                  "limits": {"angle_deg": 20.0, "rate_deg_s": 30.0, "accel_deg_s2": 100.0}},
        "instrument": {"driver": "nmea0183", "serial_port": "/nonexistent/tty"},
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp_path / "runs")},
    }
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.mark.parametrize("typed", ["", "SN-", "\n\n"], ids=["at-once", "mid-line", "after-blanks"])
def test_eof_at_the_prompt_says_the_input_ended(monkeypatch: pytest.MonkeyPatch,
                                                typed: str) -> None:
    stdin, stderr = Tty(typed), Tty()
    monkeypatch.setattr("sys.stdin", stdin)
    monkeypatch.setattr("sys.stderr", stderr)
    with pytest.raises(InputError) as e:
        # a line cut by Ctrl-D ("SN-" without its newline) is refused, then the input ends
        ask_value(None, "Serial number of the instrument", "--serial",
                  lambda v, o: check_serial(v, o, "SN-[0-9]+"))
    msg = str(e.value)
    assert msg == ("--serial: the input ended (EOF, Ctrl-D) at the prompt for the serial number "
                   "of the instrument; nothing was run")
    assert "no terminal" not in msg
    assert stderr.getvalue().endswith("Serial number of the instrument: \n")


def test_no_terminal_still_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("sys.stdin", io.StringIO(""))
    monkeypatch.setattr("sys.stderr", io.StringIO())
    with pytest.raises(InputError, match=r"^--operator is required \(the operator\); no "
                                         r"terminal to ask on$"):
        ask_value(None, "Operator", "--operator")


# a pseudo-terminal in this process (terminal.on_terminal), nothing timed: not realtime (as
# test_plan_consent's prompts on a pty). What main() wrote on the terminal is read at the
# master end until its last line has come through (the kernel hands a pty's output over to the
# other end a moment later: on a loaded machine, not always within a fixed short wait)
@pytest.mark.parametrize("command", ["run", "plan"])
def test_ctrl_d_at_the_serial_prompt_runs_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    command: str,
) -> None:
    cfg = _cfg(tmp_path)
    if command == "run":
        argv = ["run", "--config", str(cfg), "--profile", str(ROOT / "profiles/ci_short.yaml"),
                "--operator", "ana"]
    else:
        plan = tmp_path / "plan.yaml"
        plan.write_text(yaml.safe_dump({
            "name": "p", "config": str(cfg), "operator": "ana",
            "steps": [{"name": "s", "profile": str(ROOT / "profiles/ci_short.yaml")}]}))
        argv = ["plan", str(plan), "--yes"]
    last = (f"benchctl {command}: error: --serial: the input ended (EOF, Ctrl-D) at the prompt "
            "for the serial number of the instrument; nothing was run")
    with on_terminal(monkeypatch) as master:
        os.write(master, b"\x04")  # Ctrl-D on an empty line: the terminal's end of file
        code = main(argv)
        seen = b""
        deadline = time.monotonic() + 60.0
        while not seen.endswith(b"nothing was run\r\n") and time.monotonic() < deadline:
            if select.select([master], [], [], 0.1)[0]:
                seen += os.read(master, 4096)
    out = seen.decode("utf-8", "replace")
    assert code == 2
    assert "Serial number of the instrument: " in out
    assert last in out
    assert "no terminal" not in out
    assert not capsys.readouterr().out
    assert not (tmp_path / "runs").exists()  # nothing opened: no recording, no plan folder


# ---------------------------------------------------------- blank serials, serial_pattern
WHITESPACE = " \t\r\n\x0b\x0c\x1c\x1d\x1e\x1f\x85\xa0\u1680\u2000\u2007\u2028\u2029\u3000"
BLANK = st.text(st.sampled_from(WHITESPACE), min_size=1, max_size=40)


@settings(max_examples=100, deadline=None)
@given(BLANK)
def test_a_blank_serial_is_refused_naming_the_option_and_the_value(blank: str) -> None:
    assert blank.strip() == ""
    for option in ("--serial", "serial"):
        with pytest.raises(InputError) as e:
            check_serial(blank, option)
        msg = str(e.value)
        assert msg == (f"{option} {text.shown(blank)}: blank (only whitespace); expected the "
                       "serial number")
        assert "\n" not in msg and "\r" not in msg  # the value shown, never acted on
    with pytest.raises(InputError, match=r"^serial '.*': blank \(only whitespace\)"):
        RunOptions(blank, "ana")


# a serial of the form the pattern below asks for, with whitespace around it (a scanner's)
PATTERN = r"INC-[0-9]{4}"
FITS = st.builds(lambda a, d, b: f"{a}INC-{d:04d}{b}",
                 st.text(st.sampled_from(" \t\r\n"), max_size=3), st.integers(0, 9999),
                 st.text(st.sampled_from(" \t\r\n"), max_size=3))


@settings(max_examples=100, deadline=None)
@given(FITS)
def test_a_serial_of_the_pattern_is_taken_without_its_whitespace(serial: str) -> None:
    assert check_serial(serial, "--serial", PATTERN) == serial.strip()


@settings(max_examples=150, deadline=None)
@given(st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=20))
def test_a_serial_not_of_the_pattern_is_refused_naming_the_pattern(serial: str) -> None:
    s = serial.strip()
    if re.fullmatch(PATTERN, s):
        assert check_serial(serial, "--serial", PATTERN) == s
        return
    with pytest.raises(InputError) as e:
        check_serial(serial, "--serial", PATTERN, "unit.serial_pattern of bench.yaml")
    msg = str(e.value)
    assert msg.startswith("--serial ")
    if text.problem(s, text.SERIAL_MAX, "serial number") is None:  # printable: the pattern
        assert msg == (f"--serial {text.shown(s)}: does not match the serial pattern "
                       f"'{PATTERN}' (unit.serial_pattern of bench.yaml); expected a serial "
                       "number of that form")


def _run_cli(tmp_path: Path, *extra: str, **unit: Any) -> int:
    return main(["run", "--config", str(_cfg(tmp_path, **unit)), "--profile",
                 str(ROOT / "profiles/ci_short.yaml"), *extra])


@pytest.mark.parametrize("serial", ["   ", "\t", "", " \r\n"], ids=["spaces", "tab", "empty",
                                                                     "crlf"])
def test_run_and_plan_refuse_a_blank_serial_before_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], serial: str,
) -> None:
    """Before, `--serial '   '` ran and was archived as `…_unnamed`; `--serial ''` asked for
    one (or, with no terminal, said it was missing)."""
    assert _run_cli(tmp_path, "--serial", serial, "--operator", "ana") == 2
    err = capsys.readouterr().err
    said = (f"--serial {text.shown(serial)}: blank (only whitespace); expected the serial "
            "number") if serial else "--serial '': expected the serial number, got nothing"
    assert err == f"benchctl run: error: {said}\n"
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({
        "name": "p", "config": str(_cfg(tmp_path)), "operator": "ana",
        "steps": [{"name": "s", "profile": str(ROOT / "profiles/ci_short.yaml")}]}))
    assert main(["plan", str(plan), "--yes", "--serial", serial]) == 2
    assert capsys.readouterr().err == f"benchctl plan: error: {said}\n"
    assert not (tmp_path / "runs").exists()  # no recording, no plan folder, no archive


def test_run_refuses_a_serial_not_of_the_config_pattern(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    assert _run_cli(tmp_path, "--serial", " INC-42 ", "--operator", "ana",
                    serial_pattern=PATTERN) == 2
    assert capsys.readouterr().err == (
        f"benchctl run: error: --serial 'INC-42': does not match the serial pattern "
        f"'{PATTERN}' (unit.serial_pattern of {tmp_path / 'bench.yaml'}); expected a serial "
        "number of that form\n")
    assert not (tmp_path / "runs").exists()


def test_serial_pattern_in_the_config_schema() -> None:
    from benchctl.config import UnitConfig

    field = UnitConfig.model_fields["serial_pattern"]
    assert field.default is None
    assert UnitConfig(serial_pattern=PATTERN).serial_pattern == PATTERN
    with pytest.raises(ValidationError, match="expected a regular expression"):
        UnitConfig(serial_pattern="INC-[0-9")
    with pytest.raises(ValidationError):
        UnitConfig(serial_pattern="")
