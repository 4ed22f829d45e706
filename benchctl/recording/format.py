"""Layout of a benchctl recording: a folder of append-only files on one host clock.

::

    <recording>/
      meta.json         written once at start: format, version, config, profile (with seed),
                        device identities, serial number, operator, station, software version,
                        start time (UTC and monotonic), axes
      stand.csv         t_host, rtt_s, <axis>_deg…, <axis>_rate_deg_s…, <axis>_setpoint_deg…,
                        status, fault_code, t_lo, t_hi, stand_time_s
                        (t_host = where the stand took the state: TCP the midpoint of request
                        and reply, RTU the end of the request on the wire, monotonic seconds;
                        [t_lo, t_hi] the host times it can have been taken between; stand_time_s
                        the stand's own clock then, wrapping, where its map has sample_time)
      instrument.csv    t_host, device_time_s, counter, adapter_time_s, <axis>_deg…
                        (t_host = receipt time; adapter_time_s = the CAN adapter's timestamp)
      setpoints.csv     t_send, t_slot, <axis>_deg…                    (commanded motion: the
                        profile's value at its slot time t_slot, sent at t_send)
      events.jsonl      one JSON object a line: state changes, faults, notes
      end.json          written at close: state (done|aborted), reason, end time, counters,
                        integrity (rows, bytes and SHA-256 of each data file)
      end.json.reserve  room kept on the disk for end.json while the run goes (deleted at
                        close; a killed run leaves it)
      can.blf|can.asc   raw CAN frames (python-can logger), when the instrument is on CAN
      benchctl.log      the run's log (INFO and up; the traceback of an unexpected exception)
      sim.log           the simulators' output, when the run started them (config with sim:)

``meta.json`` may be rewritten (atomically) while the run goes, as facts become known (device
identities after connect); ``events.jsonl`` carries every state change of the run
(``{"kind": "state", "from", "to", "reason"}``) and ``motion_start``; ``end.json`` also holds the
``analysis_window`` ([t0, t1] monotonic seconds: the steady part of the profile, fades
excluded) that the verdict was computed on, and the run's timing statistics.

Every data line is written straight through to the OS (line-buffered), so ``kill -9`` at any
moment loses nothing already written; a torn last line is dropped by the reader. A recording
with no ``end.json`` was not closed (the process died) and reads as state ``incomplete``. A write
that fails (disk full) aborts the run; later rows are dropped, and ``end.json`` (when it can still
be written) gives ``recording_error``, ``dropped_rows`` and ``dropped_events``.
Floats are written with ``repr`` (shortest exact round trip).

``end.json``'s ``integrity`` (``{"algorithm": "sha256", "files": {name: {rows, bytes,
sha256}}}``) covers the files final at close: ``stand.csv``, ``instrument.csv``,
``setpoints.csv`` (rows: data lines after the header), ``events.jsonl`` (rows: lines) and
``meta.json`` (bytes and hash only). The reader checks them; a file changed after the run closed
it (truncated, edited) is an integrity failure. ``can.blf``, ``sim.log``, ``benchctl.log`` and
the reports are written after or beside the close and are not covered (``record.json`` names
the reports' hashes).
"""

from __future__ import annotations

from pathlib import Path

FORMAT_NAME = "benchctl-recording"
FORMAT_VERSION = 1

META_FILE = "meta.json"
END_FILE = "end.json"
RESERVE_FILE = "end.json.reserve"
RESERVE_BYTES = 256 * 1024  # end.json, record.json and an aborted run's report.html fit in it
INTEGRITY_ALGORITHM = "sha256"
EVENTS_FILE = "events.jsonl"
STREAM_FILES = {"stand": "stand.csv", "instrument": "instrument.csv", "setpoints": "setpoints.csv"}


def stand_columns(axes: tuple[str, ...]) -> list[str]:
    return (
        ["t_host", "rtt_s"]
        + [f"{a}_deg" for a in axes]
        + [f"{a}_rate_deg_s" for a in axes]
        + [f"{a}_setpoint_deg" for a in axes]
        + ["status", "fault_code", "t_lo", "t_hi", "stand_time_s"]
    )


def instrument_columns(axes: tuple[str, ...]) -> list[str]:
    return ["t_host", "device_time_s", "counter", "adapter_time_s"] + [f"{a}_deg" for a in axes]


def setpoint_columns(axes: tuple[str, ...]) -> list[str]:
    return ["t_send", "t_slot"] + [f"{a}_deg" for a in axes]


STREAM_COLUMNS = {
    "stand": stand_columns,
    "instrument": instrument_columns,
    "setpoints": setpoint_columns,
}


def is_recording(path: str | Path) -> bool:
    """True when ``path`` is a folder holding a benchctl recording."""
    p = Path(path)
    return p.is_dir() and (p / META_FILE).is_file()
