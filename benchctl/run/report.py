"""The verdict and the report: PASS when σ is within the limit on every axis under the run's
decision rule — and, for a sine_steps profile, the linearity of its steps' gains within
``run.linearity_spread_limit`` — FAIL otherwise; under the guarded rule a σ whose 95 % interval
straddles the limit is INCONCLUSIVE (exit 3). With measurements (``benchctl.results``) the
verdict is their decisive outcomes' (:func:`benchctl.results.measurements.overall`).

Written into the recording folder: ``report.json`` (machine-readable, the same object
``benchctl run --json`` prints), ``report.txt`` (for the operator) and one analysis plot per
axis (``analysis_<axis>.png``) when the analysis provides a plot. ``archive`` appends one line
per run to ``<output_dir>/index.jsonl``: the results archive of a bench.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchctl.analysis.budget import budget_lines
from benchctl.analysis.departures import departure_text, sigma_inconclusive
from benchctl.analysis.excitation import format_fidelity
from benchctl.errors import RecordingError
from benchctl.fileout import atomic_write_text
from benchctl.jsonout import dumps, plain
from benchctl.outcomes import ExitCode, Outcome
from benchctl.results.measurements import (
    RULE_TEXT,
    Measurement,
    combine,
    decide,
    overall,
)
from benchctl.text import terminal_lines

log = logging.getLogger(__name__)

REPORT_JSON = "report.json"
REPORT_TXT = "report.txt"
ARCHIVE_INDEX = "index.jsonl"


@dataclass
class AxisVerdict:
    """σ of one axis against the limit (degrees); with sine steps, also the linearity table
    (``steps``) and its verdict (``linearity``: spread, limit, verdict): the axis passes when
    both do."""

    axis: str
    sigma_deg: float
    sigma_ci95_deg: tuple[float, float]
    dof: float
    mean_error_deg: float
    rms_error_deg: float
    delay_s: float | None
    limit_deg: float
    analysis: dict[str, Any] = field(default_factory=dict, repr=False)
    steps: list[dict[str, Any]] | None = None
    linearity: dict[str, Any] | None = None
    excitation: dict[str, Any] | None = None  # measured excitation fidelity (informative)
    rule: str = "simple"  # the decision rule σ is judged by (simple | guarded)
    # why σ is not judged (the stand's motion departed from the profile for too much of the
    # window: benchctl.analysis.departures): σ is then INCONCLUSIVE under either rule
    sigma_inconclusive: str | None = None
    # σ's uncertainty budget (benchctl.analysis.budget, its JSON form): of the headline σ,
    # the one ``sigma`` and ``sigma_ci95`` are; None when the analysis gave none
    budget: dict[str, Any] | None = None

    @property
    def sigma_outcome(self) -> Outcome:
        """PASS, FAIL or INCONCLUSIVE (the guarded rule, or σ not to be judged)."""
        if self.sigma_inconclusive is not None:
            return Outcome.INCONCLUSIVE
        return decide(self.sigma_deg, None, self.limit_deg, self.sigma_ci95_deg, self.rule)

    @property
    def sigma_passed(self) -> bool:
        return self.sigma_outcome == Outcome.PASS

    @property
    def linearity_passed(self) -> bool:
        return self.linearity is None or self.linearity.get("verdict") == Outcome.PASS

    @property
    def outcome(self) -> Outcome:
        return combine([self.sigma_outcome,
                        Outcome.PASS if self.linearity_passed else Outcome.FAIL])

    @property
    def passed(self) -> bool:
        return self.outcome == Outcome.PASS

    def to_dict(self, full: bool = True) -> dict[str, Any]:
        d: dict[str, Any] = {
            "axis": self.axis,
            "verdict": self.outcome,
            "rule": self.rule,
            "sigma": self.sigma_deg,
            "sigma_ci95": list(self.sigma_ci95_deg),
            "limit": self.limit_deg,
            "dof": self.dof,
            "mean_error": self.mean_error_deg,
            "rms_error": self.rms_error_deg,
            "delay": self.delay_s,
            "sigma_verdict": self.sigma_outcome,
            "sigma_inconclusive": self.sigma_inconclusive,
            "budget": self.budget,
        }
        if self.linearity is not None:
            d["linearity"] = self.linearity
            d["steps"] = self.steps
        d["excitation"] = self.excitation
        if full:
            d["analysis"] = self.analysis
        return d


def axis_verdict(axis: str, result: Any, limit_deg: float, rule: str = "simple") -> AxisVerdict:
    """From an ``AnalysisResult`` (sigma, sigma_ci95, dof, mean_error, rms_error, delay),
    σ judged by ``rule`` (simple | guarded) — INCONCLUSIVE when the departures from the
    profile left too little to judge it on (``result.departures``)."""
    ci = tuple(float(v) for v in result.sigma_ci95)
    steps = getattr(result, "steps", None)
    table = None if steps is None else steps.to_dict()
    analysis = result.to_dict() if hasattr(result, "to_dict") else {}
    return AxisVerdict(
        axis=axis,
        sigma_deg=float(result.sigma),
        sigma_ci95_deg=(ci[0], ci[1]),
        dof=float(result.dof),
        mean_error_deg=float(result.mean_error),
        rms_error_deg=float(result.rms_error),
        delay_s=None if getattr(result, "delay", None) is None else float(result.delay),
        limit_deg=limit_deg,
        analysis=analysis,
        steps=None if table is None else table["steps"],
        linearity=None if table is None else table["linearity"],
        excitation=getattr(result, "excitation", None),
        rule=rule,
        sigma_inconclusive=sigma_inconclusive(getattr(result, "departures", None)),
        budget=analysis.get("budget"),
    )


@dataclass
class Report:
    axes: dict[str, AxisVerdict]
    recording: Path
    meta: dict[str, Any]  # serial, operator, station, profile, seed, start/end, mode …
    stats: dict[str, Any]
    window: tuple[float, float]
    # why the motion ended (benchctl.run.precision.ended_summary): reason, precision reached,
    # requested, motion_s, periods, period_s
    ended: dict[str, Any] | None = None
    decision_rule: str = "simple"  # simple | guarded (run.decision_rule, --decision-rule)
    # every result with its limits and outcome (benchctl.results.measurements); when given,
    # the verdict is their decisive outcomes'
    measurements: list[Measurement] = field(default_factory=list)
    deviations: list[str] = field(default_factory=list)  # e.g. the profile scaled to fit
    warnings: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> Outcome:
        """PASS, FAIL or INCONCLUSIVE (guarded rule)."""
        if self.measurements:
            v = overall(self.measurements)
            return Outcome.FAIL if v == Outcome.NOT_JUDGED else v  # nothing judged is no pass
        if not self.axes:
            return Outcome.FAIL
        return combine(v.outcome for v in self.axes.values())

    @property
    def exit_code(self) -> ExitCode:
        return self.verdict.exit_code

    def to_dict(self, full: bool = True) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "state": "done",
            "exit_code": self.exit_code,
            "decision_rule": {"name": self.decision_rule,
                              "text": RULE_TEXT.get(self.decision_rule, "")},
            "deviations": list(self.deviations),
            "warnings": list(self.warnings),
            "recording": str(self.recording),
            "axes": {a: v.to_dict(full) for a, v in self.axes.items()},
            "measurements": [m.to_dict() for m in self.measurements],
            "analysis_window": list(self.window),
            "ended": self.ended,
            **self.meta,
            "stats": self.stats,
        }


def _extra_lines(analysis: dict[str, Any]) -> list[str]:
    """An axis's cross-axis response and distortion test, when its analysis has them."""
    out = []
    c = analysis.get("cross_axis")
    if c:
        lo, hi = c["coefficient_ci95"]
        out.append(f"        cross-axis {c['output_axis']} per {c['input_axis']}: K = "
                   f"{c['coefficient']:+.5f}  95 % CI [{lo:+.5f}, {hi:+.5f}]")
    d = analysis.get("distortion")
    if d:
        def deg(v: float | None) -> str:
            return "—" if v is None else f"{v:.3g}°"

        out.append(f"        nonlinear distortion {'DETECTED' if d['detected'] else 'not detected'}"
                   f": odd {deg(d['odd_deg'])}, even {deg(d['even_deg'])} rms per line, noise "
                   f"{deg(d['noise_deg'])}")
    return out


