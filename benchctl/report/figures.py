"""The report's figures as inline SVG, drawn from the JSON forms the run keeps (``report.json``'s
analysis per axis, its excitation block) and from the recording (the time-trace excerpt).

matplotlib's object API only: a ``Figure`` with its own SVG canvas, saved into a string — no
pyplot, no global backend switch, safe beside a host application's figures and in threads.
Each function returns the ``<svg …>…</svg>`` element (no XML prolog, no metadata block), or
None when its data is not there.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.uncertainty import density_interval

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

FloatArray = NDArray[np.float64]

_PROLOG = re.compile(r"^.*?(?=<svg\b)", re.S)
_METADATA = re.compile(r"<metadata>.*?</metadata>\s*", re.S)
MAX_POINTS = 1500  # a trace is thinned to about this many points per line (file size)
# the report's figures are drawn at the size they are printed: half the A4 text width (two
# side by side), their text in points as it will be read on paper
FIG_W = 3.6  # inches
TITLE_PT, LABEL_PT, TICK_PT, LEGEND_PT = 7.5, 7.0, 6.5, 6.0


# fixed margins, in inches, for the sizes and text sizes above (a layout engine measuring every
# tick label would take 40 % of a report's drawing time for the same result): room for a
# y label and tick labels as wide as "2 × 10⁰" or "−100.0" on the left, a title on top, an
# x label and its tick labels below; between rows, room for an x label (``gap_in``)
LEFT_IN, RIGHT_IN, TOP_IN, BOTTOM_IN = 0.64, 0.1, 0.24, 0.42
GAP_IN, SHARED_GAP_IN = 0.46, 0.14


def _figure(width_in: float, height_in: float, rows: int = 1,
            gap_in: float = GAP_IN) -> tuple[Figure, list[Axes]]:
    # matplotlib: about 0.5 s to import, needed only when a figure is drawn
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width_in, height_in))
    row_in = (height_in - TOP_IN - BOTTOM_IN - gap_in * (rows - 1)) / rows
    fig.subplots_adjust(left=LEFT_IN / width_in, right=1 - RIGHT_IN / width_in,
                        bottom=BOTTOM_IN / height_in, top=1 - TOP_IN / height_in,
                        hspace=gap_in / row_in)
    axes = fig.subplots(rows, 1, squeeze=False)[:, 0]
    return fig, list(axes)


def svg_text(fig: Figure) -> str:
    """``fig`` as an inline ``<svg>`` element (scalable: width 100 % of its box)."""
    from matplotlib.backends.backend_svg import FigureCanvasSVG  # with matplotlib, as above

    FigureCanvasSVG(fig)
    for ax in fig.get_axes():
        ax.tick_params(which="both", labelsize=TICK_PT)
        ax.xaxis.label.set_fontsize(LABEL_PT)
        ax.yaxis.label.set_fontsize(LABEL_PT)
        leg = ax.get_legend()
        if leg is not None:
            for t in leg.get_texts():
                t.set_fontsize(LEGEND_PT)
    buf = io.StringIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    text = _METADATA.sub("", _PROLOG.sub("", buf.getvalue(), count=1))
    # the figure scales with the page (its viewBox keeps the aspect ratio)
    return re.sub(r'<svg([^>]*?) width="[^"]*" height="[^"]*"', r'<svg\1 width="100%"', text,
                  count=1)


def _arr(v: Any) -> FloatArray:
    """A JSON list (None for NaN) as a float array."""
    if v is None:
        return np.zeros(0)
    return np.array([math.nan if x is None else x for x in v], dtype=float)


def _pairs(v: Any, n: int) -> tuple[FloatArray, FloatArray]:
    """A JSON list of [lo, hi] pairs as two arrays (NaN where absent)."""
    lo, hi = np.full(n, math.nan), np.full(n, math.nan)
    if isinstance(v, Sequence):
        for i, p in enumerate(v[:n]):
            if isinstance(p, Sequence) and len(p) == 2:
                lo[i] = math.nan if p[0] is None else float(p[0])
                hi[i] = math.nan if p[1] is None else float(p[1])
    return lo, hi


def _period_marks(axes: Sequence[Axes], periods: Sequence[Mapping[str, Any]]) -> None:
    """The gain table's periods as dotted vertical lines, one legend entry for them."""
    freqs = [float(p["freq"]) for p in periods if p.get("freq")]
    for ax in axes:
        for i, f in enumerate(freqs):
            ax.axvline(f, color="grey", lw=0.7, ls=":",
                       label="gain-table periods" if i == 0 else None)


