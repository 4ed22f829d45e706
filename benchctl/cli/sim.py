"""``benchctl sim``: the simulated stand and instrument as one standalone process."""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.clock import REAL, EventLike
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode

if TYPE_CHECKING:
    from benchctl.config import BenchConfig


def register(sub: Any) -> None:
    p = sub.add_parser(
        "sim",
        help="run the simulated stand and instrument (real protocol peers) until stopped",
        description=(
            "Start the simulated stand (Modbus TCP or RTU) and the simulated instrument on it "
            "(CANopen/J1939/NMEA 2000 over slcan, or NMEA 0183, on a pseudo-terminal) where "
            "the config says, print where they listen, and run until Ctrl-C or SIGTERM."
        ),
    )
    p.add_argument("--config", required=True, type=Path, help="bench config with a sim: section")
    p.add_argument(
        "--private",
        action="store_true",
        help="free TCP port and private ptys instead of the config's port and paths",
    )
    p.add_argument(
        "--ready-json",
        action="store_true",
        help="print one JSON line with the endpoints when ready; exit when stdin closes",
    )
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from benchctl.config import load_config

    cfg = load_config(args.config)
    # the simulators' own process serves in real time until a signal or stdin's end
    done = REAL.event()

    def on_signal(signum: int, frame: object) -> None:
        done.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        return _serve(args, cfg, done)
    finally:  # called in-process (tests, scripts): the caller's handlers come back
        for s, h in old.items():
            signal.signal(s, h)


def _serve(args: argparse.Namespace, cfg: BenchConfig, done: EventLike) -> int:
    from benchctl.sim.bench import SimBench

    if not args.private:  # refuse to serve a stand endpoint a run holds (benchctl.run.lock)
        from benchctl.run.lock import check_free

        check_free(cfg, {"command": "benchctl sim", "config": str(cfg.source)})
    bench = SimBench(cfg, private=args.private)
    try:
        bench.start()
    except Exception as e:
        if args.ready_json:
            print(dumps({"ready": False, "error": str(e)}), flush=True)
        raise
    try:
        if args.ready_json:
            print(dumps({"ready": True, **bench.endpoints()}), flush=True)
            # the parent reads nothing more there: later output joins stderr (its log file)
            os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
            watcher = REAL.thread(_wait_eof, name="sim-stdin-eof", args=(done,))
            watcher.start()
        else:
            print(f"benchctl sim: {cfg.source}", flush=True)
            for line in bench.describe():
                print(f"  {line}", flush=True)
            print("  Ctrl-C to stop", flush=True)
        done.wait()
    finally:
        bench.stop()
    return ExitCode.OK


def _wait_eof(done: EventLike) -> None:
    try:
        while os.read(sys.stdin.fileno(), 4096):
            pass
    except (OSError, ValueError):
        pass
    done.set()