def format_report(rep: Report) -> str:
    """The report as text (the terminal, report.txt): every line made safe
    (``benchctl.text.visible``)."""
    m = rep.meta
    lines = [
        f"{rep.verdict}   serial {m.get('serial', '?')}   operator {m.get('operator', '?')}   "
        f"station {m.get('station', '?')}",
        f"  decision rule: {RULE_TEXT.get(rep.decision_rule, rep.decision_rule)}",
        f"profile {m.get('profile_name', '?')} (seed {m.get('seed', '?')}), "
        f"{m.get('duration_s', float('nan')):.1f} s, mode {m.get('mode', '?')}",
    ]
    scale = m.get("scale")
    if scale is not None and scale != 1.0:
        lines.append(f"  profile scaled by {scale:g} to fit the stand limits")
    timing = m.get("timing") or {}
    if timing.get("offset_s"):
        lines.append(f"  bench timing offset {timing['offset_s'] * 1e3:+.4f} ms "
                     f"(± {(timing.get('uncertainty_s') or 0.0) * 1e3:.4f} ms, calibrated "
                     f"{timing.get('calibrated')}) subtracted from the instrument's instants")
    lines.extend(f"  DEVIATION: {d}" for d in rep.deviations)
    for v in rep.axes.values():
        lo, hi = v.sigma_ci95_deg
        lines.append(
            f"  {v.axis:<5} σ = {v.sigma_deg:.4f}°  95 % CI [{lo:.4f}, {hi:.4f}]°"
            f"  limit {v.limit_deg:g}°"
            f"  → {v.sigma_outcome}   (mean error {v.mean_error_deg:+.4f}°, "
            f"dof {v.dof:.0f})"
        )
        lines.extend(_departure_lines(v))
        lines.extend(budget_lines(v.budget))
        if v.steps is not None and v.linearity is not None:
            lines.extend(_steps_lines(v.steps, v.linearity))
        lines.extend(_extra_lines(v.analysis))
        if v.excitation is not None:
            lines.append(f"        {format_fidelity(v.excitation)}")
    st = rep.stats
    lat = st.get("cycle_lateness_s", {})
    rtt = st.get("stand_rtt_s", {})
    lines.append(
        f"  cycles {st.get('cycles', 0)}, missed {st.get('missed_cycles', 0)}; lateness p50 "
        f"{1e3 * lat.get('p50', math.nan):.2f} ms p99 {1e3 * lat.get('p99', math.nan):.2f} ms; "
        f"stand round trip p50 {1e3 * rtt.get('p50', math.nan):.2f} ms p99 "
        f"{1e3 * rtt.get('p99', math.nan):.2f} ms"
    )
    cmd = st.get("commanded", {})
    peaks = ", ".join(
        f"{a} {v:.2f}°/s {cmd.get('max_accel_deg_s2', {}).get(a, math.nan):.2f}°/s²"
        for a, v in cmd.get("max_rate_deg_s", {}).items()
    )
    lines.append(
        f"  rejoins {st.get('rejoins', 0)}, underruns {st.get('underruns', 0)}; "
        f"commanded peaks {peaks or 'none'}"
    )
    lines.append(
        f"  instrument samples {st.get('instrument_samples', 0)}, "
        f"lost {st.get('instrument_lost', 0)}, "
        f"bad frames {st.get('instrument_bad_frames', 0)}"
    )
    if rep.ended is not None:
        lines.append(_ended_line(rep.ended))
    judged = [x for x in rep.measurements
              if x.outcome != Outcome.NOT_JUDGED and x.rule != "check"]
    if judged:
        lines.append("  measurements judged:")
        lines.extend(f"    {_measurement_line(x)}" for x in judged)
    lines.extend(f"  warning: {w}" for w in rep.warnings)
    lines.append(f"  recording {rep.recording}")
    return terminal_lines(lines)  # a serial's or an operator's ESC or CR/LF shown, not sent


