"""The panel's access rules: the operator's token (kept only as a scrypt hash), sessions,
cross-site request checks and the addresses that may reach the panel.

- Bound to a loopback address the panel asks for no token (unless ``require_token``); bound to
  any other address it will not start without a token hash (``benchctl serve --hash-token``).
- Every state-changing request (POST) must come from the panel's own pages: its ``Origin`` (or,
  without one, its ``Referer``) is the address the browser used (the request's ``Host``) or one
  of the configured origins, and it carries the page's CSRF token (a header, or a form field
  for the login form), an HMAC of the session under a secret made at start. The session cookie
  is ``HttpOnly`` and ``SameSite=Strict``.
- Bound to loopback without a token, only requests naming a loopback host (or a configured
  origin's host) in ``Host`` are served: a page elsewhere cannot reach the panel by renaming its
  own host to 127.0.0.1 (DNS rebinding).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import ipaddress
import secrets
from urllib.parse import urlsplit

SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1
SCHEME = "scrypt"


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def hash_token(token: str, *, salt: bytes | None = None, n: int = SCRYPT_N) -> str:
    """``token`` as ``scrypt$N$r$p$salt$hash`` (base64): what the settings file keeps."""
    salt = salt if salt is not None else secrets.token_bytes(16)
    digest = hashlib.scrypt(token.encode(), salt=salt, n=n, r=SCRYPT_R, p=SCRYPT_P, dklen=32)
    return f"{SCHEME}${n}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def check_hash(stored: str) -> str | None:
    """Why ``stored`` is not a token hash ``hash_token`` makes, or None."""
    parts = stored.split("$")
    if len(parts) != 6 or parts[0] != SCHEME:
        return "expected scrypt$N$r$p$salt$hash (benchctl serve --hash-token)"
    try:
        n, r, p = (int(x) for x in parts[1:4])
        base64.b64decode(parts[4], validate=True)
        base64.b64decode(parts[5], validate=True)
    except ValueError:
        return "its numbers or base64 parts do not read"
    if n < 2**10 or n & (n - 1) or r < 1 or p < 1:
        return f"N={n} r={r} p={p}: N a power of two ≥ 1024, r and p ≥ 1"
    return None


def verify_token(token: str, stored: str) -> bool:
    """Whether ``token`` is the one ``stored`` was made from (constant time)."""
    if check_hash(stored) is not None:
        return False
    _, n, r, p, salt, digest = stored.split("$")
    want = base64.b64decode(digest)
    got = hashlib.scrypt(token.encode(), salt=base64.b64decode(salt), n=int(n), r=int(r),
                         p=int(p), dklen=len(want), maxmem=256 * 1024 * 1024)
    return hmac.compare_digest(got, want)


def is_loopback(host: str) -> bool:
    """``host`` (an address or a name, without a port) is this machine's loopback."""
    name = host.strip("[]").lower()
    if name == "localhost" or name.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def host_name(host_header: str) -> str:
    """The host of a ``Host`` header, without its port (``[::1]:8350`` → ``::1``)."""
    return urlsplit(f"//{host_header}").hostname or ""


class Guard:
    """Sessions and CSRF tokens of one running panel."""

    def __init__(self, token_scrypt: str | None, *, require_token: bool,
                 origins: tuple[str, ...] = ()) -> None:
        self.token_scrypt = token_scrypt
        self.require_token = require_token
        self.origins = tuple(o.rstrip("/").lower() for o in origins)
        self._secret = secrets.token_bytes(32)
        self._sessions: set[str] = set()

    # ---- who may come in
    def host_allowed(self, host_header: str) -> bool:
        """DNS rebinding: without a token, only loopback names and the configured origins."""
        if self.require_token:
            return True
        name = host_name(host_header)
        return is_loopback(name) or any(urlsplit(o).hostname == name for o in self.origins)

    def authenticated(self, session: str | None) -> bool:
        return not self.require_token or (session is not None and session in self._sessions)

    def login(self, token: str) -> str | None:
        """A new session for the right token, else None."""
        if self.token_scrypt is None or not verify_token(token, self.token_scrypt):
            return None
        sid = secrets.token_urlsafe(32)
        self._sessions.add(sid)
        return sid

    def logout(self, session: str | None) -> None:
        self._sessions.discard(session or "")

    # ---- cross-site requests
    def csrf_token(self, session: str | None) -> str:
        return hmac.new(self._secret, (session or "-").encode(), hashlib.sha256).hexdigest()

    def csrf_ok(self, session: str | None, token: str | None) -> bool:
        return token is not None and hmac.compare_digest(self.csrf_token(session), token)

    def origin_ok(self, origin: str | None, referer: str | None, host_header: str) -> bool:
        """The request came from a page of this panel: ``Origin`` (else ``Referer``) is the
        address the browser used (``Host``) or a configured origin. Neither: refused."""
        source = origin if origin and origin != "null" else referer
        if not source:
            return False
        parts = urlsplit(source)
        if parts.scheme not in ("http", "https") or not parts.netloc:
            return False
        base = f"{parts.scheme}://{parts.netloc}".lower()
        return parts.netloc.lower() == host_header.lower() or base in self.origins
