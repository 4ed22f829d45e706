"""Statistics of the line view, pure functions on sequences of floats (no I/O, no database):
the individuals and moving-range (I-MR) control chart of σ, its signals, Cpk against the σ
limit, and the yield of a set of verdicts.

The I-MR chart (Montgomery, *Introduction to Statistical Quality Control*, §6.4; NIST/SEMATECH
e-Handbook of Statistical Methods, §6.3.2.2) for individual values x₁ … xₙ (n ≥ 2):

- moving ranges MRᵢ = |xᵢ − xᵢ₋₁| (i = 2 … n), their mean MR̄;
- centre line x̄ (the mean), control limits x̄ ± E₂·MR̄ with E₂ = 3/d₂ = 2.66 (d₂ = 1.128, the
  mean range of two normal values in units of σ): ±3 σ̂ with σ̂ = MR̄/d₂, the short-term
  (within) spread;
- the moving-range chart's upper limit D₄·MR̄ with D₄ = 3.267 (its lower limit is 0).

Signals (Western Electric rules 1 and 4, the latter Nelson's rule 2 with 8 points instead of 9):

- ``beyond``: a point above the upper or below the lower control limit;
- ``run``: a point in a run of ``RUN_LENGTH`` (8) or more consecutive points on the same side of
  the centre line; a point exactly on the centre line ends a run.

Cpk against an upper specification limit only (σ has no lower one):
Cpk = (USL − x̄) / (3·s), s the sample standard deviation (n − 1 in the denominator) of the
same values. It is how many "three standard deviations" fit between the process mean and the
limit: 1.33 or more is the usual target; below 1 the process is expected to put more than
0.135 % of its units above the limit even while nothing is out of control.

>>> lim = imr_limits([1.0, 2.0, 3.0, 4.0, 5.0])
>>> (lim.centre, lim.mr_bar, round(lim.ucl, 2), round(lim.lcl, 2))
(3.0, 1.0, 5.66, 0.34)
>>> round(cpk_upper([1.0, 2.0, 3.0, 4.0, 5.0], 6.0), 4)   # 3 / (3 · √2.5)
0.6325
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from benchctl.errors import InputError

D2 = 1.128  # mean range of two independent normal values, in units of their σ
E2 = 2.66  # individuals chart: x̄ ± E2·MR̄ (= 3/d2, as tabulated)
D4 = 3.267  # moving-range chart: upper limit D4·MR̄
RUN_LENGTH = 8  # Western Electric rule 4: this many in a row on one side of the centre
CPK_TARGET = 1.33  # the usual minimum for a capable process
VERDICTS = ("PASS", "FAIL", "INCONCLUSIVE", "ABORTED")


def _finite(values: Iterable[float], name: str) -> list[float]:
    out = [float(v) for v in values]
    bad = [v for v in out if not math.isfinite(v)]
    if bad:
        raise InputError(f"{name}: {bad[0]!r}: expected finite numbers only")
    return out


@dataclass(frozen=True)
class Limits:
    """The I-MR chart's lines for n individual values."""

    n: int
    centre: float  # x̄
    mr_bar: float  # mean moving range
    ucl: float  # x̄ + E2·MR̄
    lcl: float  # x̄ − E2·MR̄
    mr_ucl: float  # D4·MR̄ (the moving-range chart)

    @property
    def sigma_within(self) -> float:
        """The short-term standard deviation the limits stand for: MR̄/d₂."""
        return self.mr_bar / D2


def moving_ranges(values: Sequence[float]) -> list[float]:
    """|xᵢ − xᵢ₋₁| for i = 2 … n (n − 1 values; none for fewer than two)."""
    xs = _finite(values, "values")
    return [abs(b - a) for a, b in itertools.pairwise(xs)]


def imr_limits(values: Sequence[float]) -> Limits:
    """The I-MR chart's centre and limits of ``values`` (in their order; at least two)."""
    xs = _finite(values, "values")
    if len(xs) < 2:
        raise InputError(f"values: {len(xs)} given: an I-MR chart needs at least 2")
    centre = statistics.fmean(xs)
    mr_bar = statistics.fmean(moving_ranges(xs))
    return Limits(n=len(xs), centre=centre, mr_bar=mr_bar, ucl=centre + E2 * mr_bar,
                  lcl=centre - E2 * mr_bar, mr_ucl=D4 * mr_bar)


