"""Instrument frames per second received without loss: slcan (NMEA 2000 PGN 127257) and NMEA 0183.

The simulated instrument runs in its own process (as ``benchctl sim`` does) on a pty; the real
driver reads it in this process. For each output rate, after a 0.5 s warm-up, the driver
collects for ``--seconds`` and loss is counted by sequence: the NMEA 2000 SID (mod 253, so a
heavy loss is undercounted) over slcan, the PASHR time of day (ms) for NMEA 0183 up to
1000 Hz (above it, the simulator's count of refused frames). A pty has back-pressure: frames
are lost only when the reader falls so far behind that the simulator's 16 KiB output buffer
(its transmit FIFO) fills; ``sim_overflow`` counts those, ``sim_skipped`` the output instants
the simulator itself skipped when stalled.

Baselines measured in the same run, on the same kind of pty:
- slcan: python-can's slcan ``recv`` alone (no decoding) on a burst of pre-written frames;
- NMEA 0183: pyserial ``read`` + line split alone on a burst of pre-written sentences.
Physical ceilings for context (not measured): a 500 kbit/s bus carries at most ≈3,900
extended 8-byte frames/s; a UART slcan adapter at 115200 baud ≈420 lines/s; NMEA 0183 at
115200 baud ≈150 PASHR sentences/s, at 38400 baud ≈50.

Run: ``python benchmarks/instrument_rate.py [--seconds 3]``.
"""

from __future__ import annotations

import argparse
import itertools
import multiprocessing as mp
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import can
import serial

from benchctl.config import InstrumentConfig, SimInstrumentConfig
from benchctl.devices.instrument import open_instrument
from benchctl.sim import nmea_talker
from benchctl.sim.instrument import SimInstrument
from benchctl.sim.pty_port import PtyPort
from benchctl.sim.slcan import frame_line

ROOT = Path(__file__).resolve().parent.parent


class Static:
    def true_angles(self, t: float) -> dict[str, float]:
        return {"roll": 1.0, "pitch": -2.0}


def icfg(kind: str, path: str) -> InstrumentConfig:
    if kind == "slcan":
        return InstrumentConfig(driver="nmea2000", interface="slcan", channel=path,
                                dbc=ROOT / "drivers" / "nmea2000_attitude.dbc",
                                silence_timeout_s=5.0)
    return InstrumentConfig(driver="nmea0183", serial_port=path, sentence="PASHR",
                            silence_timeout_s=5.0)


def _child(kind: str, rate: float, link: str, conn: Any) -> None:
    sim = SimInstrument(SimInstrumentConfig(rate_hz=rate), icfg(kind, "x"), Static(),
                        link_path=Path(link))
    sim.inject("silent")
    sim.start()
    conn.send("ready")
    while True:
        cmd = conn.recv()
        if cmd == "talk":
            sim.clear_faults()
        elif cmd == "stop":
            counts = dict(sim.counts)
            sim.stop()
            conn.send(counts)
            return


def measure(kind: str, rate: float, seconds: float, tmp: Path) -> dict[str, float]:
    link = tmp / f"{kind}-{int(rate)}"
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_child, args=(kind, rate, str(link), child))
    proc.start()
    try:
        assert parent.recv() == "ready"
        dev = open_instrument(icfg(kind, str(link)))
        seq: list[float] = []
        recording = threading.Event()

        def on_sample(s: Any) -> None:
            if recording.is_set():
                seq.append(s.counter if kind == "slcan" else s.device_time_s)

        errors: list[BaseException] = []
        parent.send("talk")
        dev.connect()
        dev.start(on_sample, errors.append)
        time.sleep(0.5)
        before = dict(dev.stats.bad)
        recording.set()
        t0 = time.monotonic()
        time.sleep(seconds)
        recording.clear()
        elapsed = time.monotonic() - t0
        bad = {k: v - before.get(k, 0) for k, v in dev.stats.bad.items() if v - before.get(k, 0)}
        dev.close()
        parent.send("stop")
        counts = parent.recv()
    finally:
        proc.join(10)
        if proc.is_alive():
            proc.kill()
    lost = 0
    for a, b in itertools.pairwise(seq):
        step = (int(b) - int(a)) % 253 if kind == "slcan" else round(((b - a) % 86400.0) * rate)
        lost += max(0, step - 1)
    if kind == "nmea0183" and rate > 1000:  # ms time stamps no longer tell samples apart
        lost = counts["overflow"]
    n = len(seq)
    return {"rate": rate, "received_per_s": n / elapsed, "lost": lost,
            "loss_pct": 100.0 * lost / max(1, n + lost), "bad": sum(bad.values()),
            "sim_overflow": counts["overflow"], "sim_skipped": counts["skipped"],
            "errors": len(errors)}


