"""Helpers for the archive tests: a real PostgreSQL server in a temporary folder (the
distribution's ``initdb``/``pg_ctl``; as an unprivileged user when the tests run as root,
since PostgreSQL refuses to run as root), synthetic recordings with a record.json per the
record contract, and a worker for the two-writer tests (importable by a spawned process)."""

from __future__ import annotations

import json
import os
import pwd
import re
import shutil
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchctl.recording import RecordingWriter

# --- PostgreSQL ---------------------------------------------------------------------------------

def pg_bin_dir() -> Path | None:
    """The folder holding initdb and pg_ctl: PATH first, else the newest
    /usr/lib/postgresql/<version>/bin (where Debian puts them)."""
    found = shutil.which("pg_ctl")
    if found and shutil.which("initdb"):
        return Path(found).resolve().parent
    candidates = []
    for d in Path("/usr/lib/postgresql").glob("*/bin"):
        if (d / "initdb").is_file() and (d / "pg_ctl").is_file():
            m = re.match(r"\d+", d.parent.name)
            candidates.append((int(m.group()) if m else 0, d))
    return max(candidates)[1] if candidates else None


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _unprivileged_user() -> str:
    for name in ("postgres", "nobody"):
        try:
            pwd.getpwnam(name)
            return name
        except KeyError:
            continue
    raise RuntimeError("running as root and neither user postgres nor nobody exists")


@dataclass
class PgServer:
    bin_dir: Path
    folder: Path
    port: int
    user: str | None  # the user running the server (None: this process's own)

    @property
    def data(self) -> Path:
        return self.folder / "data"

    def url(self, db: str = "postgres") -> str:
        return f"postgresql+psycopg://bench@127.0.0.1:{self.port}/{db}"

    def _cmd(self, *args: str) -> list[str]:
        cmd = [str(self.bin_dir / args[0]), *args[1:]]
        return ["runuser", "-u", self.user, "--", *cmd] if self.user else cmd

    def _run(self, *args: str, timeout: float = 120.0) -> None:
        proc = subprocess.run(self._cmd(*args), capture_output=True, text=True, timeout=timeout,
                              cwd=self.folder, stdin=subprocess.DEVNULL)
        if proc.returncode != 0:
            log = self.folder / "server.log"
            tail = log.read_text()[-2000:] if log.is_file() else ""
            raise RuntimeError(f"{' '.join(args[:1])} failed ({proc.returncode}): "
                               f"{proc.stdout}{proc.stderr}{tail}")

    @classmethod
    def start(cls, folder: Path | None = None) -> PgServer:
        """Start a server in ``folder`` (None: a new folder under the system's temporary
        directory — one the server's user can reach, unlike pytest's 0700 folders)."""
        if folder is None:
            folder = Path(tempfile.mkdtemp(prefix="benchctl-pg-"))
        bin_dir = pg_bin_dir()
        if bin_dir is None:
            raise RuntimeError(
                "PostgreSQL's initdb/pg_ctl not found (PATH, /usr/lib/postgresql/*/bin): "
                "install the distribution's postgresql package (.ci/run does)"
            )
        user = _unprivileged_user() if os.geteuid() == 0 else None
        folder.mkdir(parents=True, exist_ok=True)
        if user is not None:
            pw = pwd.getpwnam(user)
            os.chown(folder, pw.pw_uid, pw.pw_gid)
        srv = cls(bin_dir, folder, free_port(), user)
        srv._run("initdb", "-D", str(srv.data), "-U", "bench", "--auth=trust", "-E", "UTF8",
                 "--no-locale", "--no-sync")
        opts = (f"-p {srv.port} -k {folder} -c listen_addresses=127.0.0.1 -c fsync=off "
                "-c synchronous_commit=off -c full_page_writes=off -c max_connections=50")
        srv._run("pg_ctl", "-D", str(srv.data), "-o", opts, "-l", str(folder / "server.log"),
                 "-w", "-t", "120", "start", timeout=180.0)
        return srv

    def stop(self) -> None:
        try:
            self._run("pg_ctl", "-D", str(self.data), "-m", "immediate", "-w", "-t", "60",
                      "stop")
        finally:
            shutil.rmtree(self.folder, ignore_errors=True)

    def create_database(self, name: str, owner: str = "bench") -> str:
        import psycopg

        with psycopg.connect(f"postgresql://bench@127.0.0.1:{self.port}/postgres",
                             autocommit=True, connect_timeout=30) as c:
            c.execute(f'CREATE DATABASE "{name}" OWNER "{owner}"')
        return self.url(name)

    def add_login(self, role: str, password: str) -> None:
        """A role that logs in over TCP with ``password`` only (SCRAM; the other roles keep
        the server's trust), so a test can tell whether the password reached the server."""
        import psycopg

        with psycopg.connect(f"postgresql://bench@127.0.0.1:{self.port}/postgres",
                             autocommit=True, connect_timeout=30) as c:
            c.execute("SET password_encryption = 'scram-sha-256'")
            c.execute(f"CREATE ROLE \"{role}\" LOGIN PASSWORD '{password}'")
        hba = self.data / "pg_hba.conf"
        hba.write_text(f"host all {role} 127.0.0.1/32 scram-sha-256\n" + hba.read_text())
        self._run("pg_ctl", "-D", str(self.data), "reload")


