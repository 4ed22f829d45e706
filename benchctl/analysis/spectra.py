"""The published method's spectra of one aligned record: the correlations R_x, R_y, R_xy, R_yx
to the max lag and, by eq. 2 then eq. 1, the densities G_xx, G_yy, G_xy and the error's
G_εε (Gryazin & Belova 2023, ``docs/method.md``), with the delay read from the
cross-correlation.

Max-lag rule: ``L = ⌊N/10⌋`` samples of the analysis grid (N = grid length, gaps included),
at least ``MIN_LAG``; ``max_lag_s`` overrides it (rounded to samples, at most N/2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis import frf as frf_mod
from benchctl.analysis.align import Aligned
from benchctl.analysis.correlation import Correlations, correlations, demean
from benchctl.analysis.psd import SpectralGrid, auto_spectrum, cross_spectrum, spectral_grid
from benchctl.errors import DataError

FloatArray = NDArray[np.float64]

MIN_LAG = 8


def default_max_lag(n_grid: int) -> int:
    """The max-lag rule: a tenth of the record, at least 8 samples."""
    return max(MIN_LAG, n_grid // 10)


@dataclass(frozen=True)
class Spectra:
    grid: SpectralGrid
    gxx: FloatArray
    gyy: FloatArray
    gxy: NDArray[np.complex128]
    gee: FloatArray
    r0_scale: float
    n_valid: int
    corr: Correlations


def spectra(al: Aligned, max_lag: int) -> Spectra:
    c = correlations(al.x, al.y, al.mask, max_lag)
    grid = spectral_grid(max_lag, al.dt)
    gxx = auto_spectrum(c.rx, grid)
    gyy = auto_spectrum(c.ry, grid)
    gxy = cross_spectrum(c.rxy, c.ryx, grid)
    gee = auto_spectrum(c.error(), grid)  # eq. 2 then eq. 1
    return Spectra(grid, gxx, gyy, gxy, gee, float(c.rx[0] + c.ry[0]), c.n_valid, c)


def delay_estimate(sp: Spectra, al: Aligned) -> float:
    pos = sp.grid.freq > 0
    f_peak = float(sp.grid.freq[pos][np.argmax(sp.gxx[pos])])
    c = sp.corr
    raw = c.pairs * c.n / (c.n - np.arange(c.max_lag + 1))  # undo the estimator's scaling
    x, y = demean(al.x, al.mask), demean(al.y, al.mask)
    return frf_mod.delay_from_correlation(
        c.rxy * raw, c.ryx * raw, x, y, al.mask, al.dt, f_peak
    )


def max_lag_samples(al: Aligned, max_lag_s: float | None) -> int:
    n = len(al.mask)
    if max_lag_s is None:
        lag = default_max_lag(n)
    else:
        if not np.isfinite(max_lag_s) or max_lag_s <= 0:
            raise DataError(f"max lag: expected a positive number of seconds, got {max_lag_s!r}")
        lag = round(max_lag_s / al.dt)
        if lag < MIN_LAG:
            raise DataError(
                f"max lag {max_lag_s:g} s is {lag} samples at {1 / al.dt:.6g} Hz; "
                f"expected at least {MIN_LAG} samples ({MIN_LAG * al.dt:.6g} s)"
            )
    if 2 * lag >= n:
        raise DataError(
            f"record too short: {n} samples ({n * al.dt:.6g} s) for a max lag of {lag} samples "
            f"({lag * al.dt:.6g} s); expected at least {2 * lag + 1} samples"
        )
    return lag
