"""The station panel in a real browser: the distribution's Chromium driven by Playwright
(``executable_path``: no browser download), ``benchctl serve`` a real child process starting
real runs. A run to its verdict by keyboard alone (simulated time: a child run that finishes in
seconds), Stop during a real-time run (ABORTED, the stand at rest), the login page; no page
logs an error to its console."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import psutil
import pytest
from browser import chromium
from owned_trees import OWNED_ROOTS
from panel import free_port, get_json, post_json, serve, sim_virtual_without_figures, wait_for
from playwright.sync_api import Browser as PwBrowser
from playwright.sync_api import Page, sync_playwright
from repo_paths import ROOT

from benchctl.web.security import hash_token

# in a real browser, its server and the run it starts as child processes; the runs on
# simulated time (config/sim_virtual.yaml); the panel killed and started again mid-run is
# ``realtime`` (a real SIGKILL and a restart while its run goes on)
pytestmark = pytest.mark.slow

HOSTILE_OPERATOR = '<img src=x onerror="window.pwned=1">'
TOKEN = "a long enough access token"


class Browser:
    """A page in a browser context of its own (the module's headless Chromium), and every
    console error or uncaught exception of every page that context opened."""

    def __init__(self, page: Page, errors: list[str]) -> None:
        self.page = page
        self.errors = errors

    def text(self, selector: str) -> str:
        return str(self.page.text_content(selector) or "")

    def visible(self, selector: str) -> bool:
        return bool(self.page.is_visible(selector))

    def focused(self) -> str:
        return str(self.page.evaluate("document.activeElement && document.activeElement.id"))


@pytest.fixture(scope="module")
def chromium_browser() -> Iterator[PwBrowser]:
    """One headless Chromium for the module (its launch is a second or two of each test's
    time); each test gets a context of its own in it (below): its own cookies, storage and
    pages, as a fresh browser would have."""
    roots: set[int] = set()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium(), args=["--no-sandbox"])
        try:
            # Chromium starts its GPU process and its network and storage services with the
            # first page and keeps them: started here, they are the module's, not a test's
            # (every test is checked for the child processes it leaves behind)
            warm = b.new_context()
            warm.new_page().goto("data:text/html,<p>warm-up</p><script>1</script>")
            warm.close()
            # its renderers too are the browser's business: a spare one for the next page, or
            # a closed page's still ending on a loaded machine (seen once beside two CPU-bound
            # processes: a renderer outlived the test's 5 s grace)
            roots = _chromium_roots()
            OWNED_ROOTS.update(roots)
            yield b
        finally:
            OWNED_ROOTS.difference_update(roots)
            b.close()


def _chromium_roots() -> set[int]:
    """This process's descendants that are a Chromium whose parent is not one: the browsers
    Playwright started (their renderers and services are their children)."""
    def chromium(p: psutil.Process) -> bool:
        try:
            return "chrom" in p.name().lower()
        except psutil.Error:
            return False

    found = set()
    for p in psutil.Process().children(recursive=True):
        try:
            parent = p.parent()
        except psutil.Error:  # ended since it was listed (another test's short-lived child)
            continue
        if chromium(p) and (parent is None or not chromium(parent)):
            found.add(p.pid)
    return found


@pytest.fixture
def browser(chromium_browser: PwBrowser) -> Iterator[Browser]:
    errors: list[str] = []

    def watch(page: Page) -> None:
        page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}")
                if m.type in ("error", "warning") else None)
        page.on("pageerror", lambda e: errors.append(f"uncaught: {e}"))
        page.on("response", lambda r: errors.append(f"HTTP {r.status} {r.url}")
                if r.status >= 400 else None)

    ctx = chromium_browser.new_context(viewport={"width": 1280, "height": 900})
    try:
        ctx.on("page", watch)
        page = ctx.new_page()
        page.set_default_timeout(30_000)
        yield Browser(page, errors)
    finally:
        ctx.close()


#: the test's own observer (not the panel's): every text ``#angles`` is given, in order
ANGLES_OBSERVER = """
window.__anglesSeen = [];
document.addEventListener("DOMContentLoaded", () => {
  const el = document.querySelector("#angles");
  if (el) new MutationObserver(() => window.__anglesSeen.push(el.textContent))
    .observe(el, {childList: true, subtree: true, characterData: true});
});
"""


def run_status(url: str) -> Any:
    return get_json(f"{url}/api/status")["run"]


def test_a_run_to_its_verdict_by_keyboard_alone(tmp_path: Path, browser: Browser) -> None:
    page = browser.page
    page.add_init_script(ANGLES_OBSERVER)
    # config/sim_virtual.yaml (simulated time, 30 s of motion), its report without figures
    with serve(tmp_path, config=sim_virtual_without_figures(tmp_path)) as url:
        page.goto(url)
        wait_for("the serial field focused", lambda: browser.focused() == "serial", 10)
        page.keyboard.type("20260001")
        page.keyboard.press("Enter")  # as a barcode scanner ends its serial
        wait_for("the serial accepted", lambda: "✓" in browser.text("#serial-status"), 10)
        assert browser.focused() == "operator"
        page.keyboard.type(HOSTILE_OPERATOR)
        page.keyboard.press("Enter")  # the form: Start
        wait_for("the live view", lambda: browser.visible("#live") or browser.visible(
            "#verdict"), 30)
        wait_for("the verdict", lambda: browser.visible("#verdict"), 120, every_s=0.05)
        # every text the live angles were given, as the page's own observer saw it: a run on
        # simulated time is over in seconds, and a sample of the page every 50 ms on a loaded
        # machine may see only one of its updates
        seen = set(page.evaluate("window.__anglesSeen || []"))
        assert len(seen - {""}) >= 2, f"the live values did not change: {seen}"
        assert browser.text("#verdict-word") == "PASS"
        axes = browser.text("#verdict-axes")
        assert "roll" in axes and "0.4" in axes and "…" in axes  # σ, its interval, the limit
        # the operator's name shown as the text it is, never as markup
        assert HOSTILE_OPERATOR in browser.text("#verdict-serial")
        assert page.evaluate("window.pwned === undefined")
        assert page.locator("img").count() == 0
        assert browser.focused() == "new-test"
        page.keyboard.press("Shift+Tab")
        assert browser.focused() == "report-link"
        with page.expect_navigation():
            page.keyboard.press("Enter")  # the report: one key (one tap) away
        assert "/report" in page.url and "σ" in (page.text_content("body") or "")
        page.go_back()
        wait_for("the verdict again", lambda: browser.visible("#verdict"), 30)
        wait_for("focus on New test", lambda: browser.focused() == "new-test", 10)
        page.keyboard.press("Enter")
        wait_for("the form again", lambda: browser.visible("#setup"), 30)
        wait_for("the serial field focused", lambda: browser.focused() == "serial", 10)
        assert page.input_value("#operator") == HOSTILE_OPERATOR  # remembered
        assert run_status(url) is None
    assert browser.errors == []


# Stop while the stand moves, on simulated time: the run's SIGINT handler hands the fault to
# the virtual clock (``Clock.from_signal``), which its thread holding the baton takes at its next
# wait — a real Ctrl-C there once deadlocked the run inside the clock's mutex; the run is long
# enough (3000 simulated s) to be mid-motion whenever the click comes
def test_stop_takes_the_ctrl_c_path_and_shows_aborted(tmp_path: Path, browser: Browser) -> None:
    page = browser.page
    with serve(tmp_path, config=sim_virtual_without_figures(tmp_path), duration_s=3000.0) as url:
        page.goto(url)
        page.fill("#serial", "20260001")
        page.fill("#operator", "demo")
        page.click("#start")
        wait_for("the motion", lambda: browser.text("#state").startswith(("fade-in", "running")),
                 90)
        values = set()
        wait_for("the live angles to change",
                 lambda: values.add(browser.text("#angles")) or len(values) >= 3, 30, 0.2)
        page.click("#stop")
        wait_for("the verdict", lambda: browser.visible("#verdict"), 90)
        assert browser.text("#verdict-word") == "ABORTED"
        assert browser.text("#verdict-title").startswith("Stopped by the operator")
        assert "SIGINT" in browser.text("#verdict-reason")  # the same path as Ctrl-C
        assert "At rest." in browser.text("#verdict-stand")
        outcome = run_status(url)["outcome"]
        assert outcome["verdict"] == "ABORTED" and outcome["at_rest"] is True
        assert outcome["exit_code"] == 2 and outcome["kind"] == "operator"
        assert browser.text("#verdict-next")  # what to do next
    assert browser.errors == []


def test_login_then_the_station_page_in_russian(tmp_path: Path, browser: Browser) -> None:
    panel = tmp_path / "panel.yaml"
    panel.write_text(f'lang: ru\nrequire_token: true\ntoken_scrypt: "{hash_token(TOKEN)}"\n')
    page = browser.page
    with serve(tmp_path, "--panel", str(panel)) as url:
        page.goto(url)
        assert page.url.endswith("/login")
        wait_for("the token field focused", lambda: browser.focused() == "token", 10)
        page.keyboard.type("wrong token")
        page.keyboard.press("Enter")
        wait_for("the refusal", lambda: browser.text(".error") == "Неверный ключ.", 10)
        page.fill("#token", TOKEN)
        page.keyboard.press("Enter")
        wait_for("the station page", lambda: browser.visible("#setup"), 30)
        assert page.evaluate("document.documentElement.lang") == "ru"
        assert browser.text("#setup-title") == "Новое испытание"
        assert browser.text("#start") == "Пуск"
    # the wrong token's 401 is the page's answer (the login form again), not the page's error
    assert [e for e in browser.errors if "401" not in e] == []
    assert any(e.startswith("HTTP 401") for e in browser.errors)


def test_a_stand_in_use_is_refused_clearly(tmp_path: Path, browser: Browser) -> None:
    """The run takes the stand's lock, whoever starts it: held here by another 'run' (whose
    operator's name is hostile), the panel's run is refused before it connects, and the page
    says so — the holder's details shown as text."""
    import yaml

    from benchctl.config import load_config
    from benchctl.run.lock import stand_lock

    data = yaml.safe_load((ROOT / "config/sim.yaml").read_text())
    del data["sim"]  # a "hardware" config: its stand is locked (nothing is at its address)
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    locks = tmp_path / "locks"
    locks.mkdir(mode=0o700)
    data["run"].update(output_dir=str(tmp_path / "runs"), lock_dir=str(locks))
    cfg_path = tmp_path / "bench.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    holder = {"command": "benchctl run", "serial": "OTHER-1", "operator": HOSTILE_OPERATOR,
              "start_utc": "2026-01-01T00:00:00+00:00", "config": str(cfg_path)}
    page = browser.page
    with stand_lock(load_config(cfg_path), holder), serve(tmp_path, config=cfg_path) as url:
        page.goto(url)
        page.fill("#serial", "20260001")
        page.fill("#operator", "demo")
        page.click("#start")
        wait_for("the refusal", lambda: browser.visible("#verdict"), 60)
        assert "stand is in use" in browser.text("#verdict-title")  # the panel's words
        reason = browser.text("#verdict-reason")
        assert "is in use by" in reason and HOSTILE_OPERATOR in reason
        assert page.evaluate("window.pwned === undefined")
        assert page.locator("img").count() == 0
        assert run_status(url)["outcome"]["refused"] is True
    assert browser.errors == []


