"""The web side of benchctl: pages served by a server process that is never in the safety
loop (it reads the archive and the stations' published state, and starts or stops runs only
through the same API and signals as the command line).

The station panel (``benchctl serve``):

- ``benchctl.web.app``: the station page, its live events and requests (FastAPI);
  ``benchctl.web.server``: it under uvicorn, after the access rules are checked;
- ``benchctl.web.station``: the run going on as the panel sees it — a child process
  (``benchctl run --live`` / ``benchctl plan --live``), its published state, the browsers;
  ``benchctl.web.runstate``: the current run kept in a state file, for a panel started again
  to take it up; ``benchctl.web.wording``: the panel's own words (in the station's language)
  for what a run says in English — an abort, the stand after it, its messages, a refusal;
- ``benchctl.web.live``: the run's side of the live channel (a display teed to JSON datagrams,
  never blocking); ``benchctl.web.plan_live`` and ``benchctl.web.prompts``: a plan's, with its
  prompts answered on the panel;
- ``benchctl.web.security``: the token (scrypt), sessions, CSRF and origin checks;
  ``benchctl.web.settings``: the panel's own settings file; ``benchctl.web.i18n``: its
  message catalogs.

The line view (``benchctl serve-line``):

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

FastAPI is imported only by ``benchctl.web.line`` and ``benchctl.web.app``; the run imports
only ``benchctl.web.live`` (the standard library and the run's display).
"""
