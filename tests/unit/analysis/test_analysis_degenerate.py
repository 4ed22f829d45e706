"""Degenerate inputs: an error of exactly zero, constant signals, too few samples, a record
just short of whole periods — a right answer, or exit 2 with a clear message, never an
unexpected error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchctl.analysis import analyze
from benchctl.cli import main
from benchctl.errors import DataError

FS, TP = 100.0, 20.0


def multisine(n: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) / FS
    rng = np.random.default_rng(0)
    k = np.arange(1, 15)
    ph = rng.uniform(0.0, 2 * np.pi, k.size)
    return t, np.cos(2 * np.pi * np.outer(t, k) / TP + ph).sum(axis=1)


def write_csv(path: Path, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> Path:
    with path.open("w") as f:
        f.write("time,reference,device\n")
        for a, b, c in zip(t, x, y, strict=True):
            f.write(f"{a:.6f},{b:.9f},{c:.9f}\n")
    return path


def test_an_error_of_exactly_zero(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """It raised ZeroDivisionError (the timing share of a σ² of 0)."""
    t, x = multisine(round(3 * TP * FS))
    r = analyze(t, x, t, x, period_s=TP)
    assert r.sigma == 0.0 and tuple(r.sigma_ci95) == (0.0, 0.0)
    assert not any("timing" in w for w in r.warnings)
    assert main(["analyze", str(write_csv(tmp_path / "z.csv", t, x, x)), "--json"]) == 0
    assert '"sigma": 0.0' in capsys.readouterr().out


def test_constant_signals_and_too_few_samples(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    t, x = multisine(600)
    ones = np.ones_like(t)
    cases = [
        (ones, ones, "reference angle: the signal is constant (1.0 deg); nothing to analyse"),
        (x, np.full_like(t, 2.5), "device angle: the signal is constant (2.5 deg)"),
    ]
    for xr, yd, msg in cases:
        path = write_csv(tmp_path / "c.csv", t, xr, yd)
        assert main(["analyze", str(path)]) == 2
        assert msg in capsys.readouterr().err
    for n, msg in ((2, "2 samples, at least 64 are needed"), (1, "1 sample, at least 64")):
        path = write_csv(tmp_path / "few.csv", t[:n], x[:n], x[:n])
        assert main(["analyze", str(path)]) == 2
        assert msg in capsys.readouterr().err
    with pytest.raises(DataError, match="2 samples"):
        analyze(t[:2], x[:2], t[:2], x[:2])


def test_a_record_just_short_of_whole_periods_uses_the_whole_periods_it_has() -> None:
    """2.91 periods of 20 s: the line-wise estimate over the first 2, said so; σ and its
    interval are exactly those of the record cut to those 2 periods."""
    n = round(2.91 * TP * FS)
    t, x = multisine(n)
    rng = np.random.default_rng(4)
    y = 0.98 * x + rng.normal(0.0, 0.01, n)
    r = analyze(t, x, t, y, period_s=TP)
    assert r.lines is not None and r.lines.n_periods == 2
    assert any("holds 2.91 periods of 20 s: the line-wise estimate is made over its first 2 "
               "whole periods (40 s), the last 18.2 s left out of it" in w for w in r.warnings)
    m = round(2 * TP * FS)
    cut = analyze(t[:m], x[:m], t[:m], y[:m], period_s=TP)
    assert cut.lines is not None
    assert r.lines.sigma == pytest.approx(cut.lines.sigma, rel=1e-12)
    assert r.sigma_ci95 == pytest.approx(cut.sigma_ci95, rel=1e-12)
    assert r.sigma == pytest.approx(cut.sigma, rel=1e-9)
    # under one period: no line-wise estimate, and why
    short = analyze(t[: round(0.8 * TP * FS)], x[: round(0.8 * TP * FS)],
                    t[: round(0.8 * TP * FS)], y[: round(0.8 * TP * FS)], period_s=TP)
    assert short.lines is None
    assert any("no line-wise estimate" in w for w in short.warnings)
