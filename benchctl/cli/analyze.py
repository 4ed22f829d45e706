"""``benchctl analyze``: σ, its interval, the error PSD and H(f) from a recording or CSV files."""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.errors import DataError
from benchctl.outcomes import ExitCode

if TYPE_CHECKING:
    from benchctl.analysis import AnalysisResult


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "analyze",
        help="dynamic error σ, its 95 %% interval, error PSD and H(f) of a recording or CSV",
        description=(
            "Analyse a benchctl recording folder, a CSV with columns time,reference,device, "
            "or two CSVs (--reference, --device) each with time and one angle column."
        ),
    )
    p.add_argument("source", nargs="?", help="recording folder or CSV file (time,reference,device)")
    p.add_argument("--reference", metavar="CSV", help="reference (stand) CSV: time + angle")
    p.add_argument("--device", metavar="CSV", help="instrument CSV: time + angle")
    p.add_argument("--axis", choices=("roll", "pitch", "all"), default="all",
                   help="axis of a recording (default all: one result per recorded axis)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--plot", metavar="FILE.png", help="draw error PSD, gain, phase, coherence")
    p.add_argument("--max-lag", type=float, metavar="SECONDS",
                   help="maximum correlation lag (default: a recording's run.analysis, else "
                   "a tenth of the record)")
    p.add_argument("--band", type=float, nargs=2, metavar=("LO", "HI"),
                   help="band (Hz) for the band-limited σ and the frequency-response grid "
                   "(default: a recording's run.analysis, else none)")
    p.add_argument("--compensate-delay", metavar="SECONDS|auto", default=None,
                   help="remove an acquisition delay (s, device lagging) or 'auto' (default: a "
                   "recording's run.analysis, else none)")
    p.add_argument("--time-col", default="time", help="time column name (default time)")
    p.add_argument("--reference-col", help="reference angle column (default reference, or "
                   "the only angle column of --reference)")
    p.add_argument("--device-col", help="device angle column (default device, or the only "
                   "angle column of --device)")
    p.add_argument("--units", choices=("deg", "rad"), default="deg", help="angle units of CSVs")
    p.add_argument("--timebase", choices=("auto", "given", "fitted"), default="auto",
                   help="device instants: chosen from the data (default: fitted when the "
                   "stamps jitter about a uniform clock, else as given), as given, or fitted "
                   "to a uniform clock (jittery receipt times)")
    p.add_argument("--reference-timebase", choices=("auto", "given", "fitted"), default="auto",
                   help="reference instants: chosen from the data (default), as given, or "
                   "fitted to a uniform clock (a reference sampled on its own clock whose "
                   "stamps jitter)")
    p.add_argument("--recording-timebase", default="best",
                   choices=("best", "device", "adapter", "fitted", "receipt"),
                   help="a recording's instrument instants: the best time base it has "
                   "(default), or the instrument's own clock, the CAN adapter's timestamps, "
                   "a clock fitted to the receipts, or the receipt stamps as they are")
    p.add_argument("--period", type=float, metavar="SECONDS",
                   help="the motion's repetition period: the record holds whole periods of it "
                   "(line-wise estimate; default: a recording's profile, else detected when "
                   "the record holds two or more periods)")
    p.add_argument("--lines", choices=("auto", "off"), default="auto",
                   help="line-wise estimate: auto (default) or off")
    p.set_defaults(handler=run)


def _delay_option(text: str) -> str | float:
    from benchctl.options import MAX_DELAY_S

    if text in ("none", "auto"):
        return text
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and abs(value) <= MAX_DELAY_S):
        raise DataError(
            f"--compensate-delay {text!r}: expected seconds or 'auto' (or 'none'), "
            f"-{MAX_DELAY_S:g} ≤ seconds ≤ {MAX_DELAY_S:g}"
        )
    return value


def recorded_analysis(rec: Any) -> Any:
    """The analysis options of the bench config a recording keeps (``run.analysis`` in
    meta.json; ``benchctl.config.AnalysisConfig``): what ``analyze`` takes for an option not
    given on its command line, so that it reads a recording as the run's own verdict did. A
    recording whose kept options are not valid ones: ``DataError`` naming the file and field."""
    from pydantic import ValidationError

    from benchctl.config.run import AnalysisConfig

    cfg = rec.meta.get("config")
    run = cfg.get("run") if isinstance(cfg, dict) else None
    doc = run.get("analysis") if isinstance(run, dict) else None
    try:
        return AnalysisConfig.model_validate(doc if isinstance(doc, dict) else {})
    except ValidationError as e:
        err = e.errors()[0]
        where = ".".join(str(x) for x in err["loc"])
        raise DataError(
            f"{rec.path / 'meta.json'}: config.run.analysis.{where} = {err.get('input')!r}: "
            f"{err['msg']}; expected the options of a bench config's run.analysis"
        ) from None


