"""The spectrum of a measured roll record (the paper's route from a sea trial to the stand).

Pure computation, no I/O: arrays in, a one-sided density out (deg²/Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

_JITTER_TOLERANCE = 1e-3  # relative spread of the sample interval tolerated as "uniform"
MIN_INTERVAL_S = 1e-6  # median sample interval: at most 1 MHz
MAX_GRID_FACTOR = 100  # the resampling grid: at most this many times the samples …
MAX_GRID_SAMPLES = 20_000_000  # … and at most this many


@dataclass(frozen=True)
class RecordedSpectrum:
    """A Welch estimate of a record's one-sided PSD, used as a piecewise-linear target."""

    freq_hz: FloatArray
    density_deg2_hz: FloatArray
    sample_rate_hz: float
    n_samples: int
    duration_s: float
    variance_deg2: float  # of the record about its mean (time domain)
    segment_s: float
    resampled: bool
    source: str = ""
    sha256: str = ""

    def density(self, f_hz: ArrayLike) -> FloatArray:
        """Linear interpolation between the Welch bins, zero outside them, deg²/Hz."""
        f = np.asarray(f_hz, dtype=float)
        return np.asarray(np.interp(f, self.freq_hz, self.density_deg2_hz, left=0.0, right=0.0))

    def to_dict(self) -> dict[str, object]:
        return {
            "source": self.source,
            "sha256": self.sha256,
            "sample_rate_hz": self.sample_rate_hz,
            "n_samples": self.n_samples,
            "duration_s": self.duration_s,
            "variance_deg2": self.variance_deg2,
            "segment_s": self.segment_s,
            "resampled": self.resampled,
        }


def estimate_psd(
    t_s: ArrayLike, angle_deg: ArrayLike, segment_s: float, *, source: str = "", sha256: str = ""
) -> RecordedSpectrum:
    """Welch PSD of a roll record: Hann window, ``segment_s`` segments, 50 % overlap, mean
    removed per segment, scipy's ``density``/``onesided`` scaling (deg²/Hz).

    A record whose sample interval varies by more than 0.1 % is first resampled linearly onto a
    uniform grid at its median interval (``resampled`` says so). ``ValueError`` if the record is
    shorter than two segments or has fewer than 16 samples per segment.

    Parameters
    ----------
    t_s, angle_deg : array_like
        Sample times (s, increasing) and angles (deg).
    segment_s : float
        Welch segment length, s; the frequency resolution is ``1/segment_s`` Hz.
    """
    from scipy import signal  # scipy.signal: about 1 s to import, for a recorded profile only

    t = np.asarray(t_s, dtype=float)
    x = np.asarray(angle_deg, dtype=float)
    if t.size < 32:
        raise ValueError(f"record has {t.size} samples, need at least 32")
    dts = np.diff(t)
    dt = float(np.median(dts))
    if not dt >= MIN_INTERVAL_S:
        raise ValueError(
            f"median sample interval {dt:g} s; expected at least {MIN_INTERVAL_S:g} s"
        )
    with np.errstate(over="ignore", invalid="ignore"):
        steps = (t[-1] - t[0]) / dt
    limit = min(MAX_GRID_FACTOR * t.size, MAX_GRID_SAMPLES)
    if not steps <= limit:
        i = int(np.argmax(dts)) + 1
        raise ValueError(
            f"the record spans {steps:.3g} median intervals ({dt:g} s) for {t.size} samples: "
            f"sample {i + 1} at {float(t[i])!r} s follows {float(t[i - 1])!r} s; expected a span "
            f"of at most {MAX_GRID_FACTOR}× the samples and {MAX_GRID_SAMPLES} intervals"
        )
    resampled = bool(np.max(np.abs(dts - dt)) > _JITTER_TOLERANCE * dt)
    if resampled:
        grid = t[0] + dt * np.arange(math.floor((t[-1] - t[0]) / dt) + 1)
        x = np.interp(grid, t, x)
        t = grid
    fs = 1.0 / dt
    duration = float(t[-1] - t[0] + dt)
    nperseg = round(segment_s * fs)
    if nperseg < 16:
        raise ValueError(
            f"segment_s = {segment_s} s holds {nperseg} samples at {fs:g} Hz, need >= 16"
        )
    if 2 * nperseg > x.size:
        raise ValueError(
            f"record of {duration:g} s is shorter than two segments of segment_s = {segment_s:g} s"
        )
    with np.errstate(over="ignore", invalid="ignore"):
        var_ok = bool(np.isfinite(np.var(x)))
    if not var_ok:
        raise ValueError("the angles are too large for a spectrum (their variance overflows)")
    f, g = signal.welch(
        x,
        fs=fs,
        window="hann",
        nperseg=nperseg,
        noverlap=nperseg // 2,
        detrend="constant",
        scaling="density",
        return_onesided=True,
    )
    return RecordedSpectrum(
        np.asarray(f, dtype=float),
        np.asarray(g, dtype=float),
        fs,
        int(x.size),
        duration,
        float(np.var(x)),
        float(segment_s),
        resampled,
        source,
        sha256,
    )
