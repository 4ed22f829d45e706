"""``benchctl serve``'s server: the panel's application (``benchctl.web.app``) under uvicorn,
after the access rules are checked — off loopback (or with ``require_token``) it will not start
without a token hash."""

from __future__ import annotations

import logging

from benchctl.errors import ConfigError
from benchctl.web.app import create_app
from benchctl.web.security import check_hash, is_loopback
from benchctl.web.settings import PanelSettings

log = logging.getLogger(__name__)
GRACEFUL_S = 2.0  # open event streams are closed this long after the server is asked to stop


def check_access(settings: PanelSettings) -> PanelSettings:
    """``settings`` with ``require_token`` set when the panel listens off loopback;
    ``ConfigError`` when a token is required and no valid hash is given."""
    off_loopback = not is_loopback(settings.host)
    need = settings.require_token or off_loopback
    if need and not settings.token_scrypt:
        where = f"--host {settings.host}" if off_loopback else "require_token"
        raise ConfigError(
            f"{where}: the panel then asks for an access token, and no token hash is set: make "
            "one with `benchctl serve --hash-token` and put it in the panel settings file "
            "(token_scrypt:)")
    if settings.token_scrypt:
        why = check_hash(settings.token_scrypt)
        if why is not None:
            raise ConfigError(f"token_scrypt: {why}")
    return settings.with_(require_token=need)


def serve(settings: PanelSettings) -> None:
    """Serve the panel until interrupted (Ctrl-C, SIGTERM). A run going on is not stopped by
    the server's end: it ends by itself, its stand at rest as always."""
    import uvicorn  # the optional web extra: `benchctl serve` says how to install it

    settings = check_access(settings)
    app = create_app(settings)
    shown = f"[{settings.host}]" if ":" in settings.host else settings.host
    log.warning("station panel on http://%s:%d/ (Ctrl-C stops the panel, not a run)",
                shown, settings.port)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level="warning",
                timeout_graceful_shutdown=int(GRACEFUL_S), access_log=False)
