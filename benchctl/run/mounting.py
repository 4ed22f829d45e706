"""The mounting check's pure half: the tilt's points, the instrument's response fitted to
them, and the verdict with the operator's message. No I/O, no clock (the run layer,
``benchctl.run.mounting_check``, plays the tilt on the stand and hands the samples here).

**The tilt.** Each axis in turn goes from rest at zero to ``+tilt_deg``, holds there, comes
back to zero and holds again, the others held at zero. The ramps are
``benchctl.kinematics.plan_ramp_to_zero``'s (the stop ramp's planning: rate and acceleration
limited at every step), at ``TILT_RATE_DEG_S`` and ``TILT_ACCEL_DEG_S2`` or ``RAMP_MARGIN``
of the stand's limits where those are lower; the whole sequence is checked step by step
against the limits (``check_sequence``) before anything is sent.

**The fit.** Every reading of the instrument (its axes after ``instrument.axes``) against the
stand's measured angles, by least squares with an offset: ``reading = Σ_s G[reading][s] ·
stand_s + c``. The stand's axes move one at a time, so each ``G[r][s]`` is the reading's
response to that axis alone. The stand is taken at each instrument instant less the
instrument's delay, the one (0 … 0.5 s) that leaves the least (``fit_sampled``): its lag and
latency then do not lower the gain on the ramps.

**The verdict.** The reading of a tilted axis must follow it with a gain within
1 ± ``gain_tolerance``, and no reading may respond to another axis by more than
± ``cross_tolerance``. The mounting errors are named: a gain near −1 (reversed), a reading
that follows the other axis and not its own (roll and pitch swapped), one that follows
nothing; the message says what was seen and how to fix it (remount, or the
``instrument.axes`` setting that reads the unit as it is mounted).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.errors import DataError
from benchctl.kinematics import AxisCommand, Limits, check_sequence, plan_ramp_to_zero

TILT_RATE_DEG_S = 4.0  # the tilt's rate at most (slow: a few degrees in about a second)
TILT_ACCEL_DEG_S2 = 8.0  # … and its acceleration
RAMP_MARGIN = 0.8  # at most this share of the stand's rate and acceleration limits
REST_S = 0.5  # at rest at zero before each axis's tilt and after it


def tilt_points(
    axes: Sequence[str], tilt_deg: float, hold_s: float, limits: Limits, period_s: float
) -> dict[str, NDArray[np.float64]]:
    """The tilt's points, one per ``period_s`` from rest at zero, for every axis of ``axes``:
    each axis in turn up to ``+tilt_deg``, held ``hold_s``, back to zero, at rest ``REST_S``
    before and after. Raises ``LimitError`` (needed vs allowed) should any step break
    ``limits`` (a tilt beyond the angle limit)."""
    if not axes:
        raise ValueError("tilt_points: no axis to tilt")
    rate = min(TILT_RATE_DEG_S, RAMP_MARGIN * limits.rate_deg_s)
    accel = min(TILT_ACCEL_DEG_S2, RAMP_MARGIN * limits.accel_deg_s2)
    down = plan_ramp_to_zero(tilt_deg, 0.0, rate, accel, period_s)  # after +tilt … 0
    up = np.concatenate((down[::-1][1:], [tilt_deg]))  # after 0 … +tilt (the same ramp)
    rest = np.zeros(max(1, math.ceil(REST_S / period_s)))
    hold = np.full(max(1, math.ceil(hold_s / period_s)), float(tilt_deg))
    one = np.concatenate((rest, up, hold, down, rest))
    n = one.size * len(axes)
    out = {a: np.zeros(n) for a in axes}
    for i, a in enumerate(axes):
        out[a][i * one.size:(i + 1) * one.size] = one
    for a, v in out.items():
        check_sequence(a, AxisCommand(0.0, 0.0), v, limits, period_s)
    return out


@dataclass(frozen=True)
class Response:
    """The instrument's response to the stand: ``gain[reading][stand axis]``, the reading's
    ``offset_deg`` and the RMS of what the fit leaves (``residual_deg``), over ``n`` samples."""

    gain: dict[str, dict[str, float]]
    offset_deg: dict[str, float]
    residual_deg: dict[str, float]
    n: int

    def to_dict(self) -> dict[str, Any]:
        return {"gain": self.gain, "offset_deg": self.offset_deg,
                "residual_deg": self.residual_deg, "n": self.n}


def fit_response(
    stand: Mapping[str, ArrayLike], instrument: Mapping[str, ArrayLike]
) -> Response:
    """Least squares of each instrument reading against every stand axis at once, with an
    offset: ``reading = Σ_s gain[reading][s] · stand[s] + offset``. The arrays are at the same
    instants (the stand interpolated at the instrument's); an instant with a value that is not
    finite is left out. ``DataError`` when a stand axis does not move or too few instants
    remain."""
    s_axes, r_axes = list(stand), list(instrument)
    if not s_axes or not r_axes:
        raise DataError("mounting check: no stand axis or no instrument reading to fit")
    x = np.column_stack([np.asarray(stand[a], dtype=float) for a in s_axes])
    y = np.column_stack([np.asarray(instrument[r], dtype=float) for r in r_axes])
    if x.shape[0] != y.shape[0]:
        raise DataError(f"mounting check: {x.shape[0]} stand values against {y.shape[0]} "
                        "instrument values")
    keep = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(y), axis=1)
    x, y = x[keep], y[keep]
    n = int(x.shape[0])
    if n < len(s_axes) + 2:
        raise DataError(f"mounting check: {n} usable samples, too few to fit")
    xm, ym = x.mean(axis=0), y.mean(axis=0)
    xc, yc = x - xm, y - ym
    spread = np.sqrt(np.mean(xc * xc, axis=0))
    still = [a for a, sd in zip(s_axes, spread, strict=True) if not sd > 1e-6]
    if still:
        raise DataError(f"mounting check: the stand's {', '.join(still)} did not move")
    # scaled columns: a well-conditioned solve whatever the tilt
    g_scaled, *_ = np.linalg.lstsq(xc / spread, yc, rcond=None)
    g = g_scaled / spread[:, None]  # stand axes × readings
    res = yc - xc @ g
    offset = ym - xm @ g
    return Response(
        gain={r: {s: float(g[i, j]) for i, s in enumerate(s_axes)} for j, r in enumerate(r_axes)},
        offset_deg={r: float(offset[j]) for j, r in enumerate(r_axes)},
        residual_deg={r: float(np.sqrt(np.mean(res[:, j] ** 2))) for j, r in enumerate(r_axes)},
        n=n,
    )


MAX_DELAY_S = 0.5  # the instrument's delay (lag, latency, its link) looked for up to this
DELAY_STEP_S = 0.005


def fit_sampled(
    t_stand: ArrayLike,
    stand: Mapping[str, ArrayLike],
    t_instrument: ArrayLike,
    instrument: Mapping[str, ArrayLike],
    max_delay_s: float = MAX_DELAY_S,
) -> tuple[Response, float]:
    """``fit_response`` of samples at their own instants: the stand's angles (at ``t_stand``,
    increasing) interpolated at each instrument instant less a delay d, for every d from 0 to
    ``max_delay_s`` by ``DELAY_STEP_S``; the fit that leaves the least (summed mean square
    residual) and its d. The instrument's delay taken out, its lag no longer lowers the gain
    on the ramps (a MEMS unit of 80 ms lag read 0.97× for its 0.995× without it). Instrument
    instants outside the stand's samples are left out."""
    ts = np.asarray(t_stand, dtype=float)
    ti = np.asarray(t_instrument, dtype=float)
    xs = {a: np.asarray(v, dtype=float) for a, v in stand.items()}
    ys = {r: np.asarray(v, dtype=float) for r, v in instrument.items()}
    if ts.size < 2 or ti.size < 2:
        raise DataError(f"mounting check: {ts.size} stand and {ti.size} instrument samples "
                        "during the tilt: too few to fit")
    best: tuple[float, Response, float] | None = None
    for d in np.arange(0.0, max_delay_s + 1e-12, DELAY_STEP_S):
        keep = (ti - d >= ts[0]) & (ti - d <= ts[-1])
        x = {a: np.interp(ti[keep] - d, ts, v) for a, v in xs.items()}
        r = fit_response(x, {k: v[keep] for k, v in ys.items()})
        cost = float(sum(e * e for e in r.residual_deg.values()))
        if best is None or cost < best[0]:
            best = (cost, r, float(d))
    assert best is not None
    return best[1], best[2]


