"""The web side of benchctl: pages served by a server process that is never in the safety
loop (it reads the archive and the stations' published state, and starts or stops runs only
through the same API and signals as the command line).

- ``benchctl.web.line``: the line view and the history pages as a FastAPI router
  (``line_router``), and a minimal app of its own (``create_line_app``);
- ``benchctl.web.linestations``: the stations' heartbeats in the shared archive database
  (``publish_station_state``, ``StationBoard``);
- ``benchctl.web.lineheartbeat``: one station's heartbeat kept going from its own thread
  (``HeartbeatPublisher``);
- ``benchctl.web.linedata``: what the line view shows, read from the archive;
- ``benchctl.web.linestats``: the control chart's and the yield's statistics (pure);
- ``benchctl.web.linechart``: the control chart's SVG geometry (pure);
- ``benchctl.web.linepages``: the Jinja2 environment (autoescape, gettext) and the pages.

FastAPI is imported only by ``benchctl.web.line``: the rest needs the core dependencies only.
"""
