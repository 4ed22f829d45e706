"""Start the simulators as a child process for a run on a config with a ``sim:`` section.

The child is ``benchctl sim --config CFG --private --ready-json``: it prints one JSON line with
the endpoints once both simulators listen, and exits when its stdin closes (so a parent killed
with ``kill -9`` never leaves a simulator behind) or on SIGTERM. Running the simulators in their
own process keeps their 1 kHz physics off the run's interpreter, as a real stand would be.

The child's output (its log, any error) goes to a file, ``log_path`` (the run's recording gives
``<recording>/sim.log``), never to a pipe nobody reads (a full pipe would block the simulators);
its stdout carries the one ready line and is then pointed at the same file.
"""

from __future__ import annotations

import contextlib
import json
import os
import selectors
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from benchctl.config import BenchConfig
from benchctl.errors import ConfigError, DeviceError, DeviceTimeout


class SimProcess:
    """A running ``benchctl sim`` child; ``config`` is the bench config pointed at it."""

    def __init__(
        self, cfg: BenchConfig, *, ready_timeout_s: float = 30.0, log_path: Path | None = None
    ) -> None:
        if cfg.source is None:
            raise ConfigError("the simulators need the bench config's file (cfg.source)")
        self.base = cfg
        self.ready_timeout_s = ready_timeout_s
        self.log_path = log_path  # None: an anonymous temporary file
        self._log: IO[bytes] | None = None
        self.proc: subprocess.Popen[bytes] | None = None
        self.endpoints: dict[str, Any] = {}
        self.config: BenchConfig = cfg

    def start(self) -> SimProcess:
        cmd = [sys.executable, "-m", "benchctl", "sim", "--config", str(self.base.source)]
        cmd += ["--private", "--ready-json"]
        if self.log_path is not None:
            try:
                self._log = self.log_path.open("a+b")
            except OSError as e:
                raise DeviceError(
                    f"simulators for {self.base.source}: cannot open their log {self.log_path}: "
                    f"{e.strerror}"
                ) from None
        else:
            self._log = tempfile.TemporaryFile()  # noqa: SIM115 (closed in stop)
        stamp = datetime.now(UTC).isoformat(timespec="milliseconds")
        self._log.write(f"{stamp} benchctl run starts the simulators: {' '.join(cmd)}\n".encode())
        self._log.flush()
        try:
            self.proc = subprocess.Popen(
                cmd,
                stdin=subprocess.PIPE,  # kept open: the child exits when it closes (kill -9)
                stdout=subprocess.PIPE,  # the ready line only
                stderr=self._log,
                start_new_session=True,  # a Ctrl-C to the run's terminal is the run's to handle
            )
        except BaseException:
            self._close_log()
            raise
        with contextlib.suppress(OSError):
            self._log.write(f"{stamp} simulators started, pid {self.proc.pid}\n".encode())
            self._log.flush()
        try:
            self.endpoints = self._await_ready()
        except BaseException:
            self.stop()
            raise
        assert self.proc.stdout is not None
        self.proc.stdout.close()  # the child writes nothing more there (it points it at the log)
        stand = self.base.stand.model_copy(update=self.endpoints["stand"])
        instrument = self.base.instrument.model_copy(update=self.endpoints["instrument"])
        self.config = self.base.model_copy(update={"stand": stand, "instrument": instrument})
        return self

    def _await_ready(self) -> dict[str, Any]:
        assert self.proc is not None and self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + self.ready_timeout_s
        buf = b""
        try:
            while b"\n" not in buf:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise DeviceTimeout(
                        f"simulators for {self.base.source} not ready within "
                        f"{self.ready_timeout_s:.0f} s"
                    )
                if not sel.select(left):
                    continue
                chunk = os.read(self.proc.stdout.fileno(), 4096)
                if not chunk:
                    with contextlib.suppress(subprocess.TimeoutExpired):
                        self.proc.wait(timeout=10)  # its last words reach the log first
                    raise DeviceError(
                        f"simulators for {self.base.source} exited: {self._log_tail()}"
                        + (f" (log {self.log_path})" if self.log_path else "")
                    )
                buf += chunk
        finally:
            sel.close()
        try:
            msg = json.loads(buf.split(b"\n", 1)[0])
        except ValueError:
            raise DeviceError(
                f"simulators for {self.base.source}: not a ready line: {buf[:200]!r}"
            ) from None
        if not msg.get("ready"):
            raise DeviceError(f"simulators for {self.base.source} failed: {msg}")
        return {"stand": msg["stand"], "instrument": msg["instrument"]}

    def _log_tail(self, n: int = 2000) -> str:
        """The end of the child's log: why it exited."""
        f = self._log
        if f is None:
            return ""
        try:
            f.flush()
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - n))
            lines = f.read().decode(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return " | ".join(line for line in lines[-5:] if line.strip())

    def _close_log(self) -> None:
        f, self._log = self._log, None
        if f is not None:
            with contextlib.suppress(OSError):
                f.close()

    def stop(self) -> None:
        """Close the child's stdin (it exits), wait, and kill it if it lingers; idempotent and
        never raises (it runs on every way out of a run)."""
        proc, self.proc = self.proc, None
        try:
            if proc is None:
                return
            for f in (proc.stdin, proc.stdout):
                if f is not None:
                    with contextlib.suppress(OSError):
                        f.close()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                with contextlib.suppress(subprocess.TimeoutExpired):  # unkillable (D state)
                    proc.wait(timeout=10)
        finally:
            self._close_log()

    def __enter__(self) -> SimProcess:
        return self.start()

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def start_simulators(cfg: BenchConfig, log_path: Path | None = None) -> SimProcess:
    """A ``SimProcess`` for ``cfg``, its output to ``log_path``; use as
    ``with start_simulators(cfg, log_path=…) as sim: ...``."""
    return SimProcess(cfg, log_path=log_path)