def _check_options(args: argparse.Namespace) -> None:
    """The numeric options' ranges (docs/reference/analyze.md, the option table), before any
    file is read."""
    from benchctl.options import MAX_BAND_HZ, MAX_LAG_S, MAX_RUN_DURATION_S, check_option

    check_option("--max-lag", args.max_lag, 0, MAX_LAG_S, lo_open=True, unit="s",
                 what="a positive number of seconds")
    check_option("--period", args.period, 0, MAX_RUN_DURATION_S, lo_open=True, unit="s",
                 what="a positive number of seconds")
    if args.band is not None:
        lo, hi = args.band
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo < hi <= MAX_BAND_HZ):
            raise DataError(f"--band {lo!r} {hi!r}: expected 0 ≤ lo < hi ≤ {MAX_BAND_HZ:g} Hz")


def _named(label: str, fn: Callable[..., AnalysisResult], *a: Any, **kw: Any) -> AnalysisResult:
    """``fn(*a, **kw)``; a ``DataError`` (the analysis names streams, not files) gets the
    source's name in front."""
    try:
        return fn(*a, **kw)
    except DataError as e:
        raise DataError(f"{label}: {e}") from None


def _is_recording(path: str) -> bool:
    # imported only for a folder: the recording package (its writer and the devices' sample
    # types) costs a CSV's analysis about 20 ms
    from benchctl.recording import is_recording

    return is_recording(path)


#: glibc's malloc: arrays up to this size from the heap (mallopt M_MMAP_THRESHOLD, bytes) …
HEAP_ARRAYS = 32 << 20
#: … and this much freed memory kept at its top for the next ones (M_TRIM_THRESHOLD, bytes)
HEAP_KEEP = 256 << 20


