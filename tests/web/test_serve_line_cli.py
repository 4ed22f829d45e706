"""``benchctl serve-line``'s options and the app they make (the server itself is tested in
test_line_browser.py): the archive named as everywhere else, bad ports refused, a missing
web extra said in one line."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from benchctl.cli import serve_line
from benchctl.errors import InputError


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="benchctl")
    serve_line.register(parser.add_subparsers(dest="command"))
    return parser.parse_args(["serve-line", *argv])


def test_the_app_of_the_options(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    args = _parse(["--url", url, "--port", "8099", "--stale-after", "30"])
    assert (args.host, args.port) == ("127.0.0.1", 8099)
    app = serve_line.build_app(args)
    assert isinstance(app, FastAPI)
    with TestClient(app) as c:
        r = c.get("/line")
        assert r.status_code == 200 and "30 s is shown offline" in r.text


@pytest.mark.parametrize(("opt", "value"), [("--port", "0"), ("--port", "70000"),
                                            ("--stale-after", "0")])
def test_bad_options(tmp_path: Path, opt: str, value: str) -> None:
    args = _parse(["--url", f"sqlite:///{tmp_path / 'a.sqlite'}", opt, value])
    with pytest.raises(InputError, match=opt):
        serve_line.build_app(args)


def test_without_the_web_extra(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "fastapi", None)  # as if not installed
    monkeypatch.delitem(sys.modules, "benchctl.web.line")
    args = _parse(["--url", f"sqlite:///{tmp_path / 'a.sqlite'}"])
    with pytest.raises(InputError, match=r"needs fastapi: pip install 'benchctl\[web\]'"):
        serve_line.build_app(args)
