"""A run's motion, prepared before anything opens: the profile loaded, synthesised at the
stand's rate and checked against its limits and the bench (``prepare_motion``); the mounting
check's tilt (``mounting_plan``) and the equalisation pre-test (``prepare_pretest``) checked
the same way; the run's options (``RunOptions``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from benchctl.analysis.equalise import (
    pretest_design,
)
from benchctl.config import BenchConfig, StandConfig
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.errors import (
    ConfigError,
    DataError,
    LimitError,
)
from benchctl.kinematics import Limits, profile_peaks
from benchctl.profiles import check_motion, load_profile, synthesize
from benchctl.run import mounting as mt
from benchctl.run import prechecks as pc
from benchctl.run.plan import MotionPlan, check_setpoints, make_plan
from benchctl.run.precision import (
    profile_period,
)
from benchctl.text import (
    check_operator,
    check_part_number,
    check_serial,
)


@dataclass
class RunOptions:
    serial: str
    operator: str
    duration_s: float | None = None
    out_dir: Path | None = None
    seed: int | None = None
    scale_to_fit: bool = False  # scale a profile over the limits down instead of refusing it
    precision: float | None = None  # --precision: overrides run.precision (see run.precision)
    decision_rule: str | None = None  # --decision-rule: overrides run.decision_rule
    part_number: str | None = None  # --part-number: overrides unit.part_number
    equalise: bool | None = None  # --equalise: overrides run.equalise.enabled

    def __post_init__(self) -> None:
        """The serial, the operator and the part number checked and stripped
        (``benchctl.text``): a control character or an overlong value is an ``InputError``
        here, before anything is read or opened."""
        self.serial = check_serial(self.serial, "serial")
        self.operator = check_operator(self.operator, "operator")
        if self.part_number is not None:
            self.part_number = check_part_number(self.part_number, "part_number")


@dataclass(frozen=True)
class PreparedMotion:
    profile: Any
    motion: Any
    plan: MotionPlan
    check: pc.CheckResult
    meta: dict[str, Any]
    # run.equalise: the pre-test (its designs per axis, its checked plan); None: no pre-test
    pretest: Pretest | None = None
    # run.mounting_check: the tilt, checked against the limits; None: planned when it is run
    # (a caller's own PreparedMotion) or no check
    tilt: MotionPlan | None = None


def mounting_plan(cfg: BenchConfig, axes: tuple[str, ...], where: str) -> MotionPlan:
    """The mounting check's tilt of ``axes`` (``benchctl.run.mounting.tilt_points``) as a plan
    for a stand loop, checked step by step against the stand's limits; ``LimitError`` naming
    ``where`` and the fields when it does not fit. Setpoints at the stand's setpoint rate,
    streamed — or queued, on a buffered stand (a stand that plays tables takes setpoints too:
    its ramp to zero is streamed)."""

    mc, lim = cfg.run.mounting_check, cfg.stand.limits
    period = 1.0 / cfg.stand.setpoint_rate_hz
    try:
        points = mt.tilt_points(axes, mc.tilt_deg, mc.hold_s,
                                Limits(lim.angle_deg, lim.rate_deg_s, lim.accel_deg_s2), period)
    except LimitError as e:
        raise LimitError(
            f"{where}: field run.mounting_check.tilt_deg = {mc.tilt_deg:g}°: {e} (field "
            "stand.limits); expected a smaller tilt, or run.mounting_check.enabled: false"
        ) from None
    n = next(iter(points.values())).size
    mode = "buffered" if cfg.stand.mode == "buffered" else "stream"
    return MotionPlan(axes, period, points, (n - 1) * period, 0.0, 0.0, mode,
                      peaks={a: profile_peaks(v, period) for a, v in points.items()})


@dataclass
class Pretest:
    """The equalisation pre-test, checked against the limits like any motion."""

    designs: dict[str, Any]  # axis → benchctl.analysis.equalise.PretestDesign
    motion: Any
    plan: MotionPlan
    check: dict[str, Any]


def prepare_pretest(cfg: BenchConfig, motion: Any, rate: float, where: str) -> Pretest:
    """The low-level pre-test of ``motion`` (``run.equalise``), checked against the stand's
    limits before anything moves; raises ``ConfigError``/``LimitError`` naming ``where``."""

    eq = cfg.run.equalise
    tables = getattr(motion, "tables", None) or {}
    if not tables or getattr(motion, "segments", None):
        raise ConfigError(
            f"{where}: equalisation needs a profile of lines (one harmonic table per axis); "
            f"profile kind {getattr(motion, 'kind', '?')!r} has none; expected no equalisation"
        )
    try:
        designs = {
            a: pretest_design(t, level=eq.level, periods=eq.periods,
                              max_period_s=eq.max_period_s, fade_s=eq.fade_s,
                              settle_s=eq.settle_s)
            for a, t in tables.items()
        }
    except DataError as e:
        raise ConfigError(f"{where}: {e}; expected a profile whose lines repeat") from None
    duration = max(d.table.duration_s for d in designs.values())
    pre_tables = {  # one duration for every axis: the longest pre-test
        a: dataclasses.replace(d.table, duration_s=duration) for a, d in designs.items()}
    pre_motion = dataclasses.replace(motion, name=f"{motion.name} (equalisation pre-test)",
                                     table_by_axis=pre_tables)
    try:  # a pre-test over the limits (another crest): scaled down, it only measures
        result = check_motion(pre_motion, cfg.stand.limits, rate_hz=rate, scale_to_fit=True)
    except LimitError as e:
        raise LimitError(f"{where}: the equalisation pre-test: {e}") from None
    pre_motion = result.motion
    tabs = dict(pre_motion.tables or {})
    designs = {a: dataclasses.replace(d, table=tabs[a]) for a, d in designs.items()}

    def evaluate(t: np.ndarray) -> dict[str, np.ndarray]:
        return {a: np.asarray(v, dtype=float) for a, v in pre_motion.evaluate(t).items()}

    fade = cfg.run.equalise.fade_s
    plan = make_plan(evaluate, tuple(tabs), duration, rate, fade, fade, mode=cfg.stand.mode,
                     tables=tabs)
    return Pretest(designs, pre_motion, plan, result.to_dict())


def _fades(motion: Any) -> tuple[float, float]:
    for obj in (motion, *(getattr(motion, "tables", None) or {}).values()):
        fi, fo = getattr(obj, "fade_in_s", None), getattr(obj, "fade_out_s", None)
        if fi is not None and fo is not None:
            return float(fi), float(fo)
    return 0.0, 0.0


def motion_rate_hz(stand: StandConfig) -> float:
    """The one rule for the rate a run's motion is synthesised at: the stand's setpoint rate
    (streamed or queued points), or — a stand that plays tables — the rate its angle is read
    at (the table's samples are the reference's instants)."""
    return stand.setpoint_rate_hz if stand.mode != "table" else stand.sample_rate_hz


def check_motion_length(stand: StandConfig, duration_s: float, where: str) -> None:
    """The one cap on a motion's setpoints, before any of it is synthesised: ``duration_s`` at
    the stand's faster rate, in any mode (``LimitError`` naming ``where`` beyond it). The
    command line's ``--duration``, a plan's step and a profile's own duration all pass here."""
    check_setpoints(duration_s, max(stand.setpoint_rate_hz, stand.sample_rate_hz), where)