def _reuse_freed_memory() -> None:
    """Let the analysis reuse the memory of the arrays it frees (glibc only; elsewhere
    nothing). By default glibc maps an array of a few MB on its own and unmaps it when freed,
    or hands freed heap memory back to the system: the next array of a record's length then
    faults its pages in anew (the 15-min 1 kHz record: 58 000 page faults, the baseline's
    loadtxt + welch 28 000). Kept, the same pages serve array after array: 43 000."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):  # no C library by that name, or no mallopt
        return
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    m_trim_threshold, m_mmap_threshold = -1, -3  # <malloc.h>
    mallopt(m_mmap_threshold, HEAP_ARRAYS)
    mallopt(m_trim_threshold, HEAP_KEEP)


def run(args: argparse.Namespace) -> int:
    from benchctl.analysis import analyze
    from benchctl.analysis.inputs import load_csv_pair, load_single_csv

    _check_options(args)
    _reuse_freed_memory()
    opts: dict[str, Any] = {
        "max_lag_s": args.max_lag,
        "band_hz": tuple(args.band) if args.band else None,
        "compensate_delay": _delay_option(args.compensate_delay or "none"),
        "timebase": args.timebase,
        "reference_timebase": args.reference_timebase,
        "period_s": args.period,
        "lines": args.lines,
    }
    pair = args.reference is not None or args.device is not None
    if pair and (args.reference is None or args.device is None or args.source is not None):
        raise DataError("give --reference and --device together, and no other source")
    if not pair and args.source is None:
        raise DataError("nothing to analyse: give a recording folder, a CSV, or "
                        "--reference and --device")
    results: dict[str, AnalysisResult] = {}
    single_axis = True
    status: dict[str, Any] | None = None  # a recording's state, and a note when unfinished
    if pair:
        s = load_csv_pair(args.reference, args.device, time_col=args.time_col,
                          reference_col=args.reference_col, device_col=args.device_col,
                          units=args.units)
        results[""] = _named(s.source, analyze, s.t_ref, s.x_ref, s.t_dev, s.y_dev,
                             source=s.source, **opts)
    elif Path(args.source).is_dir() and _is_recording(args.source):
        # imported here: a CSV needs none of it (the profile and config schemas cost `analyze`
        # of a CSV about a third of its wall time)
        from benchctl.evaluate import EvaluationOptions, EvaluationRequest, evaluate
        from benchctl.recording import load_recording

        rec = load_recording(args.source)
        rec.require_intact()  # an altered recording: exit 2 naming the file, never a σ
        status = recording_status(rec)
        single_axis = args.axis != "all"
        stated = recorded_analysis(rec)  # the options the run's own verdict used
        given = {"max_lag_s": args.max_lag is not None, "band_hz": args.band is not None,
                 "compensate_delay": args.compensate_delay is not None}
        ev = evaluate(rec, EvaluationRequest(
            axes=None if args.axis == "all" else [args.axis],
            options=EvaluationOptions(
                **{k: (v if given.get(k, True) else getattr(stated, k))
                   for k, v in opts.items() if k != "lines"},
                lines=None if args.lines == "auto" else args.lines,
                recording_timebase=args.recording_timebase),
            label_errors=True, source=str(args.source)))
        results.update(ev.results)
    else:
        src = Path(args.source)
        if src.is_dir():
            raise DataError(f"{src}: a folder but not a benchctl recording (no meta.json)")
        if not src.exists():  # a device or a FIFO: the CSV reader says what it is
            raise DataError(f"{src}: no such file or recording folder")
        s = load_single_csv(src, time_col=args.time_col,
                            reference_col=args.reference_col or "reference",
                            device_col=args.device_col or "device", units=args.units)
        results[""] = _named(s.source, analyze, s.t_ref, s.x_ref, s.t_dev, s.y_dev,
                             source=s.source, **opts)
    if args.plot:
        from benchctl.analysis.plot import plot_result

        dest = Path(args.plot)
        for ax, r in results.items():
            out = dest if len(results) == 1 else dest.with_name(f"{dest.stem}_{ax}{dest.suffix}")
            plot_result(r, out)
    if args.json:
        if single_axis:
            doc = next(iter(results.values())).to_dict()
        else:
            doc = {"axes": {ax: r.to_dict() for ax, r in results.items()}}
        if status is not None:
            doc["recording"] = status
        sys.stdout.write(json.dumps(doc, allow_nan=False) + "\n")  # dumps: the C encoder
    else:
        if status is not None and status["note"]:
            from benchctl.text import visible  # the recording's reason: shown, not sent

            print(f"benchctl analyze: NOTE: {visible(status['note'])}")
        for r in results.values():
            print(summary(r))
    return ExitCode.OK


def recording_status(rec: Any) -> dict[str, Any]:
    """A recording's state (done, aborted, incomplete), the reason it ended and, unless it is
    a finished run's, a note that says so: an aborted run's or a killed one's (no end.json)
    record is analysed as it is, which is not the run's verdict."""
    state = rec.state
    reason = str((rec.end or {}).get("reason") or "")
    note = ""
    if state == "aborted":
        note = (f"the run was ABORTED ({reason or 'no reason recorded'}): this analysis covers "
                "what was recorded and is not a verdict")
    elif state == "incomplete":
        note = ("the recording is INCOMPLETE (no end.json: the run was killed or is still "
                "running): this analysis covers what was recorded and is not a verdict")
    elif state != "done":
        note = f"the recording ended in state {state!r}: this analysis is not a verdict"
    integrity = rec.integrity
    if integrity.status != "verified" and state != "incomplete":
        note = (note + "; " if note else "") + f"integrity {integrity.text()}"
    return {"state": state, "reason": reason or None, "note": note or None,
            "integrity": integrity.to_dict(),
            # the bench's calibrated offset its instrument instants were moved by (s; 0: none)
            "timing_offset_s": rec.timing_offset_s}


def _fmt(v: float | None, spec: str) -> str:
    return "—" if v is None else format(v, spec)


def _periods_table(r: AnalysisResult) -> list[str]:
    src = "lines" if r.frf_source == "lines" else "H1"
    out = [f"  period   gain    95 % CI          phase     95 % CI            γ²      ({src})"]
    for p in r.periods:
        if not p["excited"]:
            out.append(f"  {p['period_s']:4.0f} s  not excited (no line near it): no gain, "
                       "no phase")
            continue
        g, gc, ph, pc = p["gain"], p["gain_ci95"], p["phase_deg"], p["phase_ci95_deg"]
        how = "  (interpolated)" if p.get("source") == "interpolated" else ""
        out.append(
            f"  {p['period_s']:4.0f} s  {g:.4f}  {gc[0]:.4f} … {gc[1]:.4f}  {ph:7.2f}°  "
            f"{pc[0]:7.2f} … {pc[1]:7.2f}°  {_fmt(p['coherence'], '.4f')}{how}"
        )
    return out


