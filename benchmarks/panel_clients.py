"""Does the station panel touch the motion? One real-time simulated run with no browser
watching, then one with N live clients (default 20), both started through the panel
(``benchctl serve``, ``config/sim.yaml``): each run's missed cycles and its stand loop's lateness
(p50, p99, max), from what the run recorded (``end.json``'s ``stats``: ``missed_cycles``,
``cycle_lateness_s``), side by side, with the events the clients received.

A client is what a browser's page does, without drawing: it holds the live event stream
(``/api/events``) open and reads every event (``--poll``: and asks for ``/api/status`` with the
plot's points once a second, more than a page does). The clients run in this process, the panel
in its own, the run in a third (the panel's child). Run it on an otherwise quiet machine, not
under ``nice``: the panel and the run inherit this process's priority.

Usage: python benchmarks/panel_clients.py [--clients 20] [--duration 60] [--config FILE]
       [--profile FILE] [--poll]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Client:
    """One watcher: the event stream read to its end, the status asked for every second."""

    def __init__(self, port: int, stop: threading.Event, poll: bool) -> None:
        self.port, self.stop = port, stop
        self.events = 0
        self.bytes = 0
        self.statuses = 0
        self.errors: list[str] = []
        self.threads = [threading.Thread(target=self._stream, daemon=True)]
        if poll:
            self.threads.append(threading.Thread(target=self._poll, daemon=True))
        for t in self.threads:
            t.start()

    def _stream(self) -> None:
        try:
            conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
            conn.request("GET", "/api/events")
            resp = conn.getresponse()
            while not self.stop.is_set():
                line = resp.readline()
                if not line:
                    break
                self.bytes += len(line)
                if line.startswith(b"event:"):
                    self.events += 1
            conn.close()
        except OSError as e:
            if not self.stop.is_set():
                self.errors.append(f"stream: {e}")

    def _poll(self) -> None:
        while not self.stop.wait(1.0):
            try:
                with urllib.request.urlopen(
                        f"http://127.0.0.1:{self.port}/api/status?trace=600", timeout=30) as r:
                    r.read()
                self.statuses += 1
            except OSError as e:
                self.errors.append(f"status: {e}")


def start_run(port: int, serial: str) -> None:
    base = f"http://127.0.0.1:{port}"
    page = urllib.request.urlopen(f"{base}/", timeout=10).read().decode()
    m = re.search(r'"csrf": "([0-9a-f]+)"', page)
    assert m, "no CSRF token on the station page"
    req = urllib.request.Request(
        f"{base}/api/start", method="POST",
        data=json.dumps({"serial": serial, "operator": "bench", "profile": "0"}).encode(),
        headers={"Content-Type": "application/json", "Origin": base, "X-CSRF-Token": m.group(1)})
    urllib.request.urlopen(req, timeout=30).read()


def post(port: int, path: str) -> None:
    base = f"http://127.0.0.1:{port}"
    page = urllib.request.urlopen(f"{base}/", timeout=10).read().decode()
    m = re.search(r'"csrf": "([0-9a-f]+)"', page)
    assert m
    req = urllib.request.Request(f"{base}{path}", method="POST", data=b"{}", headers={
        "Content-Type": "application/json", "Origin": base, "X-CSRF-Token": m.group(1)})
    urllib.request.urlopen(req, timeout=30).read()


def status(port: int) -> dict[str, Any]:
    """The panel's status; a slow answer waited for (a loaded machine), up to a minute."""
    for _ in range(6):
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status", timeout=10) as r:
                return dict(json.loads(r.read()))
        except TimeoutError:
            print("(the panel is slow to answer)", file=sys.stderr, flush=True)
    raise TimeoutError("the panel did not answer /api/status within a minute")


