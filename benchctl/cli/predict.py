"""``benchctl predict``: σ expected under another profile from a recording's measured H(f) and
incoherent error (``benchctl.analysis.predict``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.errors import ConfigError, DataError
from benchctl.outcomes import ExitCode

if TYPE_CHECKING:
    from benchctl.analysis import AnalysisResult
    from benchctl.analysis.predict import Prediction
    from benchctl.harmonics import HarmonicTable


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "predict",
        help="σ expected under another profile (sea state, ship) from a recording's H(f) and noise",
        description=(
            "Predict the dynamic error σ under another profile's motion from the frequency "
            "response and the incoherent error measured line-wise in a recording: "
            "σ² = Σ |H(f_j) − 1|²·A_j²/2 + noise, over the profile's lines where H was measured."
        ),
    )
    p.add_argument("source", metavar="RECORDING", help="a benchctl recording folder")
    p.add_argument("--profile", required=True, metavar="PROFILE.yaml",
                   help="the other profile: its lines are the motion to predict for")
    p.add_argument("--axis", choices=("roll", "pitch", "all"), default="all",
                   help="axis (default all: every axis of the recording the profile moves)")
    p.add_argument("--duration", type=float, metavar="SEC",
                   help="the profile's duration override (its lines follow, as for a run)")
    p.add_argument("--recording-timebase", default="best",
                   choices=("best", "device", "adapter", "fitted", "receipt"),
                   help="the recording's instrument instants (as for benchctl analyze)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(handler=run)


def _tables(profile_path: str, duration: float | None) -> tuple[Any, dict[str, HarmonicTable]]:
    from benchctl.profiles import load_profile, synthesize

    profile = load_profile(profile_path)
    motion = synthesize(profile, duration_s=duration)
    tables = motion.tables
    if not tables:
        raise ConfigError(
            f"{profile_path}: kind {profile.kind} has no single table of lines (a grid of sine "
            "steps); a prediction needs the motion as lines: give a spectral, harmonics or "
            "sine profile"
        )
    return profile, tables


def _measure(rec: Any, source: str, axis: str, timebase: str) -> AnalysisResult:
    """The recording's line-wise estimate of ``axis`` on the one evaluation path
    (``benchctl.evaluate``): the profile's lines, the intervals where the stand's motion was not
    the profile's (underruns, rejoins) left out as every other path leaves them out, no sine
    steps, excitation or cross-axis response (a prediction uses none of them)."""
    from benchctl.evaluate import EvaluationOptions, EvaluationRequest, evaluate

    ev = evaluate(rec, EvaluationRequest(
        axes=[axis], options=EvaluationOptions(recording_timebase=timebase),
        steps=False, excitation=False, cross_axis=False, label_errors=True, source=source))
    res = ev.results[axis]
    if res.lines is None:
        head = "no line-wise estimate: "
        reasons = [w[len(head):] for w in res.warnings if w.startswith(head)]
        if axis in ev.line_notes:
            reasons.insert(0, ev.line_notes[axis])
        raise DataError(
            f"{source} [{axis}]: no line-wise estimate of H "
            f"({'; '.join(reasons) or 'no whole periods of known lines detected'}); a "
            "prediction needs a record of whole periods of the motion's lines"
        )
    return res


def run(args: argparse.Namespace) -> int:
    from benchctl.analysis.predict import noise_from_lines, predict, response_from_lines
    from benchctl.options import MAX_RUN_DURATION_S, check_option
    from benchctl.recording import is_recording, load_recording

    check_option("--duration", args.duration, 0, MAX_RUN_DURATION_S, lo_open=True, unit="s",
                 what="a positive number of seconds")
    src = Path(args.source)
    if not is_recording(src):
        what = "a folder but not a benchctl recording (no meta.json)" if src.is_dir() else (
            "not a recording folder (predict reads recordings)" if src.exists() else
            "no such recording folder")
        raise DataError(f"{src}: {what}")
    profile, tables = _tables(args.profile, args.duration)
    rec = load_recording(src)
    rec.require_intact()  # an altered recording: exit 2 naming the file
    wanted = list(rec.axes) if args.axis == "all" else [args.axis]
    if args.axis != "all" and args.axis not in rec.axes:
        raise DataError(f"{src}: --axis {args.axis}: the recording holds {', '.join(rec.axes)}")
    axes = [a for a in wanted if a in tables]
    if not axes:
        raise ConfigError(
            f"{args.profile}: axes: moves {', '.join(tables)}, none of the recording's "
            f"{', '.join(wanted)}; expected a profile for the axis measured"
        )
    # a recording's axis the profile does not move: said, never dropped in silence
    skipped = {a: _not_moved(a, profile.name, tables) for a in wanted if a not in tables}
    docs: dict[str, dict[str, Any]] = {}
    texts: list[str] = []
    if args.axis == "all" and len(rec.axes) > 1:
        texts.append(f"benchctl predict: {src}: axes {', '.join(rec.axes)}; predicted "
                     f"{', '.join(axes)}"
                     + (f"; not predicted {', '.join(skipped)}" if skipped else ""))
    for ax in axes:
        res = _measure(rec, str(src), ax, args.recording_timebase)
        la = res.lines
        assert la is not None
        tab = tables[ax]
        pred = predict(response_from_lines(la), noise_from_lines(la), tab.freq_hz, tab.amp_deg)
        doc = _doc(args, profile, tab, res, pred, ax)
        docs[ax] = doc
        texts.append(_summary(doc, pred))
    texts += [f"benchctl predict: {src}  [{a}]  not predicted: {why}"
              for a, why in skipped.items()]
    if args.json:
        out = docs[axes[0]] if args.axis != "all" else {"axes": docs, "not_predicted": skipped}
        sys.stdout.write(json.dumps(out, allow_nan=False) + "\n")
    else:
        print("\n".join(texts))
    return ExitCode.OK


def _not_moved(axis: str, profile_name: str, tables: dict[str, HarmonicTable]) -> str:
    """Why a recording's ``axis`` has no prediction: the other profile does not move it."""
    return (f"the profile {profile_name} moves {', '.join(tables)} only; with {axis} held at "
            f"zero its error is the instrument's noise and its response to the "
            f"{', '.join(tables)} motion, which a prediction from {axis}'s own lines does not "
            "give")


