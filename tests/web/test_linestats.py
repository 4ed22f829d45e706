"""The line view's statistics against hand-computed values (I-MR limits, Cpk, the two
control-chart rules, the yield) and their invariances (hypothesis, a bounded example count)."""

from __future__ import annotations

import math

import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from benchctl.errors import InputError
from benchctl.web.linestats import (
    D2,
    chart_stats,
    cpk_upper,
    imr_limits,
    moving_ranges,
    runs_one_side,
    sample_sd,
    tally,
)

TOL = 1e-12


def test_imr_limits_of_a_ramp() -> None:
    # 1, 2, 3, 4, 5: x̄ = 3, every moving range 1, so MR̄ = 1 and the limits 3 ± 2.66
    lim = imr_limits([1.0, 2.0, 3.0, 4.0, 5.0])
    assert lim.n == 5
    assert lim.centre == pytest.approx(3.0, abs=TOL)
    assert lim.mr_bar == pytest.approx(1.0, abs=TOL)
    assert lim.ucl == pytest.approx(5.66, abs=TOL)
    assert lim.lcl == pytest.approx(0.34, abs=TOL)
    assert lim.mr_ucl == pytest.approx(3.267, abs=TOL)
    assert lim.sigma_within == pytest.approx(1.0 / 1.128, abs=TOL)


def test_imr_limits_uneven_ranges() -> None:
    # 0.30, 0.34, 0.28, 0.31: MRs 0.04, 0.06, 0.03 → MR̄ = 0.13/3; x̄ = 1.23/4 = 0.3075
    lim = imr_limits([0.30, 0.34, 0.28, 0.31])
    assert moving_ranges([0.30, 0.34, 0.28, 0.31]) == pytest.approx([0.04, 0.06, 0.03], abs=TOL)
    assert lim.centre == pytest.approx(0.3075, abs=TOL)
    assert lim.mr_bar == pytest.approx(0.13 / 3, abs=TOL)
    assert lim.ucl == pytest.approx(0.3075 + 2.66 * 0.13 / 3, abs=TOL)
    assert lim.lcl == pytest.approx(0.3075 - 2.66 * 0.13 / 3, abs=TOL)


def test_cpk_upper_by_hand() -> None:
    # s of 1..5 = √2.5; (6 − 3) / (3 √2.5) = 1/√2.5
    assert sample_sd([1.0, 2.0, 3.0, 4.0, 5.0]) == pytest.approx(math.sqrt(2.5), abs=TOL)
    assert cpk_upper([1.0, 2.0, 3.0, 4.0, 5.0], 6.0) == pytest.approx(1 / math.sqrt(2.5),
                                                                     abs=TOL)
    # σ of 0.2 and 0.3 against 0.4: x̄ = 0.25, s = 0.1/√2 → Cpk = 0.15 / (0.3/√2) = 0.5·√2
    assert cpk_upper([0.2, 0.3], 0.4) == pytest.approx(0.5 * math.sqrt(2), abs=TOL)
    # a mean above the limit: negative
    assert cpk_upper([0.5, 0.7], 0.4) == pytest.approx(-0.2 / (3 * 0.2 / math.sqrt(2)), abs=TOL)
    assert cpk_upper([0.3], 0.4) is None  # one value: no s
    assert cpk_upper([0.3, 0.3, 0.3], 0.4) is None  # no spread: not defined


def test_rule_beyond_limits_flags_the_outlier() -> None:
    xs = [0.30] * 10 + [0.31] * 10
    xs[15] = 0.60
    stats = chart_stats(xs, 0.4)
    assert stats.beyond == (15,)
    assert stats.limits is not None and stats.limits.ucl < 0.60


def test_rule_run_of_eight() -> None:
    c = 0.0
    assert runs_one_side([1.0] * 7, c) == []
    assert runs_one_side([1.0] * 8, c) == list(range(8))
    # 7 above, one on the centre (ends the run), 8 below, 1 above
    xs = [1.0] * 7 + [0.0] + [-1.0] * 8 + [1.0]
    assert runs_one_side(xs, c) == list(range(8, 16))
    # 9 above then 2 below: the nine flagged
    assert runs_one_side([2.0] * 9 + [-1.0, -1.0], c) == list(range(9))
    assert runs_one_side([1.0, -1.0] * 10, c) == []
    assert runs_one_side([1.0, 1.0, 1.0], c, length=3) == [0, 1, 2]


def test_a_drifting_batch_signals_before_it_fails() -> None:
    # a stable batch around 0.28, then a slow drift upwards, still under the 0.40 limit
    stable = [0.28, 0.29, 0.27, 0.28, 0.30, 0.27, 0.29, 0.28, 0.27, 0.29, 0.28, 0.30]
    drift = [0.31, 0.32, 0.32, 0.33, 0.33, 0.34, 0.34, 0.35]
    stats = chart_stats(stable + drift, 0.40)
    assert max(stable + drift) < 0.40  # nothing failed
    # the shift of the mean shows as a run under the centre before it and the 8 drifting
    # points above it after it
    assert stats.run == tuple(range(20))
    assert stats.beyond and set(stats.beyond) <= set(range(12, 20))  # the latest drifted out
    assert stats.limits is not None and all(x > stats.limits.centre for x in drift)
    assert stats.cpk is not None and stats.cpk < 1.33


