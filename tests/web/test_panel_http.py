"""The station panel over plain HTTP (FastAPI's TestClient, the application in this process; no
run is started): who may reach it, cross-site requests refused, the token kept hashed, hostile
values escaped, nothing loaded from elsewhere."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from repo_paths import ROOT

from benchctl.errors import ConfigError
from benchctl.web.app import create_app
from benchctl.web.security import Guard, check_hash, hash_token, verify_token
from benchctl.web.server import check_access
from benchctl.web.settings import PanelSettings

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

TOKEN = "correct horse battery staple"
HOSTILE = '<img src=x onerror="alert(1)">'
LOOPBACK = "http://127.0.0.1:8350"


def settings(tmp: Path, **kw: object) -> PanelSettings:
    return PanelSettings(config=ROOT / "config/sim_virtual.yaml",
                         profiles=(ROOT / "profiles/paper_vessel_roll_short120.yaml",),
                         out_dir=tmp / "runs", **kw)  # type: ignore[arg-type]


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    with TestClient(create_app(settings(tmp_path)), base_url=LOOPBACK) as c:
        yield c


def csrf_of(page: str) -> str:
    m = re.search(r'"csrf": "([0-9a-f]+)"', page)
    assert m, "no CSRF token on the page"
    return m.group(1)


def test_token_is_kept_as_a_scrypt_hash() -> None:
    stored = hash_token(TOKEN, n=2**10)
    assert TOKEN not in stored and stored.startswith("scrypt$1024$8$1$")
    assert check_hash(stored) is None
    assert verify_token(TOKEN, stored)
    assert not verify_token(TOKEN + "x", stored)
    assert hash_token(TOKEN, n=2**10) != stored  # salted
    assert check_hash("plain-text") is not None
    assert not verify_token("plain-text", "plain-text")


def test_off_loopback_needs_a_token(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"--host 0\.0\.0\.0.*--hash-token"):
        check_access(settings(tmp_path, host="0.0.0.0"))
    with pytest.raises(ConfigError, match="token_scrypt"):
        check_access(settings(tmp_path, host="0.0.0.0", token_scrypt="not-a-hash"))
    ok = check_access(settings(tmp_path, host="0.0.0.0", token_scrypt=hash_token(TOKEN, n=2**10)))
    assert ok.require_token
    assert not check_access(settings(tmp_path)).require_token  # loopback: none asked


def test_with_a_token_every_page_and_request_needs_the_login(tmp_path: Path) -> None:
    s = check_access(settings(tmp_path, host="0.0.0.0",
                              token_scrypt=hash_token(TOKEN, n=2**10)))
    origin = "http://bench3.lan:8350"
    with TestClient(create_app(s), base_url=origin) as c:
        r = c.get("/", follow_redirects=False)
        assert r.status_code == 303 and r.headers["location"] == "/login"
        assert c.get("/api/status").status_code == 401
        login = c.get("/login")
        assert login.status_code == 200 and 'type="password"' in login.text
        csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', login.text)
        assert csrf
        # the login form itself is protected against cross-site posting
        assert c.post("/login", data={"token": TOKEN, "csrf": csrf.group(1)},
                      headers={"Origin": "https://evil.example"}).status_code == 403
        assert c.post("/login", data={"token": TOKEN, "csrf": "0" * 64},
                      headers={"Origin": origin}).status_code == 403
        wrong = c.post("/login", data={"token": "guess", "csrf": csrf.group(1)},
                       headers={"Origin": origin}, follow_redirects=False)
        assert wrong.status_code == 401 and c.get("/api/status").status_code == 401
        ok = c.post("/login", data={"token": TOKEN, "csrf": csrf.group(1)},
                    headers={"Origin": origin}, follow_redirects=False)
        assert ok.status_code == 303
        cookie = ok.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie and TOKEN not in cookie
        assert c.get("/api/status").status_code == 200
        page = c.get("/")
        assert page.status_code == 200
        # the CSRF token belongs to the session: the login page's no longer serves
        session_csrf = csrf_of(page.text)
        assert session_csrf != csrf.group(1)
        hdr = {"Origin": origin, "X-CSRF-Token": csrf.group(1)}
        assert c.post("/api/check-serial", json={"serial": "1"}, headers=hdr).status_code == 403
        hdr["X-CSRF-Token"] = session_csrf
        assert c.post("/api/check-serial", json={"serial": "1"}, headers=hdr).status_code == 200


def test_cross_site_requests_are_refused(client: TestClient) -> None:
    csrf = csrf_of(client.get("/").text)
    body = {"serial": "20260001", "operator": "demo", "profile": "0"}
    refused = [
        {},  # neither Origin nor Referer nor token
        {"X-CSRF-Token": csrf},  # the token but no Origin
        {"Origin": "https://evil.example", "X-CSRF-Token": csrf},
        {"Origin": "null", "X-CSRF-Token": csrf},
        {"Referer": "https://evil.example/page", "X-CSRF-Token": csrf},
        {"Origin": LOOPBACK},  # the right Origin but no token
        {"Origin": LOOPBACK, "X-CSRF-Token": "0" * 64},
    ]
    for headers in refused:
        for path in ("/api/start", "/api/stop", "/api/dismiss"):
            r = client.post(path, json=body, headers=headers)
            assert r.status_code == 403, (path, headers, r.text)
    assert client.get("/api/status").json()["run"] is None  # nothing started
    ok = client.post("/api/check-serial", json={"serial": "20260001"},
                     headers={"Referer": f"{LOOPBACK}/", "X-CSRF-Token": csrf})
    assert ok.status_code == 200 and ok.json() == {"serial": "20260001"}


def test_a_foreign_host_name_is_not_served_on_loopback(client: TestClient) -> None:
    """DNS rebinding: a page of evil.example whose name now points at 127.0.0.1."""
    r = client.get("/api/status", headers={"Host": "evil.example:8350"})
    assert r.status_code == 400
    assert client.get("/api/status", headers={"Host": "localhost:8350"}).status_code == 200
    assert client.get("/api/status", headers={"Host": "[::1]:8350"}).status_code == 200


def test_the_serial_rules_apply_and_their_message_is_data(client: TestClient) -> None:
    csrf = csrf_of(client.get("/").text)
    hdr = {"Origin": LOOPBACK, "X-CSRF-Token": csrf}
    r = client.post("/api/check-serial", json={"serial": HOSTILE + "\x1b"}, headers=hdr)
    assert r.status_code == 400
    assert r.headers["content-type"].startswith("application/json")
    # the panel's words for it, the check's own English as the detail
    assert r.json()["error"] == ("The serial number holds a character that cannot be shown: "
                                 "type or scan it again.")
    assert "control character" in r.json()["detail"]
    r = client.post("/api/start", json={"serial": "20260001", "operator": "x\x07",
                                        "profile": "0"}, headers=hdr)
    assert r.status_code == 400 and "name holds a character" in r.json()["error"]
    assert "operator" in r.json()["detail"]
    r = client.post("/api/start", json={"serial": "20260001", "operator": "demo",
                                        "profile": "../../etc/passwd"}, headers=hdr)
    assert r.status_code == 400 and "not one this station offers" in r.json()["error"]
    assert client.get("/api/status").json()["run"] is None


def test_hostile_names_are_escaped_on_the_page(tmp_path: Path) -> None:
    """A profile's file name is the one value the page itself shows (the run's values reach it
    as JSON and are set as text by the script)."""
    hostile = tmp_path / f"{HOSTILE}&amp;.yaml"
    hostile.write_text((ROOT / "profiles/paper_vessel_roll_short120.yaml").read_text())
    s = settings(tmp_path).with_(profiles=(hostile,), lang="ru")
    with TestClient(create_app(s), base_url=LOOPBACK) as c:
        page = c.get("/").text
    assert HOSTILE not in page and "&amp;." not in page
    assert "&lt;img src=x onerror=&#34;alert(1)&#34;&gt;&amp;amp;" in page
    assert page.count("</script>") == 2  # the data block and the script, nothing injected


def test_nothing_is_loaded_from_elsewhere(client: TestClient) -> None:
    page = client.get("/")
    csp = page.headers["content-security-policy"]
    assert "default-src 'none'" in csp and "script-src 'self'" in csp and "http" not in csp
    assert page.headers["x-content-type-options"] == "nosniff"
    refs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert refs and all(r.startswith("/") for r in refs), refs
    for ref in refs:
        if ref.startswith("/static/"):
            asset = client.get(ref)
            assert asset.status_code == 200, ref
            assert not re.search(r"https?://(?!www\.w3\.org/2000/svg)", asset.text), ref
    script = client.get("/static/panel.js").text
    for unsafe in ("innerHTML", "outerHTML", "insertAdjacentHTML", "document.write", "eval("):
        assert unsafe not in script, unsafe


def test_the_guard_compares_origins_by_scheme_host_and_port() -> None:
    g = Guard(None, require_token=False, origins=("https://bench3.example.org",))
    assert g.origin_ok("http://127.0.0.1:8350", None, "127.0.0.1:8350")
    assert not g.origin_ok("http://127.0.0.1:8351", None, "127.0.0.1:8350")
    assert g.origin_ok("https://bench3.example.org", None, "127.0.0.1:8350")  # behind a proxy
    assert not g.origin_ok("https://bench3.example.org.evil.example", None, "127.0.0.1:8350")
    assert g.host_allowed("bench3.example.org")
    assert not g.host_allowed("evil.example")