def _departure_lines(v: AxisVerdict) -> list[str]:
    dep = v.analysis.get("departures")
    out = [] if not isinstance(dep, dict) else [f"        {departure_text(dep)}"]
    if v.sigma_inconclusive is not None:
        out.append(f"        σ not judged (INCONCLUSIVE): {v.sigma_inconclusive}")
    return out


def _measurement_line(x: Measurement) -> str:
    """``sigma roll 0.2831 deg [0.2712, 0.2950] ≤ 0.4 → PASS (guarded)``."""
    def num(v: Any) -> str:
        return "—" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v)

    lim = ("" if x.low is None else f"≥ {num(x.low)} ") + (
        "" if x.high is None else f"≤ {num(x.high)}")
    ci = "" if x.ci95 is None else f" [{num(x.ci95[0])}, {num(x.ci95[1])}]"
    what = " ".join(p for p in (x.name, x.axis) if p)
    tag = "" if x.decisive else ", informative"
    return (f"{what}: {num(x.value)} {x.unit or ''}{ci}  {lim.strip()} → {x.outcome} "
            f"({x.rule}{tag})")


def _ended_line(e: dict[str, Any]) -> str:
    """Why the motion ended, the precision σ's interval reached and the one asked for."""
    def pct(v: Any) -> str:
        return "—" if v is None else f"±{100 * float(v):.2f} %"

    periods = e.get("periods")
    per = "" if periods is None else f", {periods} period(s) of {e.get('period_s', 0):.4g} s"
    motion = e.get("motion_s")
    mot = "" if motion is None else f"; motion {motion:.1f} s"
    req = e.get("requested")
    return (f"  ended: {e.get('reason', '?')}; precision {pct(e.get('precision'))} (95 %)"
            + ("" if req is None else f", requested {pct(req)}") + per + mot)