def test_a_plan_with_its_prompts_as_dialogs(tmp_path: Path, browser: Browser) -> None:
    """plans/ci_short.yaml on simulated time: its two setup questions and its cleanup question
    come up as dialogs (No focused: Enter alone never says yes), answered from the keyboard;
    the verdict lists the steps, each with its report."""
    page = browser.page
    with serve(tmp_path, "--plan", str(ROOT / "plans/ci_short.yaml"),
               config=sim_virtual_without_figures(tmp_path)) as url:
        page.goto(url)
        page.select_option("#profile", label="ci_short")
        page.fill("#operator", "qa")
        page.fill("#serial", "SIM-0001")
        page.click("#start")
        questions = []
        for _ in range(3):
            wait_for("a question", lambda: page.is_visible("#prompt") or browser.visible(
                "#verdict"), 120)
            assert not browser.visible("#verdict"), browser.text("#verdict-reason")
            questions.append(browser.text("#prompt-text"))
            assert browser.focused() == "prompt-no"
            page.keyboard.press("Shift+Tab")
            assert browser.focused() == "prompt-yes"
            page.keyboard.press("Enter")
            wait_for("the question answered", lambda: not page.is_visible("#prompt")
                     or browser.text("#prompt-text") != questions[-1], 30)
        assert questions == [
            "Is the instrument under test mounted on the stand and connected?",
            "Is the area around the stand clear of people?",
            "Remove the instrument from the stand when the stand is at rest.",
        ]
        wait_for("the verdict", lambda: browser.visible("#verdict"), 180)
        assert browser.text("#verdict-word") == "PASS"
        steps = browser.text("#verdict-steps")
        assert "linearity" in steps and "dynamic error" in steps
        links = page.locator("#verdict-steps a")
        assert links.count() == 2
        with page.expect_navigation():
            links.nth(1).click()
        assert "/steps/1/report" in page.url and "σ" in (page.text_content("body") or "")
    assert browser.errors == []