# ------------------------------------------------------------------------------ the verdict
OK, REVERSED, SWAPPED, NO_RESPONSE, GAIN, CROSS = (
    "ok", "reversed", "swapped", "no response", "gain", "cross")


@dataclass(frozen=True)
class Finding:
    """What one reading showed: ``kind`` (``OK``, ``REVERSED``, ``SWAPPED``, ``NO_RESPONSE``,
    ``GAIN``, ``CROSS``), the words for it, and the ``instrument.axes`` entries that read the
    unit as it is mounted ({stand axis: (output, sign)}; empty when no setting can)."""

    reading: str
    kind: str
    text: str
    fix: dict[str, tuple[str, int]] = field(default_factory=dict)


@dataclass(frozen=True)
class Verdict:
    ok: bool
    findings: list[Finding]
    messages: list[str]  # one per problem, for the operator

    @property
    def detail(self) -> str:
        return "; ".join(self.messages)


def _x(g: float) -> str:
    """A gain as the operator reads it: ``−1.00×``."""
    text = f"{g:.2f}"
    return ("0.00" if text == "-0.00" else text).replace("-", "−") + "×"


def _sign(g: float) -> int:
    return 1 if g >= 0 else -1


def classify(
    reading: str,
    gains: Mapping[str, float],
    mapping: Mapping[str, tuple[str, int]],
    gain_tolerance: float,
    cross_tolerance: float,
) -> Finding:
    """One reading's response ``gains`` ({tilted stand axis: gain}) judged. ``mapping``:
    ``instrument.axes`` as {stand axis: (output, sign)} (what a fix changes)."""
    own = gains.get(reading)
    others = {s: g for s, g in gains.items() if s != reading}
    big = {s: g for s, g in others.items() if abs(g) > cross_tolerance}
    output, sign = mapping.get(reading, (reading, 1))
    if own is not None and not big:
        if abs(own - 1.0) <= gain_tolerance:
            return Finding(reading, OK, f"{reading} reads {_x(own)} the stand's {reading}")
        if abs(own + 1.0) <= gain_tolerance:
            return Finding(reading, REVERSED,
                           f"{reading} reads {_x(own)} the stand's {reading}",
                           {reading: (output, -sign)})
        if abs(own) <= cross_tolerance:
            return Finding(reading, NO_RESPONSE,
                           f"{reading} does not follow the stand's {reading} ({_x(own)}, "
                           f"expected 1 ± {gain_tolerance:g})")
        return Finding(reading, GAIN,
                       f"{reading} reads {_x(own)} the stand's {reading} (expected "
                       f"1 ± {gain_tolerance:g})")
    if own is None and not big:
        return Finding(reading, OK, f"{reading} does not respond to the stand's "
                       + ", ".join(others) if others else f"{reading}: not tilted")
    if (own is None or abs(own) <= cross_tolerance) and len(big) == 1:
        (s, g), = big.items()
        if abs(abs(g) - 1.0) <= gain_tolerance:
            text = f"{reading} reads the stand's {s} ({_x(g)})" + (
                f" and not its {reading}" if own is not None else "")
            return Finding(reading, SWAPPED, text, {s: (output, sign * _sign(g))})
    parts = []
    if own is not None and abs(own - 1.0) > gain_tolerance:
        parts.append(f"{reading} reads {_x(own)} the stand's {reading} (expected "
                     f"1 ± {gain_tolerance:g})")
    parts.extend(f"{reading} reads {_x(g)} the stand's {s} (expected within "
                 f"±{cross_tolerance:g})" for s, g in big.items())
    return Finding(reading, CROSS, "; ".join(parts))