def _steps_lines(steps: list[dict[str, Any]], lin: dict[str, Any]) -> list[str]:
    """The sine steps' table (period × amplitude: gain and phase with 95 % intervals) and the
    linearity verdict, from the JSON form."""
    out = ["        period  ampl.   gain    95 % CI            phase     95 % CI"]
    for s in steps:
        g, gc, ph, pc = s.get("gain"), s.get("gain_ci95"), s.get("phase_deg"), s.get(
            "phase_ci95_deg")
        head = f"        {s['period_s']:4.3g} s  {s['amplitude_deg']:4.3g}°  "
        if g is None or gc is None or ph is None or pc is None:
            out.append(head + f"no estimate: {s.get('note') or '?'}")
            continue
        out.append(head + f"{g:.4f}  [{gc[0]:.4f}, {gc[1]:.4f}]  {ph:7.2f}°  "
                   f"[{pc[0]:.2f}, {pc[1]:.2f}]°")
    spread = lin.get("spread")
    out.append(
        "        linearity: spread (max − min gain) "
        + ("—" if spread is None else f"{spread:.4f}")
        + f"  limit {lin.get('limit'):g}  → {lin.get('verdict')}"
    )
    return out


def _plot(result: Any, dest: Path, meta: dict[str, Any] | None = None,
          limit_deg: float | None = None) -> bool:
    """Draw the analysis plot (error PSD, gain, phase, coherence) beside the report: serial
    and date in its title, the σ limit on its PSD panel."""
    m = meta or {}
    try:
        from benchctl.analysis.plot import plot_result  # matplotlib: only when a plot is drawn

        plot_result(result, dest, serial=None if m.get("serial") is None else str(m["serial"]),
                    date=str(m.get("start_utc") or "")[:10] or None, limit_deg=limit_deg)
    except Exception as e:  # a plot is a convenience; the verdict stands without it
        with contextlib.suppress(OSError):
            dest.unlink(missing_ok=True)  # no half-drawn file
        full = RecordingError.disk_full(e, dest)
        if full is not None:  # … but a full disk is the run's abort, as anywhere
            raise full from None
        log.warning("analysis plot %s not drawn: %s", dest, e)
        return False
    return True


