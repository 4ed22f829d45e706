"""Start the simulators as a child process for a run on a config with a ``sim:`` section.

The child is ``benchctl sim --config CFG --private --ready-json``: it prints one JSON line with
the endpoints once both simulators listen, and exits when its stdin closes (so a parent killed
with ``kill -9`` never leaves a simulator behind) or on SIGTERM. Running the simulators in their
own process keeps their 1 kHz physics off the run's interpreter, as a real stand would be.
"""

from __future__ import annotations

import json
import os
import selectors
import subprocess
import sys
import time
from types import TracebackType
from typing import Any

from benchctl.config import BenchConfig
from benchctl.errors import ConfigError, DeviceError, DeviceTimeout


class SimProcess:
    """A running ``benchctl sim`` child; ``config`` is the bench config pointed at it."""

    def __init__(self, cfg: BenchConfig, *, ready_timeout_s: float = 30.0) -> None:
        if cfg.source is None:
            raise ConfigError("the simulators need the bench config's file (cfg.source)")
        self.base = cfg
        self.ready_timeout_s = ready_timeout_s
        self.proc: subprocess.Popen[bytes] | None = None
        self.endpoints: dict[str, Any] = {}
        self.config: BenchConfig = cfg

    def start(self) -> SimProcess:
        cmd = [sys.executable, "-m", "benchctl", "sim", "--config", str(self.base.source)]
        cmd += ["--private", "--ready-json"]
        self.proc = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            start_new_session=True,  # a Ctrl-C to the run's terminal is the run's to handle
        )
        try:
            self.endpoints = self._await_ready()
        except BaseException:
            self.stop()
            raise
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
                    err = (
                        self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
                    )
                    raise DeviceError(f"simulators for {self.base.source} exited: {err.strip()}")
                buf += chunk
        finally:
            sel.close()
        msg = json.loads(buf.split(b"\n", 1)[0])
        if not msg.get("ready"):
            raise DeviceError(f"simulators for {self.base.source} failed: {msg}")
        return {"stand": msg["stand"], "instrument": msg["instrument"]}

    def stop(self) -> None:
        """Close the child's stdin (it exits), wait, and kill it if it lingers; idempotent."""
        proc, self.proc = self.proc, None
        if proc is None:
            return
        if proc.stdin is not None:
            proc.stdin.close()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
        for f in (proc.stdout, proc.stderr):
            if f is not None:
                f.close()

    def __enter__(self) -> SimProcess:
        return self.start()

    def __exit__(
        self, t: type[BaseException] | None, e: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def start_simulators(cfg: BenchConfig) -> SimProcess:
    """A ``SimProcess`` for ``cfg``; use as ``with start_simulators(cfg) as sim: ...``."""
    return SimProcess(cfg)

