"""The serial and operator prompts of ``benchctl run`` and ``benchctl plan``: Ctrl-D (end of
input) at a prompt ends the command saying so, with nothing run."""

from __future__ import annotations

import io
import os
import select
from pathlib import Path
from typing import Any

import pytest
import yaml
from terminal import on_terminal

from benchctl.cli import main
from benchctl.cli.run import ask_value
from benchctl.errors import InputError
from benchctl.text import check_serial

ROOT = Path(__file__).resolve().parent.parent


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


@pytest.mark.realtime  # a pseudo-terminal
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
    with on_terminal(monkeypatch) as master:
        os.write(master, b"\x04")  # Ctrl-D on an empty line: the terminal's end of file
        code = main(argv)
        seen = b""
        while select.select([master], [], [], 0.2)[0]:
            seen += os.read(master, 4096)
    out = seen.decode("utf-8", "replace")
    assert code == 2
    assert "Serial number of the instrument: " in out
    assert (f"benchctl {command}: error: --serial: the input ended (EOF, Ctrl-D) at the prompt "
            "for the serial number of the instrument; nothing was run") in out
    assert "no terminal" not in out
    assert not capsys.readouterr().out
    assert not (tmp_path / "runs").exists()  # nothing opened: no recording, no plan folder