# --- synthetic recordings ---------------------------------------------------------------------

def make_record(run_id: str, *, serial: str = "SN-1", outcome: str = "PASS",
                sigma: float = 0.28, limit: float = 0.4, station: str = "bench-1",
                start: str = "2026-11-20T08:00:00.000+00:00", operator: str = "anna",
                part_number: str | None = "IN-100", recording: str = "/nowhere",
                axes: tuple[str, ...] = ("roll",), abort: dict[str, Any] | None = None,
                ) -> dict[str, Any]:
    """A record per the benchctl-record/1 contract."""
    ms = [{"name": "sigma", "axis": a, "value": sigma + 0.01 * i, "unit": "deg", "low": None,
           "high": limit, "ci95": [sigma * 0.97, sigma * 1.03], "outcome": outcome
           if outcome != "ABORTED" else None, "rule": "guarded"} for i, a in enumerate(axes)]
    ms.append({"name": "delay", "axis": axes[0], "value": 0.05, "unit": "s", "low": None,
               "high": None, "ci95": None, "outcome": "NOT_JUDGED", "rule": "simple"})
    return {
        "schema": "benchctl-record/1", "run_id": run_id,
        "software": {"name": "benchctl", "version": "1.2.3"},
        "outcome": outcome, "abort": abort,
        "decision_rule": {"name": "guarded", "text": "guarded acceptance"},
        "deviations": [], "warnings": [],
        "start_utc": start, "end_utc": start.replace("08:00", "08:20"),
        "unit": {"serial": serial, "part_number": part_number, "reported_serial": None,
                 "serial_match": None},
        "operator": operator, "station": station,
        "stand": {"identity": {"vendor": "sim"}, "calibration_due": None},
        "instruments": [{"role": "dut", "identity": {"serial": serial}}],
        "profile": {"name": "ci_short", "kind": "roll_spectrum", "seed": 7, "sha256": "ab" * 32},
        "config_sha256": "cd" * 32,
        "measurements": ms,
        "files": {"recording": recording,
                  "report_json": {"path": recording + "/report.json", "sha256": "ef" * 32}},
    }


def make_recording(out: Path, name: str, *, serial: str = "SN-1", close: str | None = "done",
                   reason: str = "PASS", record: dict[str, Any] | None = None,
                   report: dict[str, Any] | None = None, station: str = "bench-1") -> Path:
    """A small recording written by the real RecordingWriter: a few rows, closed ``close``
    (None: left open, as a killed run leaves it), with an optional record.json and
    report.json."""
    path = out / name
    meta = {"serial": serial, "operator": "anna", "station": station,
            "profile_name": "ci_short", "seed": 7, "config": {"unit": {"part_number": "IN-100"}}}
    w = RecordingWriter(path, ("roll",), meta)
    from benchctl.devices.base import InstrumentSample

    for i in range(5):
        t = float(i) * 0.01
        w.write_setpoint(t, {"roll": 0.1 * i})
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": 0.1 * i}))
    if close is not None:
        if report is not None:
            (path / "report.json").write_text(json.dumps(report))
        if record is not None:
            rec = dict(record)
            rec["files"] = {**rec["files"], "recording": str(path.resolve())}
            (path / "record.json").write_text(json.dumps(rec))
        w.close(close, reason)
    else:
        _drop(w)
    return path


def _drop(w: RecordingWriter) -> None:
    """Close the writer's files without end.json: what a killed process leaves."""
    for f in w._files.values():
        f.close()
    w._events.close()


def age(path: Path, seconds: float) -> None:
    """Date a recording's files back by ``seconds`` (a run killed that long ago)."""
    t = time.time() - seconds
    for p in [path, *path.iterdir()]:
        os.utime(p, (t, t))


# --- the two-writer worker ----------------------------------------------------------------------

def write_many(url: str, worker: int, n: int, shared: int) -> int:
    """Store ``n`` runs of its own and ``shared`` runs both workers store (same run_ids),
    spread over 5 serials; returns how many it stored."""
    from benchctl.archive.store import Archive

    done = 0
    with Archive(url, busy_timeout_s=60.0, connect_timeout_s=30.0) as a:
        for i in range(n):
            rec = make_record(f"w{worker}-{i:03d}", serial=f"SN-{i % 5}",
                              sigma=0.1 + 0.001 * i, axes=("roll", "pitch"),
                              start=f"2026-11-{10 + i % 10:02d}T08:00:00.000+00:00")
            a.store(rec)
            done += 1
            if i < shared:
                a.store(make_record(f"shared-{i:03d}", serial=f"SN-{i % 5}",
                                    axes=("roll", "pitch")))
                done += 1
    return done


# a short sine profile for the archive tests that run a session
SINE = """name: archive_sine
description: a short sine for the archive tests
reference: none (a test)
kind: sine
duration_s: 4
fade_in_s: 0.5
fade_out_s: 0.5
seed: 0
axes:
  roll: {amplitude_deg: 2.0, period_s: 2.0}
"""