def _blast(fd: int, line: bytes, n: int) -> None:
    """Write ``n`` copies of ``line`` to the pty master as fast as the reader takes them."""
    os.set_blocking(fd, True)
    chunk = line * 100
    for _ in range(n // 100):
        view = memoryview(chunk)
        while view:
            view = view[os.write(fd, view):]


def _baseline(line: bytes, n: int, read_one: Any, port: PtyPort) -> float:
    assert port.master_fd is not None
    writer = mp.get_context("fork").Process(target=_blast, args=(port.master_fd, line, n))
    got = 0
    t0 = time.monotonic()
    writer.start()
    deadline = time.monotonic() + 60
    while got < n and time.monotonic() < deadline:
        got += read_one()
    dt = time.monotonic() - t0
    writer.join(10)
    return got / dt


def baseline_slcan(n: int = 30000) -> float:
    """python-can's slcan ``recv`` alone, fed by another process as fast as it reads."""
    port = PtyPort()
    bus = can.Bus(interface="slcan", channel=port.path, bitrate=500000, sleep_after_open=0)
    line = frame_line(can.Message(arbitration_id=0x09F11980, is_extended_id=True, data=bytes(8)))
    try:
        return _baseline(line, n, lambda: bus.recv(timeout=0.1) is not None, port)
    finally:
        bus.shutdown()
        port.close()


def baseline_nmea(n: int = 30000) -> float:
    """pyserial ``read`` and a line split alone, fed by another process as fast as it reads."""
    port = PtyPort()
    ser = serial.serial_for_url(port.path, baudrate=115200, timeout=0.05)
    buf = bytearray()

    def read_lines() -> int:
        buf.extend(ser.read(max(1, ser.in_waiting)))
        k = buf.count(b"\n")
        del buf[:buf.rfind(b"\n") + 1]
        return k

    try:
        return _baseline(nmea_talker.pashr(0.0, 1.0, -2.0), n, read_lines, port)
    finally:
        ser.close()
        port.close()


def sweep(kind: str, rates: list[float], seconds: float, tmp: Path) -> float:
    print(f"\n{kind}: rate_hz  received/s  lost  loss%  bad  sim_overflow  sim_skipped  errors")
    best = 0.0
    lossy = 0
    for r in rates:
        m = measure(kind, r, seconds, tmp)
        print(f"{kind}: {m['rate']:7.0f}  {m['received_per_s']:10.1f}  {m['lost']:4d}  "
              f"{m['loss_pct']:5.2f}  {m['bad']:3d}  {m['sim_overflow']:12d}  "
              f"{m['sim_skipped']:11d}  {m['errors']:6d}")
        ok = (m["lost"] == 0 and m["sim_overflow"] == 0 and m["bad"] == 0
              and m["received_per_s"] > 0.95 * r)
        if ok:
            best = max(best, r)
            lossy = 0
        else:
            lossy += 1
            if lossy >= 2:
                break
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()
    print(f"machine: {os.cpu_count()} cores; measuring {args.seconds} s per rate")
    b_slcan = baseline_slcan()
    b_nmea = baseline_nmea()
    print(f"baseline: python-can slcan recv alone {b_slcan:,.0f} frames/s; "
          f"pyserial line split alone {b_nmea:,.0f} lines/s")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        best_can = sweep("slcan", [100, 500, 1000, 2000, 4000, 8000, 10000, 12000, 16000],
                         args.seconds, tmp)
        best_nmea = sweep("nmea0183", [100, 500, 1000, 2000, 4000, 8000, 16000], args.seconds, tmp)
    print(f"\nhighest rate without loss: slcan (NMEA 2000 PGN 127257) {best_can:.0f} frames/s; "
          f"NMEA 0183 PASHR {best_nmea:.0f} sentences/s")


if __name__ == "__main__":
    main()