def _write(path: Path, text: str) -> None:
    """``text`` as ``path``, atomically; a failure is a ``RecordingError`` naming the file."""
    try:
        atomic_write_text(path, text)
    except OSError as e:
        raise RecordingError.from_oserror(path, e) from None


def write_report(rep: Report, results: dict[str, Any] | None = None, *,
                 figures: bool = True) -> list[Path]:
    """report.json, report.txt (and, with ``figures``, plots) into the recording folder;
    returns the files. A file that cannot be written (a full disk) raises ``RecordingError``
    naming it, and leaves no half-written file behind; a plot that cannot be drawn for
    another reason is a warning."""
    folder = rep.recording
    out = [folder / REPORT_JSON, folder / REPORT_TXT]
    _write(out[0], dumps(rep.to_dict(), indent=2) + "\n")
    _write(out[1], format_report(rep) + "\n")
    plotted = (results or {}) if figures else {}
    for axis, res in plotted.items():
        dest = folder / f"analysis_{axis}.png"
        v = rep.axes.get(axis)
        if _plot(res, dest, rep.meta, None if v is None else v.limit_deg):
            out.append(dest)
    return out


def archive(output_dir: Path, rep: Report) -> Path:
    """Append the run's summary to the bench's results archive ``index.jsonl``."""
    index = output_dir / ARCHIVE_INDEX
    line = dumps(
        {
            **{
                k: rep.meta.get(k)
                for k in ("serial", "operator", "station", "profile_name", "seed", "start_utc")
            },
            "verdict": rep.verdict,
            "sigma": {a: v.sigma_deg for a, v in rep.axes.items()},
            "limit": {a: v.limit_deg for a, v in rep.axes.items()},
            "recording": str(rep.recording),
        }
    )
    append_line(index, line)
    return index


def append_line(path: Path, line: str) -> None:
    """Append ``line`` and a newline to ``path`` in one write; when it cannot be written
    whole (a full disk) the file is cut back to where it was (no torn line) and
    ``RecordingError`` names it."""
    data = (line + "\n").encode("utf-8")
    try:
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    except OSError as e:
        raise RecordingError.from_oserror(path, e) from None
    try:
        size = os.fstat(fd).st_size
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
        except OSError as e:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)
            raise RecordingError.from_oserror(path, e) from None
    finally:
        os.close(fd)


def archive_abort(output_dir: Path, meta: dict[str, Any], recording: Path, reason: str) -> Path:
    """An aborted run is archived too, with its reason."""
    index = output_dir / ARCHIVE_INDEX
    line = dumps(
        {
            **{
                k: meta.get(k)
                for k in ("serial", "operator", "station", "profile_name", "seed", "start_utc")
            },
            "verdict": Outcome.ABORTED,
            "reason": reason,
            "recording": str(recording),
        }
    )
    append_line(index, line)
    return index


def json_default(o: Any) -> Any:
    """Kept for callers of the old ``default=`` fallback of ``json``: the strict encoder's
    conversion (:func:`benchctl.jsonout.plain`). New code calls ``benchctl.jsonout.dumps``."""
    return plain(o)