def psd_figure(analysis: Mapping[str, Any], limit_deg: float | None = None,
               title: str = "") -> Figure | None:
    """The error PSD figure: above, the PSD (eq. 1) with its pointwise 95 % band and the
    analysis band (deg²/Hz, log); below, on its own axis in deg, σ accumulated over frequency
    and the σ limit — the limit is drawn against the axis whose unit it has, never beside a
    density axis it could be read against."""

    psd = analysis.get("psd") or {}
    f, s = _arr(psd.get("freq")), _arr(psd.get("error"))
    if f.size < 2 or f.size != s.size:
        return None
    keep = (f > 0) & np.isfinite(s)
    if keep.sum() < 2:
        return None
    floor = max(float(np.nanmax(np.abs(s))) * 1e-12, 1e-300)
    fig, (ax, ax2) = _figure(FIG_W, 2.9, 2, SHARED_GAP_IN)
    ax.sharex(ax2)
    dof = psd.get("dof")
    if isinstance(dof, int | float) and dof > 0:
        lo, hi = density_interval(s, float(dof))
        ax.fill_between(f[keep], np.maximum(lo[keep], floor), np.maximum(hi[keep], floor),
                        color="tab:blue", alpha=0.25, label=f"95 % band (ν_f = {dof:.3g})")
    ax.loglog(f[keep], np.maximum(s[keep], floor), color="tab:blue", label="error PSD (eq. 1)")
    band = analysis.get("band")
    if isinstance(band, Mapping) and band.get("lo") is not None and band.get("hi") is not None:
        for a in (ax, ax2):
            a.axvspan(max(float(band["lo"]), float(f[keep][0])), float(band["hi"]),
                      color="tab:green", alpha=0.08,
                      label="analysis band" if a is ax else None)
    ax.set_ylabel("PSD, deg²/Hz")
    ax.grid(True, which="both", alpha=0.3)
    ax.tick_params(labelbottom=False)
    ax.legend(loc="lower left", fontsize=LEGEND_PT)
    # cumulative σ(f): √∫₀^f S — where the error's variance sits, against the limit
    df = np.gradient(f)
    cum = np.sqrt(np.maximum(np.cumsum(np.where(np.isfinite(s), s, 0.0) * df), 0.0))
    ax2.plot(f[keep], cum[keep], color="tab:red", lw=1.0, label="cumulative σ")
    top = float(np.nanmax(cum[keep])) if np.isfinite(cum[keep]).any() else 0.0
    if limit_deg is not None and math.isfinite(limit_deg):
        ax2.axhline(limit_deg, color="black", ls="--", lw=1.0, label=f"σ limit {limit_deg:g}°")
        top = max(top, limit_deg)
    ax2.set_ylim(0, top * 1.15 if top > 0 else 1.0)
    ax2.set_xscale("log")
    ax2.set_xlabel("frequency, Hz")
    ax2.set_ylabel("cumulative σ, deg")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend(loc="upper left", fontsize=LEGEND_PT)
    if title:
        ax.set_title(title, fontsize=TITLE_PT)
    return fig