def prepare_motion(cfg: BenchConfig, profile_path: Path, opts: RunOptions) -> PreparedMotion:
    """Load, synthesise and check the profile against this bench; raises before anything moves."""

    profile = load_profile(profile_path)
    rate = motion_rate_hz(cfg.stand)
    src = cfg.source or Path("<config>")
    # every motion (the profile's own duration, a plan step's, --duration) capped before any
    # of it is synthesised, at the stand's faster rate in any mode (as --duration is)
    duration = profile.duration_s if opts.duration_s is None else opts.duration_s
    check_motion_length(cfg.stand, duration, f"{profile_path} on {src}")
    motion = synthesize(profile, duration_s=opts.duration_s, seed=opts.seed, setpoint_rate_hz=rate)
    axes = tuple(motion.axes)
    for section, have in (("stand", cfg.stand.axes), ("instrument", cfg.instrument.axes)):
        missing = [a for a in axes if a not in have]
        if missing:
            raise ConfigError(
                f"{src}: field {section}.axes = {list(have)}: the profile {profile_path} moves "
                f"{list(axes)}, expected {section}.axes to include {missing}"
            )
    if (cfg.stand.mode == "buffered"
            and load_register_map(cfg.stand.register_map).trajectory is None):
        raise ConfigError(
            f"{src}: field stand.mode = 'buffered', but the register map "
            f"{cfg.stand.register_map} has no trajectory queue (no `trajectory:` section); "
            "expected mode 'stream' or 'table' for this stand"
        )
    if cfg.stand.mode == "table" and not getattr(motion, "tables", None):
        raise ConfigError(
            f"{src}: field stand.mode = 'table', but profile {profile_path} gives no harmonic "
            "table; expected mode 'stream' for this profile"
        )
    if cfg.stand.mode == "table":
        axes_map = load_register_map(cfg.stand.register_map).axes
        for a, tab in (motion.tables or {}).items():
            room = axes_map[a].table_max_lines if a in axes_map else 0
            if tab is not None and tab.n_lines > room:
                raise LimitError(
                    f"{profile_path} on {src} (field stand.mode = 'table'): the {a} table has "
                    f"{tab.n_lines} lines over {duration:g} s, the stand's table takes at most "
                    f"{room} (register map {cfg.stand.register_map}); expected mode 'buffered' "
                    "or 'stream', or a profile with fewer lines"
                )
    # raises LimitError naming needed vs allowed, before anything opens
    try:
        result = check_motion(
            motion, cfg.stand.limits, rate_hz=rate, scale_to_fit=opts.scale_to_fit
        )
    except LimitError as e:
        raise LimitError(f"{profile_path} on {src} (field stand.limits): {e}") from None
    motion = result.motion
    figures = result.to_dict()
    check = pc.CheckResult("profile within limits", True, "within the stand limits", figures)
    fade_in, fade_out = _fades(motion)
    tables = motion.tables
    tables = dict(tables) if tables else None

    def evaluate(t: np.ndarray) -> dict[str, np.ndarray]:
        return {a: np.asarray(v, dtype=float) for a, v in motion.evaluate(t).items()}

    plan = make_plan(
        evaluate,
        axes,
        float(motion.duration_s),
        rate,
        fade_in,
        fade_out,
        mode=cfg.stand.mode,
        tables=tables,
    )
    pdict = profile.to_dict() if hasattr(profile, "to_dict") else {}
    requested = opts.precision if opts.precision is not None else cfg.run.precision
    equalise = opts.equalise if opts.equalise is not None else cfg.run.equalise.enabled
    if requested is not None:  # a precision stop: whole periods of a multisine, not table mode
        where = (f"--precision {requested:g}" if opts.precision is not None
                 else f"{src}: field run.precision = {requested:g}")
        if cfg.stand.mode == "table":
            raise ConfigError(
                f"{where}: a precision stop needs stand.mode 'stream' or 'buffered' (a stand "
                "playing its table cannot be faded out early); expected no precision here"
            )
        profile_period(motion, axes, f"{where} with profile {profile_path}")
    meta = {
        "profile_path": str(profile_path),
        "profile_name": getattr(profile, "name", profile_path.stem),
        "profile": pdict,
        "seed": opts.seed if opts.seed is not None else getattr(profile, "seed", None),
        "duration_s": float(motion.duration_s),
        "fade_in_s": fade_in,
        "fade_out_s": fade_out,
        "motion_check": figures,
        "scale": result.scale,
        "precision_requested": requested,
        "equalise_requested": equalise,
    }
    tilt = mounting_plan(cfg, axes, f"{src}") if cfg.run.mounting_check.enabled else None
    pretest = None
    if equalise:
        where = "--equalise" if opts.equalise else f"{src}: field run.equalise.enabled = true"
        pretest = prepare_pretest(cfg, motion, rate, f"{where} with profile {profile_path}")
        meta["equalise_pretest"] = {
            "axes": {a: d.to_dict() for a, d in pretest.designs.items()},
            "duration_s": pretest.plan.duration_s,
            "check": pretest.check,
        }
    return PreparedMotion(profile, motion, plan, check, meta, pretest, tilt)
