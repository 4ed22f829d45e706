"""The result of one analysis, and its JSON form (keys documented in
``docs/reference/analyze.md``, "JSON")."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.budget import Budget

if TYPE_CHECKING:
    from benchctl.analysis.linewise import LineAnalysis
    from benchctl.analysis.steps import StepsAnalysis

FloatArray = NDArray[np.float64]


def _num(v: float) -> float | None:
    """A JSON-safe float: NaN/inf become None."""
    f = float(v)
    return f if math.isfinite(f) else None


def _clean(v: Any) -> Any:
    """Nested dicts/lists with every non-finite float replaced by None (strict JSON)."""
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, float | np.floating):
        return _num(float(v))
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, np.bool_):
        return bool(v)
    return v


def _list(a: NDArray[Any]) -> list[Any]:
    """A JSON-safe list (nested for 2-D arrays) of an array's floats, NaN/inf as None."""
    arr = np.asarray(a, dtype=float)
    if np.isfinite(arr).all():
        return list(arr.tolist())
    return list(_clean(arr.tolist()))


@dataclass
class AnalysisResult:
    """Everything one analysis says about one axis. Angles in deg, times in s, PSD deg²/Hz.

    ``sigma`` is the dynamic error (about the mean), ``sigma_ci95`` the 95 % interval of the
    error's σ (the mean removal's loss included, see ``uncertainty``), ``dof`` its equivalent
    degrees of freedom; ``delay`` the device's equivalent delay behind the reference;
    ``delay_compensated`` what was removed before the analysis (0 if nothing). ``lines``: the
    line-wise estimate when the record holds whole periods of known lines (then ``frf_*``,
    ``periods``, ``linear``/``incoherent`` and ``sigma_ci95`` come from it), else None.
    """

    sigma: float
    variance: float
    mean_error: float
    rms_error: float
    sigma_ci95: tuple[float, float]
    dof: float
    delay: float
    delay_compensated: float
    n_samples: int
    duration: float
    sample_rate: float
    max_lag: float
    max_lag_samples: int
    resolution_hz: float
    dof_per_frequency: float
    psd_freq: FloatArray
    psd_error: FloatArray
    psd_ci95: tuple[FloatArray, FloatArray]
    welch_freq: FloatArray | None
    welch_error: FloatArray | None
    frf_freq: FloatArray
    frf_gain: FloatArray
    frf_phase_deg: FloatArray
    frf_coherence: FloatArray
    frf_gain_ci95: FloatArray
    frf_phase_ci95_deg: FloatArray
    frf_source: str
    periods: list[dict[str, Any]]
    linear: float
    incoherent: float
    components_source: str
    lines: LineAnalysis | None
    band: dict[str, Any] | None
    gaps: dict[str, Any]
    timing: dict[str, Any]
    cross_checks: dict[str, Any]
    uncertainty: dict[str, Any]
    source: str = ""
    axis: str | None = None
    warnings: list[str] = field(default_factory=list)
    # per frf point from the lines: SNR at least the floor (None from H1: no such test)
    frf_reliable: NDArray[np.bool_] | None = None
    steps: StepsAnalysis | None = None  # sine_steps: the linearity table and its verdict
    # this axis's output against the other axis's motion (benchctl.analysis.crossaxis)
    cross_axis: dict[str, Any] | None = None
    # the measured stand angle's spectrum against the profile's (benchctl.analysis.excitation)
    excitation: dict[str, Any] | None = None
    # where the stand's motion was not the profile's, left out (benchctl.analysis.departures;
    # the keys: docs/reference/analyze.md, "JSON"); None when no departure touches the record
    departures: dict[str, Any] | None = None
    # σ's uncertainty budget, GUM style (benchctl.analysis.budget); None only for a result
    # made otherwise than by ``analyze``
    budget: Budget | None = None

    @property
    def judgeable(self) -> bool:
        """False when departures left too little of the profile's motion to judge σ on."""
        return not (self.departures or {}).get("too_little", False)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (NaN/inf → null). See ``docs/reference/analyze.md``, "JSON", for
        every key."""
        return {
            "source": self.source,
            "axis": self.axis,
            "sigma": _num(self.sigma),
            "variance": _num(self.variance),
            "mean_error": _num(self.mean_error),
            "rms_error": _num(self.rms_error),
            "sigma_ci95": [_num(self.sigma_ci95[0]), _num(self.sigma_ci95[1])],
            "dof": _num(self.dof),
            "delay": _num(self.delay),
            "delay_compensated": _num(self.delay_compensated),
            "n_samples": self.n_samples,
            "duration": _num(self.duration),
            "sample_rate": _num(self.sample_rate),
            "max_lag": _num(self.max_lag),
            "max_lag_samples": self.max_lag_samples,
            "resolution_hz": _num(self.resolution_hz),
            "components": {
                "linear": _num(self.linear),
                "incoherent": _num(self.incoherent),
                "static": _num(self.mean_error**2),
                "source": self.components_source,
            },
            "band": _clean(self.band),
            "periods": _clean(self.periods),
            "frf": {
                "freq": _list(self.frf_freq),
                "gain": _list(self.frf_gain),
                "phase_deg": _list(self.frf_phase_deg),
                "coherence": _list(self.frf_coherence),
                "gain_ci95": _list(self.frf_gain_ci95),
                "phase_ci95_deg": _list(self.frf_phase_ci95_deg),
                "reliable": None if self.frf_reliable is None
                else [bool(v) for v in self.frf_reliable],
                "source": self.frf_source,
            },
            "lines": None if self.lines is None else _clean(self.lines.to_dict()),
            "distortion": None if self.lines is None or self.lines.distortion is None
            else _clean(self.lines.distortion.to_dict()),
            "cross_axis": _clean(self.cross_axis),
            "excitation": _clean(self.excitation),
            "psd": {
                "freq": _list(self.psd_freq),
                "error": _list(self.psd_error),
                "dof": _num(self.dof_per_frequency),
            },
            "gaps": _clean(self.gaps),
            "departures": _clean(self.departures),
            "timing": _clean(self.timing),
            "cross_checks": _clean(self.cross_checks),
            "uncertainty": _clean(self.uncertainty),
            "budget": None if self.budget is None else _clean(self.budget.to_dict()),
            "warnings": list(self.warnings),
            **(
                {"steps": None, "linearity": None}
                if self.steps is None
                else _clean(self.steps.to_dict())
            ),
        }