def _doc(args: argparse.Namespace, profile: Any, tab: HarmonicTable, res: AnalysisResult,
         pred: Prediction, axis: str) -> dict[str, Any]:
    from benchctl.analysis.result import _clean

    la = res.lines
    assert la is not None
    timing = float(res.timing.get("timing_variance", 0.0) or 0.0)
    return _clean({
        "recording": str(args.source),
        "profile": str(args.profile),
        "profile_name": profile.name,
        "axis": axis,
        "duration_s": tab.duration_s,
        "period_s": tab.period_s,
        **pred.to_dict(),
        "measured": {
            "sigma": res.sigma,
            "sigma_ci95": list(res.sigma_ci95),
            "linear": la.linear,
            "incoherent": la.incoherent,
            "n_lines": len(la.freq),
            "n_reliable": int(la.reliable.sum()),
            "snr_floor": la.snr_floor,
            "period_s": la.lines.period_s,
            "lines_source": la.lines.source,
            "timing_variance": timing,
            "warnings": list(res.warnings),
        },
        "assumptions": {
            "noise": "independent of the motion (carried over whole)",
            "outside_band": "excluded from sigma; sigma_outside_bound takes |1 - H| <= 1 there",
            "weak_lines": "lines measured with SNR below snr_floor are not used (outside)",
            "bounded": "when what was not measured could add more than 5 % to sigma, sigma "
                       "is null and sigma_bound the 95 % upper bound",
            "interval": "linear part: delta method over the line estimates; noise: scaled "
                        "chi-square; combined by the modified large-sample method",
        },
    })


def _summary(doc: dict[str, Any], pred: Prediction) -> str:
    m = doc["measured"]
    lo_b, hi_b = pred.tested_band_hz
    s_lo, s_hi = pred.sigma_ci95
    lines = [
        f"benchctl predict: {doc['recording']}  [{doc['axis']}]  →  {doc['profile']} "
        f"({doc['profile_name']}, {doc['duration_s']:g} s)",
        f"  measured: σ = {m['sigma']:.5g}° (linear {m['linear']:.4g} + incoherent "
        f"{m['incoherent']:.4g} deg²), H at {m['n_lines'] - len(pred.weak_lines_hz)} lines "
        f"over {lo_b:.4g} … {hi_b:.4g} Hz"
        + (f" ({len(pred.weak_lines_hz)} more below SNR {m['snr_floor']:g}, not used)"
           if pred.weak_lines_hz else ""),
        (f"  predicted σ ≤ {pred.sigma_bound:.5g}° (95 %): a bound, not an estimate — "
         f"{100 * pred.outside_share:.3g} % of the motion lies where the recording did not "
         f"measure H (see the warning); from the lines measured σ = {pred.sigma:.5g}° "
         f"(95 % CI {s_lo:.5g} … {s_hi:.5g}°)"
         if pred.bounded else
         f"  predicted σ = {pred.sigma:.5g}°   95 % CI {s_lo:.5g} … {s_hi:.5g}°"),
        f"    linear Σ|H−1|²A²/2 = {pred.linear:.5g} deg² (95 % CI {pred.linear_ci95[0]:.4g} … "
        f"{pred.linear_ci95[1]:.4g}), noise {pred.noise:.5g} deg² (95 % CI "
        f"{pred.noise_ci95[0]:.4g} … {pred.noise_ci95[1]:.4g}, ν = {pred.noise_dof:.4g}), "
        f"interpolation bound {pred.interpolation_bound:.2g} deg²",
        f"  the profile's motion: {len(pred.freq)} lines over {pred.freq.min():.4g} … "
        f"{pred.freq.max():.4g} Hz, {pred.target_variance:.5g} deg²; "
        + (f"outside the tested band {100 * pred.outside_share:.3g} % "
           f"({pred.outside_variance:.4g} deg², {len(pred.freq) - pred.n_inside} lines): not in "
           f"σ" + ("" if pred.bounded else ", what it could add held in σ's interval")
           + f"; with no more than |1 − H| ≤ 1 there σ ≤ {pred.sigma_outside_bound:.5g}°"
           if pred.n_inside < len(pred.freq) else "all inside the tested band"),
        "  assumes: the noise independent of the motion (carried over whole); H between "
        "measured lines interpolated, never outside them",
    ]
    if pred.untested_gaps_hz:
        gaps = ", ".join(f"{a:.4g} … {b:.4g}" for a, b in pred.untested_gaps_hz)
        lines.append(f"  holes between measured lines not interpolated: {gaps} Hz")
    if m["timing_variance"] > 0.01 * pred.noise:
        lines.append(
            f"  note: {m['timing_variance']:.3g} deg² of the noise is the time bases' error, "
            "which grows with the motion's rate (not scaled here)"
        )
    lines.extend(f"  warning: {w}" for w in pred.warnings)
    lines.extend(f"  the recording: {w}" for w in m["warnings"])
    return "\n".join(lines)