def psd_svg(analysis: Mapping[str, Any], limit_deg: float | None = None,
            title: str = "") -> str | None:
    """:func:`psd_figure` as inline SVG (None without a PSD)."""
    fig = psd_figure(analysis, limit_deg, title)
    return None if fig is None else svg_text(fig)


def frf_svg(analysis: Mapping[str, Any], title: str = "") -> str | None:
    """Gain, phase and coherence over frequency, each with its 95 % interval; gain = 1 and
    the gain table's periods marked."""
    frf = analysis.get("frf") or {}
    f = _arr(frf.get("freq"))
    if f.size == 0:
        return None
    gain, phase, coh = _arr(frf.get("gain")), _arr(frf.get("phase_deg")), _arr(
        frf.get("coherence"))
    glo, ghi = _pairs(frf.get("gain_ci95"), f.size)
    plo, phi = _pairs(frf.get("phase_ci95_deg"), f.size)
    # lines below the SNR floor (a profile's band edges, 1e-8° high) read gains up to 1e10:
    # not drawn, or they would set the scale; their count goes into the legend
    rel = frf.get("reliable")
    weak = 0
    if isinstance(rel, Sequence) and len(rel) == f.size:
        keep = np.array([bool(v) for v in rel])
        weak = int((~keep).sum())
        if not keep.any():
            return None
        f, gain, phase, coh = f[keep], gain[keep], phase[keep], coh[keep]
        glo, ghi, plo, phi = glo[keep], ghi[keep], plo[keep], phi[keep]
    fig, (a1, a2, a3) = _figure(FIG_W, 3.4, 3)
    a1.axhline(1.0, color="black", lw=0.8, label="gain = 1")
    a1.fill_between(f, glo, ghi, color="tab:blue", alpha=0.25, label="95 % interval")
    a1.plot(f, gain, ".-", color="tab:blue",
            label="gain" + (f" ({weak} lines below the SNR floor not drawn)" if weak else ""))
    a1.set_ylabel("gain")
    a2.axhline(0.0, color="black", lw=0.8)
    a2.fill_between(f, plo, phi, color="tab:orange", alpha=0.25, label="95 % interval")
    a2.plot(f, phase, ".-", color="tab:orange", label="phase")
    a2.set_ylabel("phase, deg")
    a3.plot(f, coh, ".-", color="tab:green", label="coherence γ²")
    a3.set_ylim(0, 1.05)
    a3.set_ylabel("coherence γ²")
    periods = [p for p in analysis.get("periods") or [] if isinstance(p, Mapping)]
    _period_marks((a1, a2, a3), periods)
    for ax in (a1, a2, a3):
        ax.set_xlabel("frequency, Hz")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=LEGEND_PT)
    if title:
        a1.set_title(title, fontsize=TITLE_PT)
    return svg_text(fig)