def _lines_block(r: AnalysisResult) -> list[str]:
    la = r.lines
    if la is None:
        return []
    src = {"profile": "the profile", "period": "--period", "detected": "detected"}.get(
        la.lines.source, la.lines.source)
    lo, hi = la.sigma_ci95
    return [
        f"  line-wise ({src}): T_p = {la.lines.period_s:.6g} s, {la.n_periods} period(s), "
        f"{len(la.freq)} lines, noise at the lines from "
        + ("the local polynomial fit" if la.noise_lpm.all() else
           "unexcited bins" if not la.noise_lpm.any() else
           "unexcited bins and the local polynomial fit"),
        f"    σ = {la.sigma:.5g}°   95 % CI {lo:.5g} … {hi:.5g}°   (mean removal "
        f"{la.mean_removal:.3g} deg² added back)",
        f"    linear {la.linear:.5g} deg² (95 % CI {la.linear_ci95[0]:.5g} … "
        f"{la.linear_ci95[1]:.5g}), incoherent {la.incoherent:.5g} deg² "
        f"({la.incoherent_ci95[0]:.5g} … {la.incoherent_ci95[1]:.5g})",
        *_gain_range(la),
    ]


def _gain_range(la: Any) -> list[str]:
    """The gain and phase ranges over the reliable lines (SNR ≥ the floor); the weak lines'
    count and band said, never their noise-made gains."""
    import numpy as np

    ok = la.reliable if la.reliable.size == len(la.freq) else np.ones(len(la.freq), dtype=bool)
    weak = int((~ok).sum())
    note = (f" ({weak} line{'s' if weak > 1 else ''} over {float(la.freq[~ok].min()):.4g} … "
            f"{float(la.freq[~ok].max()):.4g} Hz below SNR {la.snr_floor:g}: not measured "
            "reliably, not shown)" if weak else "")
    if not ok.any():
        return [f"    no line measured reliably{note}"]
    return [f"    gain {float(la.gain[ok].min()):.4f} … {float(la.gain[ok].max()):.4f}, phase "
            f"{float(la.phase_deg[ok].min()):.3f} … {float(la.phase_deg[ok].max()):.3f}° over "
            f"{float(la.freq[ok].min()):.4g} … {float(la.freq[ok].max()):.4g} Hz{note}"]


def _distortion_block(r: AnalysisResult) -> list[str]:
    d = None if r.lines is None else r.lines.distortion
    if d is None:
        return []
    out = [f"  nonlinear distortion (odd multisine, {d.n_periods} periods; error at the "
           f"unexcited lines vs the noise between harmonics): "
           + ("DETECTED" if d.detected else "not detected") + f" (α = {d.alpha:g})"]
    for name, g in (("odd", d.odd), ("even", d.even)):
        lv = g.level
        if lv.harmonics.size == 0 or lv.level_deg is None or lv.noise_deg is None:
            out.append(f"    {name:4s}: no unexcited line")
            continue
        ratio = 10 * math.log10(lv.ratio) if 0 < lv.ratio < math.inf else math.inf
        out.append(
            f"    {name:4s}: {lv.level_deg:.3g}° rms per line vs noise {lv.noise_deg:.3g}° "
            f"({ratio:+.1f} dB, threshold {10 * math.log10(g.threshold):+.1f} dB, "
            f"p = {g.p_value:.2g}, {lv.harmonics.size} lines)"
            + ("  → detected" if g.detected else "")
        )
    return out


def _cross_axis_block(r: AnalysisResult) -> list[str]:
    c = r.cross_axis
    if not c:
        return []
    lo, hi = c["coefficient_ci95"]
    return [f"  cross-axis: {c['output_axis']} output per {c['input_axis']} angle "
            f"K = {c['coefficient']:+.5f}  95 % CI {lo:+.5f} … {hi:+.5f}  (quadrature "
            f"{c['quadrature']:+.5f}; {c['n_lines']} lines of {c['input_axis']})"]


def _departures_block(r: AnalysisResult) -> list[str]:
    """Where the stand's motion was not the profile's, and what was left out for it."""
    from benchctl.analysis.departures import departure_text, sigma_inconclusive

    dep = r.departures
    if not dep:
        return []
    out = [f"  {departure_text(dep)}"]
    why = sigma_inconclusive(dep)
    if why is not None:
        out.append(f"  σ NOT TO BE JUDGED: {why}")
    return out


