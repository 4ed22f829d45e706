"""A plan's prompts answered on the panel (``benchctl.web.prompts``): the question published
(and again while it waits), the answer read from the file the panel writes, no answer in time
an unanswered prompt (``TimeoutError``)."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
from panel import live_socket

from benchctl.web.live import LivePublisher
from benchctl.web.prompts import PanelAsker


def test_the_answer_file_answers_the_question(tmp_path: Path) -> None:
    answers = tmp_path / "answers"
    answers.mkdir()
    with live_socket(tmp_path, 10.0) as sock:
        asker = PanelAsker(LivePublisher(tmp_path / "live.sock"), answers, timeout_s=60)

        def panel() -> None:  # what the server does when the operator presses a button
            for qid, word in enumerate(("yes", "no")):
                msg = json.loads(sock.recv(65536))
                assert msg == {**msg, "kind": "prompt", "id": qid}
                (answers / f"prompt-{qid}.part").write_text(word)
                (answers / f"prompt-{qid}.part").rename(answers / f"prompt-{qid}.answer")
                while msg["kind"] != "prompt_closed":
                    msg = json.loads(sock.recv(65536))
                assert msg["why"] == word

        t = threading.Thread(target=panel)
        t.start()
        assert asker("Is the instrument mounted?") is True
        assert asker("Is the area clear?") is False
        t.join(30)
    assert list(answers.iterdir()) == []  # each answer taken once


def test_no_answer_in_time_is_unanswered(tmp_path: Path) -> None:
    with live_socket(tmp_path, 10.0) as sock:
        asker = PanelAsker(LivePublisher(tmp_path / "live.sock"), tmp_path, timeout_s=2.5)
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match=r"no answer on the panel within 2\.5 s"):
            asker("Is the area clear?")
        assert time.monotonic() - t0 >= 2.5
        kinds = []
        sock.settimeout(0.5)
        while True:
            try:
                kinds.append(json.loads(sock.recv(65536))["kind"])
            except TimeoutError:
                break
    assert kinds[0] == "prompt" and kinds.count("prompt") >= 2  # sent again while it waited
    assert kinds[-1] == "prompt_closed"
