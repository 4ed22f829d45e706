"""Figure of one analysis: error PSD with its 95 % band (and Welch), gain, phase, coherence."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from benchctl.analysis.result import AnalysisResult
from benchctl.text import visible


def plot_result(result: AnalysisResult, dest: str | Path, *, serial: str | None = None,
                date: str | None = None, limit_deg: float | None = None) -> Path:
    """Draw the four panels into a PNG file ``dest``. matplotlib's object API (a ``Figure``
    with its own canvas): no global backend switch, no pyplot state, safe beside a host
    application's own figures and in threads.

    Every panel has its frequency axis labelled; the gain panel its gain = 1 reference; the
    gain table's periods are marked (dotted, in the legend); with ``limit_deg`` the PSD panel
    shows σ accumulated over frequency against the limit; ``serial`` and ``date`` go into the
    figure's title."""
    # matplotlib: about 0.5 s to import, needed only when a figure is drawn
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 11))
    head = " — ".join(p for p in (f"serial {serial}" if serial else "", date or "") if p)
    if head:  # as typed: no mathtext ($…$ in a serial), control characters shown as escapes
        fig.suptitle(visible(head), parse_math=False)
    # fixed margins (inches on the 8 × 11 in page): a layout engine measuring every tick label
    # would take 40 % of the drawing for the same result; room on the right for the PSD
    # panel's second axis, between panels for an x label
    fig.subplots_adjust(left=0.9 / 8, right=1 - 0.75 / 8, bottom=0.55 / 11, top=1 - 0.75 / 11,
                        hspace=0.62 / ((11 - 0.75 - 0.55 - 3 * 0.62) / 4))
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
    if limit_deg is not None:
        title += f", limit {limit_deg:g}°"
    ax.set_title(title)
    ax.set_ylabel("deg²/Hz")
    ax.grid(True, which="both", alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    if limit_deg is not None:  # σ accumulated over frequency, against the limit
        s = np.where(np.isfinite(result.psd_error), result.psd_error, 0.0)
        cum = np.sqrt(np.maximum(np.cumsum(s * np.gradient(f)), 0.0))
        ax2 = ax.twinx()
        ax2.plot(f[pos], cum[pos], color="tab:red", lw=1.0, label="cumulative σ")
        ax2.axhline(limit_deg, color="tab:red", ls="--", lw=1.0, label=f"limit {limit_deg:g}°")
        ax2.set_ylim(0, 1.15 * max(limit_deg, float(np.max(cum)) if cum.size else 0.0))
        ax2.set_ylabel("cumulative σ, deg")
        h2, l2 = ax2.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    ax.legend(handles, labels, loc="best", fontsize=8)
    # lines below the SNR floor are not drawn: their noise-made gains would set the scale
    ok = (np.ones(len(result.frf_freq), dtype=bool) if result.frf_reliable is None
          else np.asarray(result.frf_reliable, dtype=bool))
    ff = result.frf_freq[ok]
    axes[1].axhline(1.0, color="black", lw=0.8, label="gain = 1")
    axes[1].plot(ff, result.frf_gain[ok], ".-", label="gain" + (
        f" ({int((~ok).sum())} lines below the SNR floor not drawn)" if not ok.all() else ""))
    axes[1].set_ylabel("gain")
    axes[2].plot(ff, result.frf_phase_deg[ok], ".-")
    axes[2].set_ylabel("phase, deg")
    axes[3].plot(ff, result.frf_coherence[ok], ".-")
    axes[3].set_ylabel("coherence γ²")
    axes[3].set_ylim(0, 1.05)
    for i, p in enumerate(result.periods):
        for a in axes[1:]:
            a.axvline(p["freq"], color="grey", lw=0.7, ls=":",
                      label="gain-table periods (" + ", ".join(
                          f"{q['period_s']:g}" for q in result.periods) + " s)"
                      if i == 0 else None)
    for a in axes:
        a.set_xlabel("frequency, Hz")
    for a in axes[1:]:
        a.grid(True, alpha=0.3)
        if a.get_legend_handles_labels()[0]:
            a.legend(loc="best", fontsize=8)
    out = Path(dest)
    fig.savefig(out, dpi=100)
    return out