@pytest.mark.realtime  # the server killed (SIGKILL) and started again while its run goes on
def test_a_panel_started_again_takes_up_the_run_it_left_going(tmp_path: Path,
                                                               browser: Browser) -> None:
    """The panel crashes mid-run; started again on its port, it shows that run running, its
    live values moving again; Stop (SIGINT, Ctrl-C's path) ends it and its ABORTED verdict is
    shown — the run read from its own files, not this server's child. The run is on simulated
    time, long enough to outlive the restart."""
    import signal
    import subprocess

    import psutil

    port = free_port()
    procs: list[subprocess.Popen[bytes]] = []
    with serve(tmp_path, duration_s=3000.0, procs=procs, port=port) as url:
        post_json(url, "/api/start", {"serial": "20260001", "operator": "demo",
                                      "profile": "0"})
        children = wait_for("the run's process",
                            lambda: psutil.Process(procs[0].pid).children(), 30)
        run = children[0]
        wait_for("the motion", lambda: (run_status(url) or {}).get("state") in (
            "fade-in", "running"), 120)
        procs[0].send_signal(signal.SIGKILL)  # the panel crashes; the run goes on
        procs[0].wait(30)
    try:
        assert run.is_running()
        restart_and_stop(tmp_path, port, run, browser)
    finally:  # whatever failed, the run left going is stopped as Stop would
        if run.is_running():
            run.send_signal(signal.SIGINT)
            psutil.wait_procs([run], timeout=60)
    # put away: a panel started again now starts idle
    with serve(tmp_path, duration_s=3000.0, port=port) as url:
        assert run_status(url) is None
    assert browser.errors == []