def _timing_block(tm: dict[str, Any]) -> list[str]:
    """The time bases (how "auto" chose them), the clock skew, timing in σ's interval."""
    if "device_timebase" not in tm:
        return []
    choice = tm.get("timebase_choice") or {}

    def why(entry: str) -> str:
        c = choice.get(entry) or {}
        if c.get("asked") != "auto" or c.get("stamp_share") is None:
            return ""
        return (f", auto: {100 * c['stamp_share']:.0f} ± {100 * c['stamp_share_se']:.0f} % of "
                "the stamps' scatter is their own error")

    out = [
        f"  timing: device {tm['device_timebase']} (±{1e3 * tm['device_time_residual_s']:.2g}"
        f" ms{why('device')}), reference {tm['reference_timebase']} "
        f"(±{1e3 * tm['reference_time_residual_s']:.2g} ms{why('reference')}): "
        f"σ_ẋ²·jitter² = {100 * tm['timing_share']:.2g} % of σ²"
    ]
    if tm.get("skew_ppm") is not None:
        lo, hi = tm["skew_ci95_ppm"]
        out.append(
            f"  clock skew: {tm['skew_ppm']:+.4g} ppm (95 % {lo:+.4g} … {hi:+.4g}), "
            + (f"{1e3 * tm['skew_drift_s']:+.4g} ms over the record, corrected"
               if tm.get("skew_corrected") else "not corrected (not significant)"))
    if tm.get("timing_in_interval"):
        slo, shi = tm["sigma_ci95_statistical"]
        out.append(
            f"  σ's interval includes timing (statistical alone {slo:.5g} … {shi:.5g}°; offset "
            f"between the streams ±{1e3 * tm['timing_offset_u_s']:.2g} ms)")
    return out


def summary(r: AnalysisResult) -> str:
    """A readable summary of one result."""
    g = r.gaps
    lines = [
        f"benchctl analyze: {r.source}" + (f"  [{r.axis}]" if r.axis else ""),
        f"  {r.n_samples} samples over {r.duration:.6g} s at {r.sample_rate:.6g} Hz; "
        f"max lag {r.max_lag:.6g} s ({r.max_lag_samples} samples), "
        f"resolution {r.resolution_hz:.3g} Hz",
        f"  gaps: device {g['device']['count']} ({g['device']['missing_samples']} missing, "
        f"longest {g['device']['longest_s']:.3g} s), reference {g['reference']['count']}, "
        f"excluded samples {g['excluded_samples']}",
        *_departures_block(r),
        f"  σ (dynamic error, about the mean) = {r.sigma:.5g}°   "
        f"95 % CI {r.sigma_ci95[0]:.5g} … {r.sigma_ci95[1]:.5g}°   (ν = {r.dof:.4g}, "
        + ("line-wise)" if r.lines is not None else "lag window)"),
        f"  mean error (static) = {r.mean_error:.5g}°   rms error = {r.rms_error:.5g}°",
        f"  delay = {r.delay * 1e3:.4g} ms"
        + (f", compensated {r.delay_compensated * 1e3:.4g} ms" if r.delay_compensated
           else " (not compensated)"),
        f"  variance {r.variance:.5g} deg²: linear {r.linear:.5g} + incoherent "
        f"{r.incoherent:.5g} deg²"
        + (" (line-wise, mean removal included)" if r.lines is not None else " (lag window)"),
    ]
    lines.extend(_lines_block(r))
    lines.extend(_distortion_block(r))
    lines.extend(_cross_axis_block(r))
    if r.band:
        b = r.band
        ci = b.get("sigma_ci95")
        lines.append(f"  band {b['lo']:g} … {b['hi']:g} Hz: σ = {b['sigma']:.5g}°"
                     + (f"   95 % CI {ci[0]:.5g} … {ci[1]:.5g}° (from the lines' DFT bins)"
                        if ci else "   (the smoothed PSD's area: no interval without lines)"))
    if r.periods:
        lines.extend(_periods_table(r))
    if r.excitation is not None:
        from benchctl.analysis.excitation import format_fidelity

        lines.append(f"  {format_fidelity(r.excitation)}")
    if r.steps is not None:
        from benchctl.analysis.steps import format_steps

        lines.extend(format_steps(r.steps))
    c = r.cross_checks
    welch = ("skipped" if c["welch_area"] is None else
             f"{c['welch_area']:.5g} deg² (tolerance ±{c['welch_tolerance']:.2g}): "
             + ("agrees" if c["welch_agrees"] else "DISAGREES"))
    lines.append(f"  checks: Parseval rel. diff {c['parseval_rel_diff']:.1e}; Welch area {welch}")
    lines.extend(_timing_block(r.timing))
    if r.budget is not None:
        from benchctl.analysis.budget import budget_lines

        lines.extend(budget_lines(r.budget.to_dict(), "  "))
    lines.extend(f"  warning: {w}" for w in r.warnings)
    return "\n".join(lines)
