"""Prechecks: nothing moves until every one of them has passed.

Each check returns a ``CheckResult`` (recorded as a ``precheck`` event); ``require`` turns a
failed one into ``PrecheckFailed`` (a ``SafetyAbort``: the run aborts, exit code 2).

- the profile is within the stand's limits (``check_motion``), before any device is opened;
- there is disk space for the recording;
- each device answers and identifies itself (done at connect, recorded in meta.json);
- the stand is ready (no fault, no E-stop) and at rest; a latched fault or E-stop is named
  with the command that clears it (``benchctl stand reset``);
- under ``unit.serial_check: require``, the serial typed is the one the instrument reports
  (``check_serial``; an instrument that reports none cannot show it is the unit named);
- the host wakes its threads on time: its scheduling latency against the stand's buffer and
  watchdog (``benchctl.run.fitness``: the precheck ``host latency``, failed only under
  ``run.host_check.on_poor: refuse``);
- the instrument streams at its expected rate (± ``run.instrument_rate_tolerance``), reports
  every axis of the profile, and its static reading agrees with the stand's within
  ``instrument.static_tolerance_deg``;
- the unit is mounted as ``instrument.axes`` says (``run.mounting_check``: each axis tilted
  to a few degrees and back, the response fitted; ``benchctl.run.mounting`` and
  ``benchctl.run.mounting_check``): one mounted reversed or with roll and pitch swapped is
  refused, the message saying what was seen and how to fix it.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.errors import SafetyAbort
from benchctl.results.measurements import serial_match

REST_RATE_DEG_S = 0.5


class PrecheckFailed(SafetyAbort):
    """A precheck failed: the run is refused before the stand moves."""


@dataclass
class CheckResult:
    name: str
    ok: bool
    detail: str
    values: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "ok": self.ok, "detail": self.detail, "values": self.values}


def require(result: CheckResult) -> CheckResult:
    if not result.ok:
        raise PrecheckFailed(f"precheck '{result.name}' failed: {result.detail}")
    return result


def check_serial(typed: str, reported: str | None) -> CheckResult:
    """The serial typed against the one the instrument reports, as a precheck (``unit.
    serial_check: require``): a mismatch, or no serial reported, refuses the run."""

    values = {"typed": typed, "reported": reported}
    match = serial_match(typed, reported)
    if match is None:
        return CheckResult("serial match", False,
                           f"serial {typed!r} typed, but the instrument reports no serial to "
                           "check it against (unit.serial_check: require; set it to warn for "
                           "an instrument that reports none)", values)
    if not match:
        return CheckResult("serial match", False,
                           f"serial {typed!r} typed, the instrument reports {reported!r}: the "
                           "unit mounted is not the one named (unit.serial_check: require) — "
                           "mount that unit, or run again with the serial of the unit mounted",
                           values)
    return CheckResult("serial match", True,
                       f"serial {typed!r} typed, the instrument reports {reported!r}", values)


def check_disk(out_dir: Path, min_free_mb: float, *, quiet: bool = False) -> CheckResult:
    """Free space on the filesystem of ``out_dir`` (its nearest existing parent). ``quiet``
    (a run on simulated time): checked as ever, but the free space is not recorded when there
    is enough — the host's disk must not reach a simulated recording's data."""
    p = out_dir.resolve()
    while not p.exists() and p != p.parent:
        p = p.parent
    free_mb = shutil.disk_usage(p).free / 1e6
    ok = free_mb >= min_free_mb
    if quiet and ok:
        return CheckResult(
            "disk space",
            ok,
            f"at least {min_free_mb:g} MB free (run.min_free_disk_mb)",
            {"min_free_mb": min_free_mb},
        )
    return CheckResult(
        "disk space",
        ok,
        f"{free_mb:.0f} MB free at {p} (run.min_free_disk_mb = {min_free_mb:g} MB)",
        {"free_mb": free_mb, "min_free_mb": min_free_mb},
    )


def clear_fault_hint(config: Path | str | None = None) -> str:
    """How an operator clears a latched fault or E-stop (named wherever one is found)."""
    where = f" --config {config}" if config is not None else ""
    return (f"a latched fault or E-stop stays until it is reset: once its cause is dealt with, "
            f"`benchctl stand reset{where}` clears it (`benchctl stand home{where}` then brings "
            "the stand to zero)")


def _status_problems(st: StandStatus) -> list[str]:
    problems = []
    if st.estop:
        problems.append("E-stop is engaged")
    if st.fault:
        problems.append(f"fault code {st.fault_code}")
    if st.limit:
        problems.append("a limit switch is active")
    if not st.ready:
        problems.append("not ready")
    return problems


def check_stand_ready(
    status: StandStatus,
    sample: StandSample | None,
    axes: Sequence[str],
    config: Path | str | None = None,
) -> CheckResult:
    """The stand is ready, not faulted, not moving, at rest on every axis of the profile.

    ``sample`` None: a stand whose status reports a fault or an E-stop (its sample cannot be
    read); the detail then names the command that clears it (``config``: the bench config's
    file, shown in that command)."""
    problems = _status_problems(status)
    if status.moving:
        problems.append("reports moving")
    if sample is None:
        if status.fault or status.estop:
            problems.append(clear_fault_hint(config))
        return CheckResult("stand ready and at rest", not problems,
                           "; ".join(problems) or "ready", {"fault_code": status.fault_code})
    missing = [a for a in axes if a not in sample.angle_deg]
    if missing:
        problems.append(f"has no axis {missing} (stand axes: {sorted(sample.angle_deg)})")
    for a, r in sample.rate_deg_s.items():
        if abs(r) > REST_RATE_DEG_S:
            problems.append(
                f"{a} moving at {r:+.2f}°/s (at rest means |rate| ≤ {REST_RATE_DEG_S}°/s)"
            )
    if status.fault or status.estop:
        problems.append(clear_fault_hint(config))
    angles = ", ".join(f"{a} {v:+.3f}°" for a, v in sample.angle_deg.items())
    return CheckResult(
        "stand ready and at rest",
        not problems,
        "; ".join(problems) if problems else f"ready, at rest ({angles})",
        {"angle_deg": dict(sample.angle_deg), "rate_deg_s": dict(sample.rate_deg_s)},
    )


def check_stand_at_zero(sample: StandSample, tolerance_deg: float) -> CheckResult:
    off = {a: v for a, v in sample.angle_deg.items() if abs(v) > tolerance_deg}
    detail = (
        "at zero"
        if not off
        else ", ".join(f"{a} at {v:+.3f}°" for a, v in off.items())
        + f" (stand.zero_tolerance_deg = {tolerance_deg}°)"
    )
    return CheckResult("stand at zero", not off, detail, {"angle_deg": dict(sample.angle_deg)})


def check_instrument_rate(
    samples: Sequence[InstrumentSample],
    window_s: float,
    expected_hz: float,
    tolerance: float,
    axes: Sequence[str],
) -> CheckResult:
    """Samples per second within ``expected_hz·(1 ± tolerance)``; every axis present."""
    n = len(samples)
    rate = n / window_s
    lo, hi = expected_hz * (1 - tolerance), expected_hz * (1 + tolerance)
    problems = []
    if not lo <= rate <= hi:
        problems.append(
            f"{n} samples in {window_s:g} s = {rate:.1f} Hz, expected {expected_hz:g} Hz "
            f"(instrument.expected_rate_hz, ±{tolerance:.0%})"
        )
    if samples:
        missing = [a for a in axes if a not in samples[-1].angle_deg]
        if missing:
            problems.append(
                f"reports no {missing} (it reports {sorted(samples[-1].angle_deg)}; "
                f"the profile moves {list(axes)})"
            )
    return CheckResult(
        "instrument streams",
        not problems,
        "; ".join(problems) if problems else f"{rate:.1f} Hz (expected {expected_hz:g} Hz)",
        {"rate_hz": rate, "expected_hz": expected_hz, "n": n},
    )


def check_static_agreement(
    samples: Sequence[InstrumentSample],
    stand_angle_deg: dict[str, float],
    tolerance_deg: float,
    axes: Sequence[str],
) -> CheckResult:
    """At rest, the instrument's mean reading agrees with the stand's within the tolerance."""
    diffs: dict[str, float] = {}
    for a in axes:
        vals = [
            s.angle_deg[a] for s in samples if a in s.angle_deg and math.isfinite(s.angle_deg[a])
        ]
        diffs[a] = float(np.mean(vals)) - stand_angle_deg[a] if vals else math.nan
    bad = {a: d for a, d in diffs.items() if not abs(d) <= tolerance_deg}
    detail = ", ".join(f"{a}: instrument − stand = {d:+.3f}°" for a, d in diffs.items())
    if bad:
        detail += f" (instrument.static_tolerance_deg = {tolerance_deg}°)"
    return CheckResult("static agreement", not bad, detail, {"difference_deg": diffs})
