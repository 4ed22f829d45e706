"""The panel's pages as a browser loads them: bytes per page and per resource, and no external URL.

Starts ``benchctl serve`` as a child on a free loopback port (the simulated bench's config, a
fresh output folder, so the line view and history read an empty archive), fetches the station
page, the line view and the history page, then every resource each one loads (``src=``, a
``<link>``'s ``href=``, CSS ``url(…)``), and prints their sizes as sent (no compression is
asked for). A URL that leaves the server (a scheme and a host, or ``//host``) is listed: the
goal is none, a station PC is often offline.

Usage: python benchmarks/page_weight.py [--config config/sim.yaml] [--lang en|ru]
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PAGES = ("/", "/line", "/history")
#: what a browser loads by itself: ``src=``, a ``<link>``'s ``href=``, CSS ``url(…)`` (an ``<a>``'s
#: ``href`` is a page the operator may open, not part of this one)
LINK = re.compile(r"""\bsrc\s*=\s*["']([^"'#]+)["']|<link\b[^>]*\bhref\s*=\s*["']([^"'#]+)["']"""
                  r"""|url\(\s*["']?([^"')]+)["']?\s*\)""")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def fetch(url: str) -> tuple[bytes, str]:
    req = urllib.request.Request(url, headers={"Accept-Encoding": "identity"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return r.read(), r.headers.get("Content-Type", "")


def links(body: bytes) -> list[str]:
    return [a or b or c for a, b, c in LINK.findall(body.decode("utf-8", "replace"))]


def external(link: str) -> bool:
    u = urllib.parse.urlsplit(link)
    return bool(u.netloc) or (bool(u.scheme) and u.scheme not in ("data",))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", type=Path, default=ROOT / "config/sim.yaml")
    ap.add_argument("--lang", choices=("en", "ru"), default="en")
    args = ap.parse_args()
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "benchctl", "serve", "--config", str(args.config),
               "--port", str(port), "--out", tmp, "--lang", args.lang,
               "--profile", str(ROOT / "profiles")]
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        try:
            deadline = time.monotonic() + 60
            while True:
                try:
                    fetch(base + "/api/status")
                    break
                except (urllib.error.URLError, ConnectionError):
                    if proc.poll() is not None or time.monotonic() > deadline:
                        err = proc.stderr.read().decode() if proc.stderr else ""
                        print(f"the panel did not start: {err[-2000:]}")
                        return 2
                    time.sleep(0.2)
            outside: list[str] = []
            for page in PAGES:
                body, _ = fetch(base + page)
                sizes = {page: len(body)}
                seen = {page}
                todo = links(body)
                while todo:
                    link = todo.pop(0)
                    if external(link):
                        outside.append(f"{page}: {link}")
                        continue
                    path = urllib.parse.urljoin(page, link)
                    if path in seen:
                        continue
                    seen.add(path)
                    res, ctype = fetch(base + path)
                    sizes[path] = len(res)
                    if "css" in ctype:
                        todo.extend(links(res))
                total = sum(sizes.values())
                parts = ", ".join(f"{p} {n / 1000:.1f}" for p, n in sizes.items())
                print(f"{page:9s} {total / 1000:5.1f} kB in all ({parts})")
            print(f"external URLs: {len(outside)}" + "".join(f"\n  {o}" for o in outside))
            return 1 if outside else 0
        finally:
            proc.terminate()
            proc.wait(timeout=30)


if __name__ == "__main__":
    raise SystemExit(main())