def one_run(port: int, n_clients: int, timeout_s: float, poll: bool) -> dict[str, Any]:
    stop = threading.Event()
    clients = [Client(port, stop, poll) for _ in range(n_clients)]
    time.sleep(1.0)  # the streams open before the run starts
    t0 = time.monotonic()
    start_run(port, f"PANEL{n_clients:02d}")
    run: dict[str, Any] = {}
    while time.monotonic() - t0 < timeout_s:
        run = status(port)["run"] or {}
        if run.get("ended"):
            break
        time.sleep(0.5)
    stop.set()
    took = time.monotonic() - t0
    outcome = run.get("outcome") or {}
    out: dict[str, Any] = {"clients": n_clients, "verdict": outcome.get("verdict"),
                           "took_s": took, "events": sum(c.events for c in clients),
                           "bytes": sum(c.bytes for c in clients),
                           "statuses": sum(c.statuses for c in clients),
                           "client_errors": [e for c in clients for e in c.errors][:5]}
    recording = outcome.get("recording")
    end = Path(recording) / "end.json" if recording else None
    if end is not None and end.is_file():
        stats = json.loads(end.read_text()).get("stats", {})
        out.update(missed=stats.get("missed_cycles"), cycles=stats.get("cycles"),
                   lateness=stats.get("cycle_lateness_s", {}), underruns=stats.get("underruns"),
                   rejoins=stats.get("rejoins"))
    else:
        out["error"] = outcome.get("reason") or "no recording"
    post(port, "/api/dismiss")
    return out


def ms(v: Any) -> str:
    return "—" if not isinstance(v, int | float) else f"{v * 1e3:8.3f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clients", type=int, default=20)
    ap.add_argument("--duration", type=float, default=60.0, help="each run's motion (s)")
    ap.add_argument("--config", type=Path, default=ROOT / "config/sim.yaml")
    ap.add_argument("--profile", type=Path,
                    default=ROOT / "profiles/paper_vessel_roll_short120.yaml")
    ap.add_argument("--poll", action="store_true",
                    help="each client also asks for the status with the plot every second")
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="benchctl-panel-bench-"))
    port = free_port()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    server = subprocess.Popen(
        [sys.executable, "-m", "benchctl", "serve", "--config", str(args.config), "--profile",
         str(args.profile), "--duration", repr(args.duration), "--out", str(tmp / "runs"),
         "--port", str(port)], env=env, stdout=subprocess.DEVNULL,
        stderr=(tmp / "serve.log").open("wb"))
    rows = []
    try:
        deadline = time.monotonic() + 60
        while True:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/static/panel.css", timeout=2)
                break
            except OSError:
                if time.monotonic() > deadline or server.poll() is not None:
                    print((tmp / "serve.log").read_text(), file=sys.stderr)
                    return 2
                time.sleep(0.2)
        for n in (0, args.clients):
            print(f"run with {n} live client(s)…", file=sys.stderr, flush=True)
            rows.append(one_run(port, n, args.duration + 300.0, args.poll))
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(30)
        except subprocess.TimeoutExpired:
            server.kill()

    print(f"{'clients':>7} {'verdict':>8} {'cycles':>7} {'missed':>6} {'late p50 ms':>11} "
          f"{'p99 ms':>8} {'max ms':>8} {'underruns':>9} {'rejoins':>7} {'events':>7} "
          f"{'status':>6}")
    for r in rows:
        lat = r.get("lateness") or {}
        print(f"{r['clients']:>7} {r['verdict'] or '—':>8} {r.get('cycles', '—')!s:>7} "
              f"{r.get('missed', '—')!s:>6} {ms(lat.get('p50')):>11} {ms(lat.get('p99')):>8} "
              f"{ms(lat.get('max')):>8} {r.get('underruns', '—')!s:>9} "
              f"{r.get('rejoins', '—')!s:>7} {r['events']:>7} {r['statuses']:>6}")
        if r.get("error") or r["client_errors"]:
            print(f"        {r.get('error', '')} {r['client_errors']}")
    print(f"(the runs' recordings: {tmp / 'runs'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
