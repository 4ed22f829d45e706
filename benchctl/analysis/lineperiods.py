"""Gain, phase and coherence at given periods (the traditional table) from the line-wise
estimate: at an excited line, or interpolated between two neighbouring ones with the
interpolation's error bound in the interval; a period with no reliable line near it is not
excited."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from benchctl.analysis.frf import not_excited
from benchctl.analysis.linewise import LineAnalysis, t975

PERIOD_ON_LINE = 0.01  # a traditional period "on" a line: within this share of the line
# spacing (the period refined from the record differs from the profile's by a few ppm)
PERIOD_NEAR = 0.2  # interpolation: both neighbouring lines within 20 % of the frequency


def periods_from_lines(
    la: LineAnalysis, periods_s: tuple[float, ...]
) -> list[dict[str, Any]]:
    """Gain, phase and coherence with 95 % intervals at the given periods, from the lines.

    A period is *excited* when its frequency f is an excited line (within ``PERIOD_ON_LINE`` of
    the line spacing 1/T_p), or lies between two excited lines that are consecutive harmonics k,
    k+1 of ``T_p`` and each within ``PERIOD_NEAR`` (20 %) of f. Between two lines H is
    interpolated linearly (complex, weight a of the upper line); its noise adds as ``(1−a)² var
    H_k + a² var H_{k+1}``, and the interpolation error, bounded by ``a(1−a)/2 · |Δ²H|`` (the
    largest second difference of H over the neighbouring lines; the first difference when there
    are only the two), is added to the half-widths. Otherwise ``excited`` is false and gain,
    phase, coherence and intervals are None.
    """
    k = la.lines.harmonics
    tp = la.lines.period_s
    reliable = la.reliable if la.reliable.size == len(k) else np.ones(len(k), dtype=bool)
    index = {int(v): i for i, v in enumerate(k) if reliable[i]}
    weak = {int(v): i for i, v in enumerate(k) if not reliable[i]}
    cvar = 2.0 * la.noise / la.ref_amplitude**2  # complex variance of each H_k
    out: list[dict[str, Any]] = []
    for period in periods_s:
        f = 1.0 / period
        kf = f * tp
        kr = round(kf)
        if abs(kf - kr) <= PERIOD_ON_LINE and kr in index:
            i = index[kr]
            out.append(_period_entry(period, "line", la.h[i], cvar[i], la.noise_dof[i],
                                     la.coherence[i], 0.0))
            continue
        ka = math.floor(kf)
        if ka in index and ka + 1 in index:
            fa, fb = ka / tp, (ka + 1) / tp
            if (f - fa) <= PERIOD_NEAR * f and (fb - f) <= PERIOD_NEAR * f:
                i, j = index[ka], index[ka + 1]
                a = kf - ka
                h = (1 - a) * la.h[i] + a * la.h[j]
                var = (1 - a) ** 2 * cvar[i] + a**2 * cvar[j]
                d2 = [
                    abs(la.h[m + 1] - 2 * la.h[m] + la.h[m - 1])
                    for m in (i, j)
                    if 0 < m < len(k) - 1 and k[m + 1] - k[m - 1] == 2
                ]
                curv = max(d2) if d2 else abs(la.h[j] - la.h[i])
                coh = (1 - a) * la.coherence[i] + a * la.coherence[j]
                out.append(_period_entry(period, "interpolated", h, var,
                                         min(la.noise_dof[i], la.noise_dof[j]), coh,
                                         a * (1 - a) / 2 * curv))
                continue
        entry = not_excited(period)
        if abs(kf - kr) <= PERIOD_ON_LINE and kr in weak:
            i = weak[kr]
            entry["snr"] = float(la.snr[i])
            entry["note"] = (f"the line at {f:.4g} Hz has SNR {la.snr[i]:.3g}, below "
                             f"{la.snr_floor:g}: not measured reliably")
        out.append(entry)
    return out


def _period_entry(
    period: float, source: str, h: complex, cvar: float, dof: float, coh: float, bound: float
) -> dict[str, Any]:
    t = float(t975(np.array([dof]))[0])
    g = abs(h)
    ph = math.degrees(math.atan2(h.imag, h.real))
    sd = math.sqrt(cvar / 2.0)
    hg = t * sd + bound
    hp = math.degrees(min((t * sd + bound) / max(g, 1e-300), math.pi))
    return {
        "period_s": period,
        "freq": 1.0 / period,
        "excited": True,
        "gain": g,
        "gain_ci95": [g - hg, g + hg],
        "phase_deg": ph,
        "phase_ci95_deg": [ph - hp, ph + hp],
        "coherence": float(coh),
        "source": source,
    }