def test_too_few_points_and_bad_values() -> None:
    s = chart_stats([0.3], 0.4)
    assert s.limits is None and s.cpk is None and s.beyond == () and s.run == ()
    assert chart_stats([], None).limits is None
    with pytest.raises(InputError, match="at least 2"):
        imr_limits([0.3])
    with pytest.raises(InputError, match="finite"):
        chart_stats([0.3, math.nan], 0.4)
    with pytest.raises(InputError, match="finite"):
        cpk_upper([0.3, 0.2], math.inf)


def test_tally_yield() -> None:
    t = tally(["PASS", "PASS", "FAIL", "INCONCLUSIVE", "ABORTED", None])
    assert (t.runs, t.passed, t.failed, t.inconclusive, t.aborted) == (6, 2, 1, 1, 1)
    assert t.yield_ == pytest.approx(0.5, abs=TOL)
    assert tally(["ABORTED"]).yield_ is None
    assert tally([]).yield_ is None


values = st.lists(st.integers(min_value=0, max_value=4000).map(lambda i: i / 4000.0),
                  min_size=3, max_size=40)


def _near_a_line(xs: list[float], lines: list[float], tol: float = 1e-9) -> bool:
    return any(abs(x - line) < tol for x in xs for line in lines)


@settings(max_examples=200)
@given(xs=values, usl=st.floats(0.0, 2.0), shift=st.floats(-5.0, 5.0))
def test_shifting_values_and_limit_together_changes_no_verdict(xs: list[float], usl: float,
                                                               shift: float) -> None:
    a = chart_stats(xs, usl)
    assert a.limits is not None
    assume(not _near_a_line(xs, [a.limits.centre, a.limits.ucl, a.limits.lcl]))
    b = chart_stats([x + shift for x in xs], usl + shift)
    assert b.limits is not None
    assert b.limits.centre == pytest.approx(a.limits.centre + shift, abs=1e-9)
    assert b.limits.ucl == pytest.approx(a.limits.ucl + shift, abs=1e-9)
    assert b.limits.mr_bar == pytest.approx(a.limits.mr_bar, abs=1e-9)
    assert b.beyond == a.beyond and b.run == a.run
    if a.cpk is None:
        assume(b.cpk is not None)  # s = 0 before the shift may round to a tiny s after it
    else:
        assert b.cpk is not None
        assert b.cpk == pytest.approx(a.cpk, rel=1e-6, abs=1e-6)


@settings(max_examples=200)
@given(xs=values, usl=st.floats(0.0, 2.0), scale=st.floats(0.01, 100.0))
def test_scaling_values_and_limit_keeps_cpk(xs: list[float], usl: float, scale: float) -> None:
    a = chart_stats(xs, usl)
    b = chart_stats([scale * x for x in xs], scale * usl)
    assert a.limits is not None and b.limits is not None
    assert b.limits.ucl == pytest.approx(scale * a.limits.ucl, rel=1e-9, abs=1e-12)
    if a.cpk is not None and b.cpk is not None:
        assert b.cpk == pytest.approx(a.cpk, rel=1e-6, abs=1e-9)


@settings(max_examples=200)
@given(xs=values, usl=st.floats(0.0, 2.0), data=st.data())
def test_order(xs: list[float], usl: float, data: st.DataObject) -> None:
    """Cpk and the centre ignore the order; MR̄ (so the limits) does not, but is the same
    read backwards; the run rule read backwards flags the same points."""
    a = chart_stats(xs, usl)
    perm = data.draw(st.permutations(xs))
    b = chart_stats(perm, usl)
    r = chart_stats(xs[::-1], usl)
    assert a.limits is not None and b.limits is not None and r.limits is not None
    assert b.limits.centre == pytest.approx(a.limits.centre, abs=1e-12)
    assert (a.cpk is None) == (b.cpk is None)
    if a.cpk is not None and b.cpk is not None:
        assert b.cpk == pytest.approx(a.cpk, rel=1e-9, abs=1e-9)
    assert r.limits.mr_bar == pytest.approx(a.limits.mr_bar, abs=1e-12)
    n = len(xs)
    assert sorted(n - 1 - i for i in r.run) == list(a.run)


@settings(max_examples=100)
@given(xs=values)
def test_limits_bracket_the_centre_and_sigma_within(xs: list[float]) -> None:
    lim = imr_limits(xs)
    assert lim.lcl <= lim.centre <= lim.ucl
    assert lim.ucl - lim.centre == pytest.approx(3 * lim.mr_bar / D2, rel=1e-3)  # E2 ≈ 3/d2


def _runs_brute(xs: list[float], c: float, length: int) -> list[int]:
    """Every index inside some window of ``length`` points all strictly on one side."""
    flagged: set[int] = set()
    for i in range(len(xs) - length + 1):
        w = xs[i:i + length]
        if all(x > c for x in w) or all(x < c for x in w):
            flagged.update(range(i, i + length))
    return sorted(flagged)


@settings(max_examples=200)
@given(xs=st.lists(st.sampled_from([-1.0, 0.0, 1.0]), max_size=40),
       length=st.integers(1, 10))
def test_run_rule_against_every_window(xs: list[float], length: int) -> None:
    assert runs_one_side(xs, 0.0, length) == _runs_brute(xs, 0.0, length)


def test_the_module_examples() -> None:
    import doctest

    from benchctl.web import linestats

    assert doctest.testmod(linestats).failed == 0
