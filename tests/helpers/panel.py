"""The station panel in tests: an in-process application (FastAPI's TestClient) for the HTTP
checks, and ``benchctl serve`` as a real child process for the browser tests."""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from repo_paths import ROOT

SHORT_PROFILE = ROOT / "profiles/paper_vessel_roll_short120.yaml"


def sim_virtual_without_figures(tmp: Path) -> Path:
    """config/sim_virtual.yaml (simulated time) as ``tmp/bench-nofig.yaml``, its paths absolute
    and ``run.figures: false``: the panel's runs and plans with their reports' tables but no
    figures (matplotlib, seconds of each run's child after its verdict), for the tests about
    the panel that look at no figure (the figures' own tests are tests/unit/report/)."""
    import yaml

    src = ROOT / "config/sim_virtual.yaml"
    data = yaml.safe_load(src.read_text())
    data["stand"]["register_map"] = str((src.parent / data["stand"]["register_map"]).resolve())
    data["instrument"]["eds"] = str((src.parent / data["instrument"]["eds"]).resolve())
    data["run"]["output_dir"] = str(tmp / "runs")
    data["run"]["figures"] = False
    path = tmp / "bench-nofig.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def child_env() -> dict[str, str]:
    """This checkout first on the child's path (the tests run from a worktree)."""
    path = os.environ.get("PYTHONPATH", "")
    return {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{path}" if path else str(ROOT)}


def get_json(url: str, timeout: float = 10.0) -> Any:
    with urllib.request.urlopen(url, timeout=timeout) as r:
        return json.loads(r.read())


def post_json(url: str, path: str, body: dict[str, Any]) -> Any:
    """A state-changing request as the panel's page makes it (its Origin, its CSRF token)."""
    page = urllib.request.urlopen(f"{url}/", timeout=10).read().decode()
    m = re.search(r'"csrf": "([0-9a-f]+)"', page)
    assert m, "no CSRF token on the station page"
    req = urllib.request.Request(f"{url}{path}", method="POST", data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json", "Origin": url,
                                          "X-CSRF-Token": m.group(1)})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


def wait_for(what: str, check: Any, timeout_s: float, every_s: float = 0.1) -> Any:
    """``check()``'s first truthy value within ``timeout_s`` (fails the test after it)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = check()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s:g} s waiting for {what}")
        time.sleep(every_s)


@contextlib.contextmanager
def serve(tmp: Path, *args: str, config: Path = ROOT / "config/sim_virtual.yaml",
          profile: Path = SHORT_PROFILE, duration_s: float = 30.0,
          procs: list[subprocess.Popen[bytes]] | None = None,
          port: int | None = None) -> Iterator[str]:
    """``benchctl serve`` on a free loopback port (or ``port``: a panel started again where
    it was); yields its base URL (its process appended to ``procs``). At the end the server
    gets SIGINT and is waited for; the run it started must have ended by then."""
    port = free_port() if port is None else port
    cmd = [sys.executable, "-m", "benchctl", "serve", "--config", str(config),
           "--profile", str(profile), "--duration", repr(duration_s), "--out",
           str(tmp / "runs"), "--port", str(port), *args]
    log = (tmp / f"serve-{port}.log").open("ab")  # a panel started again: its log after
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=child_env(),
                            cwd=tmp)
    url = f"http://127.0.0.1:{port}"
    if procs is not None:
        procs.append(proc)

    def up() -> bool:
        if proc.poll() is not None:
            raise AssertionError(f"benchctl serve ended ({proc.returncode}): "
                                 f"{(tmp / f'serve-{port}.log').read_text()[-2000:]}")
        try:
            urllib.request.urlopen(f"{url}/static/panel.css", timeout=2).close()
            return True
        except (urllib.error.URLError, OSError):
            return False

    try:
        wait_for("benchctl serve to answer", up, 60.0)
        yield url
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        log.close()


def live_socket(tmp: Path, timeout_s: float = 10.0) -> socket.socket:
    """The panel's end of the live channel: a datagram socket bound at ``tmp/live.sock``."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(tmp / "live.sock"))
    s.settimeout(timeout_s)
    return s
