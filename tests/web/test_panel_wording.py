"""The panel's own words for what a run says (``benchctl.web.wording``): an abort's headline,
the stand's state and what to do next composed from the record's structured fields, the run's
messages and the form's refusals — in English and in Russian, the run's English kept as the
detail. One real run on simulated time, aborted by a stand fault, checks every message it
publishes and its verdict screen."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml
from panel import SHORT_PROFILE, child_env
from repo_paths import ROOT

from benchctl.run import fitness
from benchctl.run.result import stand_after
from benchctl.text import SERIAL_MAX
from benchctl.web.panelrun import Run, outcome
from benchctl.web.wording import Words

RU, EN = Words("ru"), Words("en")


def final(roll: float, rate: float = 0.0, *, code: int = 0, estop: bool = False,
          enabled: bool = False) -> dict[str, Any]:
    """A stand's final state as the abort's cleanup reads it."""
    return {"angle_deg": {"roll": roll, "pitch": 0.0}, "rate_deg_s": {"roll": rate, "pitch": 0.0},
            "enabled": enabled, "fault_code": code, "fault_text": "overtemp" if code else "",
            "estop": estop}


def test_the_stands_state_from_its_fields_with_numbers_in_the_language() -> None:
    stand = stand_after(final(3.0, code=42), zero_tolerance_deg=0.05, config="b.yaml")
    assert EN.stand_sentence(stand) == (
        "Stand: roll +3.000°, pitch +0.000°. At rest. Servo off. Fault 42. NOT at zero.")
    assert RU.stand_sentence(stand) == (
        "Стенд: крен +3,000°, дифферент +0,000°. В покое. Привод выключен. Неисправность 42. "
        "НЕ в нуле.")
    moving = stand_after(final(-0.5, rate=2.0, estop=True, enabled=True),
                         zero_tolerance_deg=0.05, config="b.yaml")
    assert RU.stand_sentence(moving) == (
        "Стенд: крен -0,500°, дифферент +0,000°. ДВИЖЕТСЯ. Привод включён. Нажата аварийная "
        "остановка. НЕ в нуле.")
    rest = stand_after(final(0.01), zero_tolerance_deg=0.05, config="b.yaml")
    assert RU.stand_sentence(rest).endswith("В покое. Привод выключен. В нуле.")
    silent = stand_after(None, zero_tolerance_deg=0.05, config="b.yaml")
    assert RU.stand_sentence(silent).startswith("Положение стенда неизвестно")
    never = stand_after(None, zero_tolerance_deg=0.05, config="b.yaml", known=False)
    assert RU.stand_sentence(never) == "Стенд не был подключён: он не двигался."


@pytest.mark.parametrize(("abort", "en", "ru"), [
    ({"kind": "operator", "source": "signal", "error": "SafetyAbort",
      "reason": "signal: interrupted by SIGINT"},
     "Stopped by the operator (Stop, or Ctrl-C at the terminal).",
     "Остановлено оператором (кнопка «Стоп» или Ctrl-C в терминале)."),
    ({"kind": "operator", "source": "signal", "error": "SafetyAbort",
      "reason": "signal: interrupted by SIGTERM"},
     "Stopped by a signal from the computer (SIGTERM).",
     "Остановлено сигналом от компьютера (SIGTERM)."),
    ({"kind": "equipment", "source": "stand loop", "error": "StandFault",
      "reason": "stand loop: StandFault: stand fault 42", "stand": {"fault_code": 42}},
     "The stand reported fault 42.", "Стенд сообщил о неисправности 42."),
    ({"kind": "equipment", "source": "stand loop", "error": "StandFault",
      "reason": "stand loop: StandFault: stand reports E-stop", "stand": {"estop": True}},
     "The stand's emergency stop (E-stop) was pressed.",
     "Нажата аварийная остановка стенда (E-stop)."),
    ({"kind": "equipment", "source": "run", "error": "SafetyAbort",
      "reason": "run: instrument silent: no sample for 2.60 s (silence_timeout_s = 2.0 s)"},
     "The instrument went silent: no sample in time.",
     "Прибор замолчал: отсчёты не поступают."),
    ({"kind": "equipment", "source": "stand loop", "error": "SafetyAbort",
      "reason": "stand loop: tracking error on roll: +0.612° (measured − stand setpoint) "
                "beyond ±0.5° (stand.tracking_tolerance_deg)"},
     "The stand did not follow its setpoint (tracking error).",
     "Стенд не отрабатывал задание (ошибка слежения)."),
    ({"kind": "equipment", "source": "run", "error": "PrecheckFailed",
      "reason": "run: precheck 'serial match' failed: typed 1, reported 2"},
     "A check before the motion failed: the serial matches the unit's.",
     "Не пройдена проверка перед движением: серийный номер совпадает с номером прибора."),
    ({"kind": "equipment", "source": "instrument reader", "error": "ConnectionLost",
      "reason": "instrument reader: ConnectionLost: slcan0 gone"},
     "The connection to the instrument was lost.", "Связь с прибором потеряна."),
    ({"kind": "equipment", "source": "recording", "error": "RecordingError",
      "reason": "recording: disk full: cannot write stand.csv (ENOSPC)"},
     "The disk is full: the recording could not be written.",
     "Диск заполнен: запись не удалось сохранить."),
    ({"kind": "software", "source": "run (exception)", "error": "ZeroDivisionError",
      "reason": "run (exception): unexpected ZeroDivisionError: division by zero"},
     "A software error stopped the run.", "Испытание остановлено из-за ошибки программы."),
], ids=["SIGINT", "SIGTERM", "fault", "E-stop", "silent", "tracking", "precheck",
        "connection", "disk-full", "software"])
def test_an_aborts_headline_from_its_kind_source_and_error(abort: dict[str, Any], en: str,
                                                           ru: str) -> None:
    assert EN.abort_headline(abort, abort["reason"]) == en
    assert RU.abort_headline(abort, abort["reason"]) == ru
    assert RU.abort_advice(abort, abort["reason"])  # what to do next, in Russian too


def test_the_verdict_screen_in_russian_keeps_the_runs_english_as_details(
        tmp_path: Path) -> None:
    stand = stand_after(final(3.0, code=42), zero_tolerance_deg=0.05, config="b.yaml")
    reason = "stand loop: StandFault: stand fault 42 (<b>overtemp</b>)"
    run = Run(1, "SN", "op", "short", tmp_path)
    run.exit_code = 2
    run.result = {"verdict": "ABORTED", "state": "aborted", "reason": reason,
                  "abort": {"kind": "equipment", "source": "stand loop", "error": "StandFault",
                            "reason": reason, "stand": stand},
                  "measured": {"verdict": "PASS"}}
    o = outcome(run, RU)
    assert o["word"] == "ПРЕРВАНО" and o["headline"] == "Стенд сообщил о неисправности 42."
    assert o["detail"] == reason and o["details_label"] == "Подробности"  # verbatim
    assert o["stand_text"].startswith("Стенд: крен +3,000°")
    assert o["stand_detail"] == stand["text"]  # the run's own description, as a detail
    assert o["next"] == stand["commands"] and o["advice"].startswith("Найдите и устраните")
    assert o["measured_word"] == "ГОДЕН"


def test_a_run_that_did_not_start_or_left_no_result(tmp_path: Path) -> None:
    run = Run(4, "SN", "op", "short", tmp_path)
    run.exit_code, run.error, run.refused = 2, "stand x is in use by benchctl run", True
    o = outcome(run, RU)
    assert o["headline"] == "Стенд занят: запуск отклонён, стенд не двигался"
    assert o["detail"] == run.error and o["word"] == "НЕ ЗАПУЩЕНО"
    run = Run(5, "SN", "op", "short", tmp_path)
    run.exit_code = 9
    assert outcome(run, RU)["headline"] == (
        "Испытание завершилось (код выхода 9) без результата.")


def test_the_runs_fixed_messages_and_those_of_a_known_form() -> None:
    assert RU.message(fitness.SKIP_VIRTUAL) == {
        "text": "Модельное время: временные характеристики компьютера не измеряются.",
        "detail": ""}
    assert RU.message(fitness.SKIP_DISABLED)["text"].startswith("Временные характеристики")
    assert RU.message("PASS: recording closed") == {"text": "ГОДЕН: запись закрыта.",
                                                    "detail": ""}
    got = RU.message("precheck static agreement: FAILED — roll: 0.8°")
    assert got == {"text": "Проверка перед движением: стенд и прибор согласуются в покое — "
                           "НЕ ПРОЙДЕНА.", "detail": "roll: 0.8°"}
    assert RU.message("step warm-up: FAIL (σ over the limit)") == {
        "text": "Шаг warm-up: НЕ ГОДЕН.", "detail": "σ over the limit"}
    assert RU.message("setup 1: declined — answered no: Clear?") == {
        "text": "Подготовительное действие 1: ответ «нет».", "detail": "answered no: Clear?"}
    # one the panel does not know: the run's words alone, as a detail
    assert RU.message("<b>σ roll 0.2° ±3 %</b>") == {"text": "",
                                                     "detail": "<b>σ roll 0.2° ±3 %</b>"}


def test_the_forms_refusals() -> None:
    assert RU.refused_text("serial", "  ", SERIAL_MAX) == "Введите или отсканируйте серийный номер."
    assert RU.refused_text("serial", "01\x1d21", SERIAL_MAX).startswith("Скан содержит")
    assert RU.refused_text("serial", "x" * 65, SERIAL_MAX) == (
        "Серийный номер слишком длинный: не более 64 символов.")
    assert RU.refused_text("serial", "ABC", SERIAL_MAX, r"\d{8}") == (
        "Серийный номер не соответствует форме, принятой на этом посту (\\d{8}).")
    assert RU.refused_text("operator", "a\x07", 128) == (
        "Имя содержит непечатаемый символ: введите его снова.")


@pytest.mark.slow  # a whole run on simulated time (seconds), its child process
def test_every_message_of_an_aborted_run_has_the_panels_words(tmp_path: Path) -> None:
    """A real run stopped by a stand fault (code 42) mid-motion, published on the live channel
    as the panel receives it: each message it publishes has the panel's Russian words, and its
    verdict screen is composed from its record's fields."""
    data = yaml.safe_load((ROOT / "config/sim_virtual.yaml").read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["run"]["output_dir"] = str(tmp_path / "runs")
    data["sim"]["stand"]["faults"] = [{"kind": "stand_fault", "after_s": 20.0, "code": 42}]
    cfg = tmp_path / "bench.yaml"
    cfg.write_text(yaml.safe_dump(data))
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(tmp_path / "live.sock"))
    sock.settimeout(0.5)
    with (tmp_path / "result.json").open("wb") as out, \
            (tmp_path / "stderr.txt").open("wb") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "benchctl", "run", "--config", str(cfg), "--profile",
             str(SHORT_PROFILE), "--serial", "20260001", "--operator", "demo", "--duration",
             "30", "--json", "--quiet", "--live", str(tmp_path / "live.sock")],
            stdout=out, stderr=err, env=child_env(), cwd=tmp_path)
        messages: list[str] = []
        try:
            while True:
                try:
                    msg = json.loads(sock.recv(65536))
                except TimeoutError:
                    if proc.poll() is not None:
                        break
                    continue
                if msg.get("kind") == "message":
                    messages.append(msg["text"])
        finally:
            sock.close()
            if proc.poll() is None:
                os.kill(proc.pid, 9)
            proc.wait(60)
    assert proc.returncode == 2, (tmp_path / "stderr.txt").read_text()[-2000:]
    assert any(m.startswith("ABORTED: ") for m in messages), messages
    assert any(m.startswith("  ramp to zero: ") for m in messages), messages
    untold = [m for m in messages if not RU.message(m)["text"]]
    assert untold == [], untold
    run = Run(1, "20260001", "demo", "short", tmp_path)
    run.exit_code = proc.returncode
    run.result = json.loads((tmp_path / "result.json").read_text())
    o = outcome(run, RU)
    assert o["headline"] == "Стенд сообщил о неисправности 42."
    assert "stand fault 42" in o["detail"]  # the run's English, kept as the detail
    assert o["stand_text"].startswith("Стенд: крен +") and "Неисправность 42." in o["stand_text"]
    assert "НЕ в нуле." in o["stand_text"]
    assert o["next"][0].startswith("benchctl stand reset")