def restart_and_stop(tmp_path: Path, port: int, run: Any, browser: Browser) -> None:
    import psutil

    page = browser.page
    with serve(tmp_path, duration_s=3000.0, port=port) as url:
        status = run_status(url)
        assert status is not None and not status["ended"] and status["adopted"]
        assert status["serial"] == "20260001" and status["operator"] == "demo"
        page.goto(url)
        wait_for("the live view", lambda: browser.visible("#live"), 30)
        assert browser.focused() == "stop"
        values: set[str] = set()
        wait_for("the live angles to change",
                 lambda: values.add(browser.text("#angles")) or len(values - {""}) >= 3, 60,
                 0.2)
        assert "restarted" in browser.text("#messages")
        page.keyboard.press("Enter")  # Stop
        wait_for("the verdict", lambda: browser.visible("#verdict"), 120)
        assert browser.text("#verdict-word") == "ABORTED"
        assert browser.text("#verdict-title").startswith("Stopped by the operator")
        assert "SIGINT" in browser.text("#verdict-reason")  # the run's own words: details
        assert "At rest." in browser.text("#verdict-stand")
        outcome = run_status(url)["outcome"]
        assert outcome["verdict"] == "ABORTED" and outcome["kind"] == "operator"
        assert outcome["at_rest"] is True
        gone, _ = psutil.wait_procs([run], timeout=30)
        assert gone, "the run did not end"
        page.click("#new-test")
        wait_for("the form again", lambda: browser.visible("#setup"), 30)


def test_a_run_in_russian_every_text_in_the_language(tmp_path: Path, browser: Browser) -> None:
    """The station in Russian: a refused serial in the panel's words (the check's English as
    the detail), the run's messages and its verdict screen (the verdict, the axes) in Russian."""
    page = browser.page
    with serve(tmp_path, "--lang", "ru",  # simulated time, the report without figures
               config=sim_virtual_without_figures(tmp_path)) as url:
        page.goto(url)
        wait_for("the serial field focused", lambda: browser.focused() == "serial", 10)
        page.keyboard.press("Enter")  # nothing typed
        wait_for("the refusal", lambda: browser.text("#form-error") ==
                 "Введите или отсканируйте серийный номер.", 10)
        assert "expected the serial number" in browser.text("#form-detail")
        page.fill("#serial", "20260001")
        page.fill("#operator", "demo")
        page.click("#start")
        wait_for("the verdict", lambda: browser.visible("#verdict"), 120)
        assert browser.text("#verdict-word") == "ГОДЕН"
        axes = browser.text("#verdict-axes")
        assert "крен" in axes and "0,4" in axes and "0.4" not in axes  # a decimal comma
        messages = browser.text("#messages")
        assert "Проверка перед движением: место на диске — пройдена." in messages
        assert "ГОДЕН: запись закрыта." in messages
        page.click("#new-test")
        wait_for("the form again", lambda: browser.visible("#setup"), 30)
    # the refused serial's 400 is the page's answer (and the browser's log of it), no error
    assert [e for e in browser.errors if "400" not in e] == []
    assert any(e.startswith("HTTP 400") and "check-serial" in e for e in browser.errors)