def excitation_svg(exc: Mapping[str, Any], title: str = "") -> str | None:
    """The stand's achieved spectrum against the profile's target, band by band (power), and
    each band's error in dB with the alarm and abort tolerance bands."""
    bands = [b for b in exc.get("bands") or [] if isinstance(b, Mapping)]
    if not bands:
        return None
    fc = np.array([float(b.get("centre_hz") or math.nan) for b in bands])
    tgt = np.array([math.nan if b.get("target_power") is None else float(b["target_power"])
                    for b in bands])
    ach = np.array([math.nan if b.get("achieved_power") is None else float(b["achieved_power"])
                    for b in bands])
    err = np.array([math.nan if b.get("error_db") is None else float(b["error_db"])
                    for b in bands])
    elo, ehi = _pairs([b.get("error_ci95_db") for b in bands], len(bands))
    fig, (a1, a2) = _figure(FIG_W, 2.9, 2)
    pos = (tgt > 0) | (ach > 0)
    a1.loglog(fc[pos], np.where(tgt[pos] > 0, tgt[pos], np.nan), "s-", color="black", ms=4,
              lw=0.8, label="target (profile)")
    a1.loglog(fc[pos], np.where(ach[pos] > 0, ach[pos], np.nan), "o", color="tab:blue", ms=4,
              label="achieved (stand)")
    a1.set_ylabel("band power, deg²")
    alarm, abort = exc.get("alarm_db"), exc.get("abort_db")
    if isinstance(abort, int | float):
        a2.axhspan(-abort, abort, color="tab:orange", alpha=0.12, label=f"abort ±{abort:g} dB")
    if isinstance(alarm, int | float):
        a2.axhspan(-alarm, alarm, color="tab:green", alpha=0.18, label=f"alarm ±{alarm:g} dB")
    yerr = np.vstack([np.where(np.isfinite(elo), err - elo, 0.0),
                      np.where(np.isfinite(ehi), ehi - err, 0.0)])
    a2.errorbar(fc, err, yerr=np.abs(yerr), fmt="o", color="tab:blue", ms=4, capsize=2,
                label="achieved − target (95 %)")
    a2.axhline(0.0, color="black", lw=0.8)
    a2.set_xscale("log")
    a2.set_ylabel("error, dB")
    from matplotlib.ticker import FuncFormatter  # with matplotlib, as above

    def _plain(v: float, _pos: int) -> str:  # 0.2, 0.3, 0.5 (not 2×10⁻¹ …: they overlap)
        m = v / 10 ** math.floor(math.log10(v)) if v > 0 else 0.0
        return f"{v:g}" if round(m, 6) in (1.0, 2.0, 3.0, 5.0) else ""

    for ax in (a1, a2):
        ax.xaxis.set_major_formatter(FuncFormatter(_plain))
        ax.xaxis.set_minor_formatter(FuncFormatter(_plain))
    lim = max(float(abort) if isinstance(abort, int | float) else 0.0,
              float(np.nanmax(np.abs(np.concatenate([err, elo, ehi])))) if np.isfinite(
                  np.concatenate([err, elo, ehi])).any() else 0.0, 0.5)
    a2.set_ylim(-1.2 * lim, 1.2 * lim)
    for ax in (a1, a2):
        ax.set_xlabel("frequency, Hz")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="best", fontsize=LEGEND_PT)
    if title:
        a1.set_title(title, fontsize=TITLE_PT)
    return svg_text(fig)


def _thin(t: FloatArray, x: FloatArray, n: int = MAX_POINTS) -> tuple[FloatArray, FloatArray]:
    step = max(1, math.ceil(t.size / n))
    return t[::step], x[::step]


def trace_svg(t_ref: FloatArray, x_ref: FloatArray, t_dev: FloatArray, y_dev: FloatArray,
              t0: float, title: str = "") -> str | None:
    """A time-trace excerpt: the stand's angle and the instrument's, and their difference
    (instrument − stand at the instrument's instants), time from ``t0``."""
    if t_ref.size < 2 or t_dev.size < 2:
        return None
    err = y_dev - np.interp(t_dev, t_ref, x_ref, left=np.nan, right=np.nan)
    fig, (a1, a2) = _figure(FIG_W, 2.9, 2)
    tr, xr = _thin(t_ref - t0, x_ref)
    td, yd = _thin(t_dev - t0, y_dev)
    te, ye = _thin(t_dev - t0, err)
    a1.plot(tr, xr, color="black", lw=1.0, label="stand")
    a1.plot(td, yd, color="tab:blue", lw=0.8, label="instrument")
    a1.set_ylabel("angle, deg")
    a2.plot(te, ye, color="tab:red", lw=0.7, label="instrument − stand")
    a2.set_ylabel("error, deg")
    for ax in (a1, a2):
        ax.set_xlabel("time from the motion's start, s")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=LEGEND_PT)
    if title:
        a1.set_title(title, fontsize=TITLE_PT)
    return svg_text(fig)


__all__ = ["excitation_svg", "frf_svg", "psd_figure", "psd_svg", "svg_text", "trace_svg"]