def beyond_limits(values: Sequence[float], limits: Limits) -> list[int]:
    """Indices of the points above ``limits.ucl`` or below ``limits.lcl`` (rule 1)."""
    xs = _finite(values, "values")
    return [i for i, x in enumerate(xs) if x > limits.ucl or x < limits.lcl]


def runs_one_side(values: Sequence[float], centre: float,
                  length: int = RUN_LENGTH) -> list[int]:
    """Indices of the points that belong to a run of ``length`` or more consecutive points
    strictly on one side of ``centre`` (rule 4); a point on the centre ends a run."""
    if length < 1:
        raise InputError(f"length = {length}: expected 1 or more")
    xs = _finite(values, "values")
    flagged: list[int] = []
    start, side = 0, 0
    for i, x in enumerate([*xs, centre]):  # the sentinel on the centre closes the last run
        s = (x > centre) - (x < centre)
        if s != side or s == 0:
            if side != 0 and i - start >= length:
                flagged.extend(range(start, i))
            start, side = i, s
    return flagged


def sample_sd(values: Sequence[float]) -> float:
    """The sample standard deviation s (n − 1 in the denominator; at least two values)."""
    xs = _finite(values, "values")
    if len(xs) < 2:
        raise InputError(f"values: {len(xs)} given: a standard deviation needs at least 2")
    return statistics.stdev(xs)


def cpk_upper(values: Sequence[float], usl: float) -> float | None:
    """Cpk against an upper limit only: (USL − x̄)/(3·s). None when it is not defined: fewer
    than two values, or no spread at all (s = 0)."""
    xs = _finite(values, "values")
    (limit,) = _finite([usl], "usl")
    if len(xs) < 2:
        return None
    s = statistics.stdev(xs)
    if s == 0.0:
        return None
    return (limit - statistics.fmean(xs)) / (3.0 * s)


@dataclass(frozen=True)
class ChartStats:
    """One control chart's numbers: its lines, its signals and its capability."""

    limits: Limits | None  # None: fewer than two values
    s: float | None  # the sample standard deviation
    usl: float | None  # the σ limit
    cpk: float | None
    beyond: tuple[int, ...]  # indices (rule 1)
    run: tuple[int, ...]  # indices (rule 4)

    @property
    def signals(self) -> bool:
        return bool(self.beyond or self.run)


def chart_stats(values: Sequence[float], usl: float | None,
                run_length: int = RUN_LENGTH) -> ChartStats:
    """Everything the line view states about one series of σ (oldest first) and its limit
    (None: no limit recorded, no Cpk)."""
    xs = _finite(values, "values")
    if len(xs) < 2:
        return ChartStats(None, None, usl, None, (), ())
    lim = imr_limits(xs)
    return ChartStats(
        limits=lim, s=statistics.stdev(xs), usl=usl,
        cpk=None if usl is None else cpk_upper(xs, usl),
        beyond=tuple(beyond_limits(xs, lim)),
        run=tuple(runs_one_side(xs, lim.centre, run_length)),
    )


@dataclass(frozen=True)
class Tally:
    """Verdicts counted: the yield = PASS / (PASS + FAIL + INCONCLUSIVE) (None when no run
    reached a verdict; aborted runs are counted but reached none) — as the archive's
    ``benchctl history`` counts it."""

    runs: int
    passed: int
    failed: int
    inconclusive: int
    aborted: int

    @property
    def judged(self) -> int:
        return self.passed + self.failed + self.inconclusive

    @property
    def yield_(self) -> float | None:
        return None if self.judged == 0 else self.passed / self.judged


def tally(outcomes: Iterable[str | None]) -> Tally:
    """The verdicts of some runs counted (an unknown outcome counts as a run only)."""
    seen = list(outcomes)
    c = {v: sum(o == v for o in seen) for v in VERDICTS}
    return Tally(runs=len(seen), passed=c["PASS"], failed=c["FAIL"],
                 inconclusive=c["INCONCLUSIVE"], aborted=c["ABORTED"])


__all__ = ["CPK_TARGET", "D2", "D4", "E2", "RUN_LENGTH", "ChartStats", "Limits", "Tally",
           "beyond_limits", "chart_stats", "cpk_upper", "imr_limits", "moving_ranges",
           "runs_one_side", "sample_sd", "tally"]
