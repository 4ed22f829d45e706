"""The station web panel: ``benchctl serve`` (``benchctl.web.app``, ``benchctl.web.server``) and
the live channel a run publishes to it (``benchctl.web.live``).

The panel is never in the safety loop: each run is a child process (``benchctl run --live``)
with its own real-time loop; the server starts it, reads what it publishes and sends it
signals (Stop is SIGINT, the same path as Ctrl-C). Only ``benchctl.web.live`` is imported by the
run, and it needs nothing beyond the standard library; the server's modules need the ``web``
extra (FastAPI, uvicorn).
"""
