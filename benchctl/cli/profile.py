"""``benchctl profile show|synth|plot``: look at a motion profile before it moves the stand."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("profile", type=Path, help="profile YAML (see profiles/)")
    p.add_argument("--duration", type=float, metavar="SEC", help="override the profile's duration")
    p.add_argument("--seed", type=int, help="override the profile's seed")
    p.add_argument(
        "--rate",
        type=float,
        metavar="HZ",
        help="sample rate (default: the config's setpoint_rate_hz, else 100 Hz)",
    )
    p.add_argument("--config", type=Path, help="bench config: check against its stand limits")
    p.add_argument(
        "--scale-to-fit",
        action="store_true",
        help="with --config: scale the motion down to fit the limits instead of refusing",
    )


def register(sub: Any) -> None:
    p = sub.add_parser(
        "profile",
        help="show, synthesise or plot a motion profile",
        description=(
            "Look at a motion profile (profiles/*.yaml) before it moves the stand, synthesised "
            "exactly as a run would: show its figures, write its motion as CSV (synth), or "
            "plot its spectrum and trace (plot). With --config the motion is checked against "
            "the stand's limits (angle, rate, acceleration), as a run checks it."
        ),
    )
    ps = p.add_subparsers(dest="profile_command", metavar="ACTION")
    ps.required = True
    show = ps.add_parser(
        "show", help="kind, band, sigma, peaks, crest factor, lines, period",
        description=(
            "A profile's kind, band, σ, peak angle, rate and acceleration, crest factor, its "
            "lines and period, and (with --config) whether it fits the stand's limits. Exit 0, "
            "2 for a bad profile or one over the limits."))
    _common(show)
    show.add_argument("--json", action="store_true", help="one JSON object on stdout")
    show.set_defaults(handler=handle_show)
    synth = ps.add_parser(
        "synth", help="write the motion as CSV (time_s, <axis>_deg)",
        description=(
            "Write the profile's motion, as a run would command it, as CSV (time_s, "
            "<axis>_deg per axis) at --rate; --table also writes its harmonic table."))
    _common(synth)
    synth.add_argument("--out", type=Path, required=True, metavar="FILE.csv", help="output CSV")
    synth.add_argument(
        "--table", type=Path, metavar="FILE.csv", help="also write the harmonic table (CSV)"
    )
    synth.add_argument("--json", action="store_true", help="one JSON object on stdout")
    synth.set_defaults(handler=handle_synth)
    plot = ps.add_parser(
        "plot", help="target vs synthesised spectrum, and a stretch of the trace",
        description=(
            "Plot the profile's target spectrum against the synthesised motion's, and the "
            "first --window seconds of its trace, to an image (PNG)."))
    _common(plot)
    plot.add_argument("--out", type=Path, required=True, metavar="FILE.png", help="output image")
    plot.add_argument(
        "--window", type=float, default=60.0, metavar="SEC", help="trace length shown"
    )
    plot.set_defaults(handler=handle_plot)


def _prepare(args: argparse.Namespace) -> tuple[Any, Any, Any, float]:
    """(profile, motion, check or None, rate_hz) after loading, synthesis and the limit check."""
    from benchctl.config import load_config
    from benchctl.options import (
        MAX_PROFILE_RATE_HZ,
        MAX_PROFILE_SAMPLES,
        MAX_RUN_DURATION_S,
        MAX_SEED,
        check_option,
    )
    from benchctl.profiles import check_motion, load_profile, measure_peaks, synthesize

    check_option("--duration", args.duration, 0, MAX_RUN_DURATION_S, lo_open=True, unit="s")
    check_option("--seed", args.seed, 0, MAX_SEED)
    check_option("--rate", args.rate, 0, MAX_PROFILE_RATE_HZ, lo_open=True, unit="Hz")
    check_option("--window", getattr(args, "window", None), 0, MAX_RUN_DURATION_S,
                 lo_open=True, unit="s")
    profile = load_profile(args.profile)
    cfg = load_config(args.config) if args.config is not None else None
    rate = args.rate or (cfg.stand.setpoint_rate_hz if cfg else 100.0)
    if not (math.isfinite(rate) and rate > 0):
        raise InputError(f"--rate {rate}: expected a rate in Hz > 0")
    duration = args.duration if args.duration is not None else profile.duration_s
    if duration * rate > MAX_PROFILE_SAMPLES:
        raise InputError(
            f"{duration:g} s at {rate:g} Hz is {duration * rate:.4g} samples per axis; expected "
            f"at most {MAX_PROFILE_SAMPLES} (lower --rate or --duration)"
        )
    motion = synthesize(profile, duration_s=args.duration, seed=args.seed, setpoint_rate_hz=rate)
    if cfg is not None:
        check = check_motion(motion, cfg.stand.limits, scale_to_fit=args.scale_to_fit, rate_hz=rate)
        return profile, check.motion, check, rate
    if args.scale_to_fit:
        raise InputError("--scale-to-fit needs --config (the stand limits)")
    return profile, motion, measure_peaks(motion, rate), rate


def _report(profile: Any, motion: Any, check: Any, rate: float) -> dict[str, Any]:
    out: dict[str, Any] = {"profile": str(profile.source), **motion.summary(), "rate_hz": rate}
    if isinstance(check, dict):
        out["peaks"] = {a: p.to_dict() for a, p in check.items()}
        out["check"] = None
    else:
        out["peaks"] = {a: p.to_dict() for a, p in check.peaks.items()}
        out["check"] = check.to_dict()
    return out


def _print_report(r: dict[str, Any]) -> None:
    print(f"profile   {r['name']} ({r['kind']})  {r['profile']}")
    print(f"duration  {r['duration_s']:g} s   seed {r['seed']}   axes {', '.join(r['axes'])}")
    for note in r.get("notes", []):
        print(f"          {note}")
    for axis in r["axes"]:
        pk = r["peaks"][axis]
        print(f"[{axis}]")
        pa = r.get("per_axis", {}).get(axis)
        if pa:
            line = f"  lines {pa['n_lines']}"
            if pa.get("period_s"):
                line += f", period T_p {pa['period_s']:g} s"
            if pa.get("band_hz"):
                line += f", band {pa['band_hz'][0]:g}…{pa['band_hz'][1]:g} Hz"
            print(line)
            sig = f"  sigma {pa['sigma_deg']:.4f} deg"
            if pa.get("target_sigma_deg") is not None:
                sig += (
                    f" (target {pa['target_sigma_deg']:.4f} deg, variance error "
                    f"{100 * pa['variance_error']:+.3f} %)"
                )
            print(sig)
            if pa.get("band_share") is not None:
                print(
                    f"  model sigma {pa['model_sigma_deg']:.4f} deg; the band keeps "
                    f"{100 * pa['band_share']:.1f} % of its variance, so the motion's sigma is "
                    f"{pa['sigma_deg']:.4f} deg"
                )
            crest = pa.get("crest")
            if crest and crest["method"] != "none":
                print(
                    f"  crest factor {crest['crest_after']:.3f} ({crest['method']}: from "
                    f"{crest['crest_before']:.3f})"
                )
            elif pa.get("crest_factor") is not None:
                print(f"  crest factor {pa['crest_factor']:.3f}")
        print(
            f"  peak angle {pk['angle_deg']:.3f} deg, rate {pk['rate_deg_s']:.3f} deg/s, "
            f"acceleration {pk['accel_deg_s2']:.3f} deg/s² (at {r['rate_hz']:g} Hz)"
        )
    if r.get("steps"):
        print(f"steps     {r['n_steps']}")
        for s in r["steps"]:
            print(
                f"  {s['axis']:5s} {s['start_s']:8.1f}…{s['end_s']:8.1f} s"
                f"  period {s['period_s']:g} s  amplitude {s['amplitude_deg']:g} deg"
            )
    chk = r.get("check")
    if chk is not None:
        lim = chk["limits"]
        verdict = "within limits" + (
            f" after scaling by {chk['scale']:g}" if chk["scale"] != 1 else ""
        )
        print(
            f"limits    angle {lim['angle_deg']:g} deg, rate {lim['rate_deg_s']:g} deg/s, "
            f"accel {lim['accel_deg_s2']:g} deg/s²: {verdict}"
        )


def handle_show(args: argparse.Namespace) -> int:
    profile, motion, check, rate = _prepare(args)
    report = _report(profile, motion, check, rate)
    if args.json:
        print(dumps(report, indent=2))
    else:
        _print_report(report)
    return ExitCode.OK


def handle_synth(args: argparse.Namespace) -> int:
    import numpy as np

    from benchctl.profiles import sample_times, tables_to_csv

    profile, motion, check, rate = _prepare(args)
    tables = motion.tables
    if args.table is not None and tables is None:
        raise InputError(
            f"{args.profile}: kind {profile.kind} is not one harmonic table per axis; "
            "no --table export"
        )
    t = sample_times(motion.duration_s, rate)
    x = motion.evaluate(t)
    cols = [t] + [x[a] for a in motion.axes]
    header = ",".join(["time_s"] + [f"{a}_deg" for a in motion.axes])
    try:
        np.savetxt(
            args.out, np.column_stack(cols), fmt="%.6f", delimiter=",", header=header, comments=""
        )
        if args.table is not None:
            args.table.write_text(tables_to_csv(tables), encoding="utf-8")
    except OSError as e:
        raise InputError(f"{e.filename}: cannot write: {e.strerror}") from None
    report = _report(profile, motion, check, rate)
    report.update(
        {
            "out": str(args.out),
            "n_samples": int(t.size),
            "table": str(args.table) if args.table else None,
        }
    )
    if args.json:
        print(dumps(report, indent=2))
    else:
        print(
            f"wrote {args.out}: {t.size} samples at {rate:g} Hz, {motion.duration_s:g} s, "
            f"axes {', '.join(motion.axes)}"
        )
        if args.table is not None:
            print(f"wrote {args.table}: harmonic table")
    return ExitCode.OK


def handle_plot(args: argparse.Namespace) -> int:
    import numpy as np
    from matplotlib.figure import Figure

    from benchctl.profiles import sample_times
    from benchctl.profiles.synthesis import periodogram_lines

    profile, motion, _check, rate = _prepare(args)
    axes = motion.axes
    fig = Figure(figsize=(9, 7))  # the object API: no backend switch, no pyplot state
    ax = fig.subplots(2, 1)
    tables = motion.tables
    for a in axes:
        tab = tables[a] if tables else None
        if tab is not None and tab.period_s and tab.n_lines:
            fi, fo = tab.fade_in_s, tab.fade_out_s
            n = round((tab.duration_s - fi - fo) * rate)
            periods = max(1, round((tab.duration_s - fi - fo) / tab.period_s))
            ts = fi + np.arange(n) / rate
            xs = motion.evaluate(ts)[a]  # envelope is 1 on the steady part
            k = np.round(tab.freq_hz * tab.period_s).astype(np.int64)
            var = periodogram_lines(xs, k, periods)
            df = 1.0 / tab.period_s
            ax[0].plot(tab.freq_hz, var / df, "o", ms=3, label=f"{a}: synthesised (periodogram)")
            fgrid = np.linspace(max(1e-4, tab.freq_hz.min() * 0.5), tab.freq_hz.max() * 1.5, 800)
            g = motion.target_psd(a, fgrid)
            if g is not None:
                ax[0].plot(fgrid, g, "-", label=f"{a}: target G(f)")
        elif tab is not None:
            ax[0].stem(tab.freq_hz, tab.amp_deg**2 / 2, label=f"{a}: line variance A²/2 (deg²)")
    ax[0].set_xlabel("frequency, Hz")
    ax[0].set_ylabel("PSD, deg²/Hz")
    ax[0].set_title(f"{profile.name}: target vs synthesised spectrum")
    ax[0].legend(fontsize=8)
    t = sample_times(min(args.window, motion.duration_s), rate)
    x = motion.evaluate(t)
    for a in axes:
        ax[1].plot(t, x[a], lw=0.8, label=a)
    ax[1].set_xlabel("time, s")
    ax[1].set_ylabel("angle, deg")
    ax[1].legend(fontsize=8)
    fig.tight_layout()
    try:
        fig.savefig(args.out, dpi=110)
    except OSError as e:
        raise InputError(f"{args.out}: cannot write: {e.strerror}") from None
    print(f"wrote {args.out}")
    return ExitCode.OK