def _axis_order(a: str) -> tuple[int, str]:
    return (0 if a == "roll" else 1 if a == "pitch" else 2, a)


def _setting(fix: Mapping[str, tuple[str, int]], mapping: Mapping[str, tuple[str, int]]) -> str:
    """The ``instrument.axes`` fields a fix changes, as the operator types them."""
    parts = []
    for a, (o, s) in sorted(fix.items(), key=lambda e: _axis_order(e[0])):
        was_o, was_s = mapping.get(a, (a, 1))
        if o != was_o:
            parts.append(f"instrument.axes.{a}.output: {o}")
        if s != was_s:
            parts.append(f"instrument.axes.{a}.sign: {s}")
    return " and ".join(parts)


def judge(
    response: Response,
    tilted: Sequence[str],
    mapping: Mapping[str, tuple[str, int]],
    gain_tolerance: float,
    cross_tolerance: float,
    config: str = "the bench config",
) -> Verdict:
    """The mounting check's verdict from the fitted ``response`` to the ``tilted`` stand axes:
    every reading classified (``classify``); the problems as the operator's messages, each
    with its likely cause and its fix (``config``: the bench config's file, named in it)."""
    findings = [
        classify(r, {s: g[s] for s in tilted if s in g}, mapping, gain_tolerance,
                 cross_tolerance)
        for r, g in response.gain.items()
    ]
    bad = [f for f in findings if f.kind != OK]
    messages: list[str] = []
    remount = "Remount the unit"
    swapped = [f for f in bad if f.kind == SWAPPED]
    fix: dict[str, tuple[str, int]] = {}
    for f in swapped:
        fix.update(f.fix)
    # a reading that follows nothing because its axis was not tilted and the other reading
    # follows it: the swap's other half (the profile moves one axis)
    explained = [f for f in bad if f.kind == NO_RESPONSE and f.reading in fix]
    if swapped:
        used = {o for o, _ in fix.values()}
        needing = [a for a in mapping if a not in fix and mapping[a][0] in used]
        freed = [mapping[a][0] for a in fix if a in mapping and mapping[a][0] not in used]
        if len(needing) == 1 and len(freed) == 1:  # the other output to the other axis
            fix[needing[0]] = (freed[0], mapping[needing[0]][1])
        new = {**mapping, **fix}
        outputs = [o for o, _ in new.values()]
        setting = _setting(fix, mapping)
        how = (f"{remount}, or set {setting} in {config}"
               if len(set(outputs)) == len(outputs) and setting else
               f"{remount} (its axes along the stand's: {', '.join(tilted)})")
        names = sorted({f.reading for f in swapped} | set(fix), key=_axis_order)
        what = f"{' and '.join(names)} swapped?" if len(names) > 1 else "axes swapped?"
        seen = ", ".join(f.text for f in sorted(swapped + explained,
                                                key=lambda f: _axis_order(f.reading)))
        messages.append(f"mounting check: {seen}: {what} {how}")
    for f in bad:
        if f in explained:
            continue
        if f.kind == REVERSED:
            messages.append(f"mounting check: {f.text}: mounted reversed? {remount}, or set "
                            f"{_setting(f.fix, mapping)} in {config}")
        elif f.kind == NO_RESPONSE:
            messages.append(f"mounting check: {f.text}: is the unit fixed to the stand, and is "
                            f"instrument.axes.{f.reading}.output the output that measures it? "
                            f"Check the mounting and {config}")
        elif f.kind == GAIN:
            messages.append(f"mounting check: {f.text}: mounted loose or tilted, or the wrong "
                            f"output? Check the mounting (run.mounting_check.gain_tolerance "
                            f"= {gain_tolerance:g})")
        elif f.kind == CROSS:
            messages.append(f"mounting check: {f.text}: mounted turned about the vertical? "
                            f"{remount} square to the stand's axes "
                            f"(run.mounting_check.cross_tolerance = {cross_tolerance:g})")
    return Verdict(not bad, findings, messages)


__all__ = [
    "CROSS",
    "GAIN",
    "NO_RESPONSE",
    "OK",
    "REVERSED",
    "SWAPPED",
    "Finding",
    "Response",
    "Verdict",
    "classify",
    "fit_response",
    "fit_sampled",
    "judge",
    "tilt_points",
]
