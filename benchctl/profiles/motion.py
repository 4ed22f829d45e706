"""Planned stand motions: what the run layer plays — a :class:`Motion` (its axes, duration,
``evaluate(t, derivative)``, target density, summary, scaling), made of one harmonic table per
axis (:class:`TableMotion`) or of steps (:class:`StepMotion`).

Pure computation, no I/O. The tables themselves are designed and sampled in
:mod:`benchctl.profiles.synthesis`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.harmonics import HarmonicTable
from benchctl.profiles.synthesis import CrestReport, crest_factor, evaluate_table

FloatArray = NDArray[np.float64]
Density = Callable[[FloatArray], FloatArray]


@dataclass(frozen=True)
class AxisTarget:
    """The target spectrum of one axis, to compare the synthesis with."""

    density: Density
    band_hz: tuple[float, float]
    variance_deg2: float  # ∫_band G df (already scaled)
    scale: float = 1.0  # amplitude scale applied since design: G is multiplied by scale²
    model_variance_deg2: float | None = None  # ∫_0^∞ G df (already scaled): the whole model

    def psd(self, f_hz: ArrayLike) -> FloatArray:
        return np.asarray(self.scale**2 * np.asarray(self.density(np.asarray(f_hz, dtype=float))))


class Motion:
    """A planned stand motion for one or more axes (abstract base).

    Contract (relied on by the run layer): ``axes``, ``duration_s``,
    ``evaluate(t_s, derivative=0|1|2) -> {axis: ndarray}`` (deg, deg/s, deg/s², zero outside
    ``[0, duration_s]``), ``tables`` (one :class:`HarmonicTable` per axis, or ``None`` when the
    motion is not one table per axis), ``target_psd(axis, f_hz)``, ``summary()`` (JSON-able),
    ``scaled(factor)``.
    """

    name: str
    kind: str
    axes: tuple[str, ...]
    duration_s: float
    seed: int | None

    @property
    def tables(self) -> dict[str, HarmonicTable] | None:
        return None

    def evaluate(self, t_s: ArrayLike, derivative: int = 0) -> dict[str, FloatArray]:
        raise NotImplementedError

    def target_psd(self, axis: str, f_hz: ArrayLike) -> FloatArray | None:
        """Target one-sided density at ``f_hz`` (deg²/Hz), or None if the kind has none."""
        return None

    def summary(self) -> dict[str, object]:
        raise NotImplementedError

    def scaled(self, factor: float) -> Motion:
        raise NotImplementedError


def _scaled_table(table: HarmonicTable, factor: float) -> HarmonicTable:
    return HarmonicTable(
        table.freq_hz,
        table.amp_deg * factor,
        table.phase_rad,
        table.duration_s,
        table.fade_in_s,
        table.fade_out_s,
        table.period_s,
        dict(table.meta),
    )


@dataclass(frozen=True)
class TableMotion(Motion):
    """One :class:`HarmonicTable` per axis (sea_state, roll_spectrum, recorded, harmonics, sine)."""

    name: str
    kind: str
    table_by_axis: Mapping[str, HarmonicTable]
    targets: Mapping[str, AxisTarget | None]
    seed: int | None
    crest: Mapping[str, CrestReport] = field(default_factory=dict)
    scale: float = 1.0
    notes: tuple[str, ...] = ()

    @property
    def axes(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(self.table_by_axis)

    @property
    def duration_s(self) -> float:  # type: ignore[override]
        return next(iter(self.table_by_axis.values())).duration_s

    @property
    def tables(self) -> dict[str, HarmonicTable]:
        return dict(self.table_by_axis)

    def evaluate(self, t_s: ArrayLike, derivative: int = 0) -> dict[str, FloatArray]:
        return {a: evaluate_table(tab, t_s, derivative) for a, tab in self.table_by_axis.items()}

    def target_psd(self, axis: str, f_hz: ArrayLike) -> FloatArray | None:
        target = self.targets.get(axis)
        return None if target is None else target.psd(f_hz)

    def scaled(self, factor: float) -> TableMotion:
        if not factor > 0:
            raise ValueError(f"scale factor must be > 0, got {factor!r}")
        targets = {
            a: None
            if t is None
            else AxisTarget(
                t.density,
                t.band_hz,
                t.variance_deg2 * factor**2,
                t.scale * factor,
                None if t.model_variance_deg2 is None else t.model_variance_deg2 * factor**2,
            )
            for a, t in self.targets.items()
        }
        return TableMotion(
            self.name,
            self.kind,
            {a: _scaled_table(t, factor) for a, t in self.table_by_axis.items()},
            targets,
            self.seed,
            self.crest,
            self.scale * factor,
            self.notes,
        )

    def summary(self) -> dict[str, object]:
        per_axis: dict[str, object] = {}
        for a, tab in self.table_by_axis.items():
            target = self.targets.get(a)
            var = tab.variance_deg2
            w = 2.0 * np.pi * tab.freq_hz
            entry: dict[str, object] = {
                "n_lines": tab.n_lines,
                "period_s": tab.period_s,
                "f_min_hz": float(tab.freq_hz.min()) if tab.n_lines else None,
                "f_max_hz": float(tab.freq_hz.max()) if tab.n_lines else None,
                "sigma_deg": math.sqrt(var),
                "variance_deg2": var,
                "rate_bound_deg_s": float(np.sum(w * tab.amp_deg)),
                "accel_bound_deg_s2": float(np.sum(w**2 * tab.amp_deg)),
            }
            if target is not None:
                entry["band_hz"] = list(target.band_hz)
                entry["target_variance_deg2"] = target.variance_deg2
                entry["target_sigma_deg"] = math.sqrt(target.variance_deg2)
                entry["variance_error"] = (
                    var / target.variance_deg2 - 1.0 if target.variance_deg2 > 0 else None
                )
                mv = target.model_variance_deg2
                if mv is not None and mv > 0:
                    # what the band keeps of the model: the motion's σ is the band's, not the
                    # model's (a band cutting the tails lowers it)
                    entry["model_variance_deg2"] = mv
                    entry["model_sigma_deg"] = math.sqrt(mv)
                    entry["band_share"] = target.variance_deg2 / mv
            crest = self.crest.get(a)
            if crest is not None:
                entry["crest"] = crest.to_dict()
                entry["crest_factor"] = crest.crest_after
            elif tab.period_s and tab.n_lines:
                k = np.round(tab.freq_hz * tab.period_s).astype(np.int64)
                entry["crest_factor"] = crest_factor(k, tab.amp_deg, tab.phase_rad)
            elif tab.n_lines and var > 0:  # not periodic: estimate over a long stretch
                span = min(tab.duration_s, 20.0 / float(tab.freq_hz.min()))
                ts = np.linspace(
                    0.0, span, max(2, math.ceil(span * 20.0 * float(tab.freq_hz.max())))
                )
                entry["crest_factor"] = float(np.max(np.abs(tab.steady(ts)))) / math.sqrt(var)
            per_axis[a] = entry
        first = next(iter(self.table_by_axis.values()))
        return {
            "name": self.name,
            "kind": self.kind,
            "axes": list(self.axes),
            "duration_s": self.duration_s,
            "fade_in_s": first.fade_in_s,
            "fade_out_s": first.fade_out_s,
            "seed": self.seed,
            "scale": self.scale,
            "per_axis": per_axis,
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class StepSegment:
    """One sine of a step sequence: ``table`` played on ``axis`` from ``start_s``."""

    axis: str
    start_s: float
    period_s: float
    amplitude_deg: float
    table: HarmonicTable

    @property
    def end_s(self) -> float:
        return self.start_s + self.table.duration_s


@dataclass(frozen=True)
class StepMotion(Motion):
    """A sequence of faded single sines with rests between (sine_steps): no single table."""

    name: str
    kind: str
    axes: tuple[str, ...]
    segments: tuple[StepSegment, ...]
    duration_s: float
    seed: int | None = None
    scale: float = 1.0

    def evaluate(self, t_s: ArrayLike, derivative: int = 0) -> dict[str, FloatArray]:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        out = {a: np.zeros_like(t) for a in self.axes}
        for seg in self.segments:
            sel = (t >= seg.start_s) & (t <= seg.end_s)
            if np.any(sel):
                out[seg.axis][sel] += evaluate_table(seg.table, t[sel] - seg.start_s, derivative)
        return out

    def scaled(self, factor: float) -> StepMotion:
        if not factor > 0:
            raise ValueError(f"scale factor must be > 0, got {factor!r}")
        segs = tuple(
            StepSegment(
                s.axis,
                s.start_s,
                s.period_s,
                s.amplitude_deg * factor,
                _scaled_table(s.table, factor),
            )
            for s in self.segments
        )
        return StepMotion(
            self.name, self.kind, self.axes, segs, self.duration_s, self.seed, self.scale * factor
        )

    def summary(self) -> dict[str, object]:
        return {
            "name": self.name,
            "kind": self.kind,
            "axes": list(self.axes),
            "duration_s": self.duration_s,
            "seed": self.seed,
            "scale": self.scale,
            "n_steps": len(self.segments),
            "steps": [
                {
                    "axis": s.axis,
                    "start_s": s.start_s,
                    "end_s": s.end_s,
                    "period_s": s.period_s,
                    "amplitude_deg": s.amplitude_deg,
                    "fade_s": s.table.fade_in_s,
                }
                for s in self.segments
            ],
        }
