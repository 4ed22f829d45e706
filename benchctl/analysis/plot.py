"""Figure of one analysis: error PSD with its 95 % band (and Welch), gain, phase, coherence."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchctl.analysis.result import AnalysisResult


def plot_result(result: AnalysisResult, dest: str | Path) -> Path:
    """Draw the four panels into a PNG file ``dest``. matplotlib's object API (a ``Figure``
    with its own canvas): no global backend switch, no pyplot state, safe beside a host
    application's own figures and in threads."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 11), constrained_layout=True)
    axes = fig.subplots(4, 1)
    f = result.psd_freq
    pos = f > 0
    ax = axes[0]
    lo, hi = result.psd_ci95
    floor = max(float(np.max(np.abs(result.psd_error))) * 1e-12, 1e-300)
    ax.fill_between(f[pos], np.maximum(lo[pos], floor), np.maximum(hi[pos], floor),
                    color="tab:blue", alpha=0.25, label="95 % band")
    ax.loglog(f[pos], np.maximum(result.psd_error[pos], floor), color="tab:blue",
              label="eq. 1 (Blackman–Tukey, Parzen)")
    if result.welch_freq is not None and result.welch_error is not None:
        wp = result.welch_freq > 0
        ax.loglog(result.welch_freq[wp], np.maximum(result.welch_error[wp], floor),
                  color="tab:orange", lw=0.8, alpha=0.8, label="Welch")
    lo_s, hi_s = result.sigma_ci95
    title = f"error PSD: σ = {result.sigma:.4g}° (95 %: {lo_s:.4g} … {hi_s:.4g}°)"
    if result.axis:
        title = f"{result.axis}: {title}"
    ax.set_title(title)
    ax.set_ylabel("deg²/Hz")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ff = result.frf_freq
    axes[1].plot(ff, result.frf_gain, ".-")
    axes[1].set_ylabel("gain")
    axes[2].plot(ff, result.frf_phase_deg, ".-")
    axes[2].set_ylabel("phase, deg")
    axes[3].plot(ff, result.frf_coherence, ".-")
    axes[3].set_ylabel("coherence γ²")
    axes[3].set_ylim(0, 1.05)
    axes[3].set_xlabel("frequency, Hz")
    for p in result.periods:
        for a in axes[1:]:
            a.axvline(p["freq"], color="grey", lw=0.5, ls=":")
    for a in axes[1:]:
        a.grid(True, alpha=0.3)
    out = Path(dest)
    fig.savefig(out, dpi=100)
    return out
