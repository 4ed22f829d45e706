"""Process trees a fixture owns for longer than one test (a module's headless Chromium): the
processes under their roots come and go as that program decides — Chromium starts a spare
renderer for the next page when it sees fit, and ends a closed page's renderer when it gets
to it — so they are not a test's leak. ``tests/conftest.py``'s leak check leaves them out; the
fixture that owns a tree closes it (and its processes) at its own end."""

from __future__ import annotations

#: the root process ids of the trees fixtures own now
OWNED_ROOTS: set[int] = set()
