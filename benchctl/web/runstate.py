"""What the panel keeps about its current run across its own restarts: a small JSON file in the
station's working folder (the runs' output folder), ``.benchctl-panel-<port>.json``, written
whole (a rename) each time it changes — when the run starts, when its recording is known, when
Stop is pressed, when it ends — and removed when the operator puts the verdict away.

It holds the run's process id and **identity** (the boot's id and the process's start time,
``/proc/<pid>/stat``: a pid the kernel has since given to another process is never taken for
the run), the panel's run number, serial, operator, profile or plan, kind, the panel's folder
for the run (its live socket, the run's JSON output and error files, a plan's answers), the
recording once known, and, once the run ended, what its verdict screen needs. A panel started
again reads it (``benchctl.web.station.Station.resume``): a run still going on is taken up
again, a run that ended meanwhile is shown with its verdict from its own files.

The file is the panel's only: the run knows nothing of it (the panel is never in the safety
loop)."""

from __future__ import annotations

import itertools
import json
import logging
import os
import socket
from pathlib import Path
from typing import Any

from benchctl.fileout import atomic_write_text
from benchctl.jsonout import dumps

log = logging.getLogger(__name__)

VERSION = 1
RECORD_JSON = "record.json"
REPORT_JSON = "report.json"


def state_path(out_dir: Path, port: int) -> Path:
    """The state file of the panel listening on ``port`` with runs in ``out_dir``."""
    return out_dir / f".benchctl-panel-{port}.json"


def boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def identity(pid: int) -> str | None:
    """``<boot id>:<start time in clock ticks>`` of the live process ``pid`` (None: no such
    process, a zombie, or no ``/proc`` to tell)."""
    try:
        stat = Path(f"/proc/{int(pid)}/stat").read_text()
    except (OSError, ValueError):
        return None
    fields = stat[stat.rfind(")") + 2:].split()  # after "pid (comm) "; comm may hold spaces
    if len(fields) < 20 or fields[0] in ("Z", "X"):
        return None
    return f"{boot_id()}:{fields[19]}"


def is_the_run(pid: int, ident: str, sock: Path) -> bool:
    """Whether ``pid`` is still the run the file names: the same identity, and its command
    line the run's (``--live`` at the panel's socket)."""
    if not ident or identity(pid) != ident:
        return False
    try:
        argv = Path(f"/proc/{int(pid)}/cmdline").read_bytes().split(b"\0")
    except (OSError, ValueError):
        return False
    want = os.fsencode(str(sock))
    return any(a == b"--live" and b == want for a, b in itertools.pairwise(argv))


def save(path: Path, data: dict[str, Any]) -> None:
    """Write the state (never raises: the panel goes on without it, saying so in its log)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, dumps({"version": VERSION, "host": socket.gethostname(),
                                       "boot_id": boot_id(), **data}) + "\n")
    except (OSError, TypeError, ValueError) as e:
        log.warning("the panel's state not saved in %s: %s", path, e)


def load(path: Path) -> dict[str, Any] | None:
    """The state the file holds, if it is this computer's (None: none, unreadable, another
    host's or another boot's)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as e:
        log.warning("the panel's state in %s not read: %s", path, e)
        return None
    if not isinstance(data, dict) or data.get("version") != VERSION:
        return None
    if data.get("host") != socket.gethostname():
        return None
    return data


def remove(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    except OSError as e:
        log.warning("the panel's state %s not removed: %s", path, e)


def slim(result: dict[str, Any] | None) -> dict[str, Any] | None:
    """The part of a run's (or a plan's) JSON result the verdict screen shows."""
    if result is None:
        return None
    keep = ("verdict", "state", "reason", "recording", "record", "exit_code", "measured",
            "deviations", "outcome")
    out: dict[str, Any] = {k: result[k] for k in keep if k in result}
    abort = result.get("abort")
    if isinstance(abort, dict):
        out["abort"] = {k: v for k, v in abort.items() if k != "shutdown"}
    axes = result.get("axes")
    if isinstance(axes, dict):
        out["axes"] = {a: {k: v.get(k) for k in ("sigma", "sigma_ci95", "limit", "verdict")}
                       for a, v in axes.items() if isinstance(v, dict)}
    steps = result.get("steps")
    if isinstance(steps, list):
        out["steps"] = [{k: s.get(k) for k in ("name", "status", "reason", "recording")}
                        for s in steps if isinstance(s, dict)]
    return out


def from_recording(recording: Path) -> dict[str, Any] | None:
    """A run's result read from its recording, as its JSON output would have said it: a done
    run's ``report.json``, an aborted one's ``record.json`` (None: neither is there yet)."""
    def read(name: str) -> dict[str, Any] | None:
        try:
            obj = json.loads((recording / name).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return None
        return obj if isinstance(obj, dict) else None

    record = read(RECORD_JSON)
    if record is None:
        return None
    if record.get("outcome") == "ABORTED":
        abort = record.get("abort") or {}
        return {"verdict": "ABORTED", "state": "aborted", "reason": abort.get("reason", ""),
                "abort": abort, "recording": str(recording), "exit_code": record.get("exit_code"),
                "record": str(recording / RECORD_JSON)}
    report = read(REPORT_JSON)
    if report is None:
        return None
    report.setdefault("record", str(recording / RECORD_JSON))
    return report
