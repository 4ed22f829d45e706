"""The noise at the excited lines: the power ``s_k = E|N_k|²/2`` a line's coefficient picks up
from the incoherent error, with its degrees of freedom.

From the record's unexcited DFT bins near the line (the residual's periodogram, at least
``NOISE_BINS`` of them within ``±NOISE_REACH`` bins), else — every bin excited, as with one
period per record — from the local polynomial method: the deviation of ``E_j = c^y_j − c^x_j``
from ``P(f_j)·c^x_j`` (P of degree ``LPM_DEGREE``) over the ``LPM_LINES`` nearest other lines
(the line itself left out, so that its noise estimate is independent of its own noise). Step 2
of the line-wise estimate (:mod:`benchctl.analysis.linewise`); also the excitation fidelity's
and the cross-axis estimate's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.lines import LinesError

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

NOISE_BINS = 8  # unexcited DFT bins behind one line's noise estimate …
NOISE_REACH = 16  # … found within ± this many bins of the line
LPM_LINES = 15  # neighbours of a line in its local-polynomial window (degree LPM_DEGREE)
LPM_DEGREE = 2


@dataclass(frozen=True)
class LineNoise:
    power: FloatArray  # s_k: variance a line picks up from the noise, deg²
    dof: FloatArray  # real degrees of freedom of each estimate
    lpm: NDArray[np.bool_]  # True where from the local polynomial method
    var_sum: float  # variance of Σ_k s_k (estimation error)
    #: at a line from the local polynomial method, ``E_k − P(f_k)·c^x_k``: the noise's part of
    #: its coefficient (with the polynomial's own error); 0 at the others
    deviation: ComplexArray | None = None


def _nearest_offsets(reach: int) -> IntArray:
    o = np.arange(-reach, reach + 1)
    return np.asarray(o[np.lexsort((o, np.abs(o)))], dtype=np.int64)  # 0, −1, 1, −2, 2 …


def line_noise(
    e: ComplexArray, cx: ComplexArray, freq: FloatArray, bins: IntArray, u: FloatArray,
    probe: NDArray[np.bool_],
) -> LineNoise:
    """Noise power at each line (see module notes, step 2). ``u``: the residual's periodogram
    in line units (``2|R_j|²/N_v²``); ``probe``: the bins that are neither DC, Nyquist nor a
    line."""
    kk = len(e)
    nb = len(u)
    off = _nearest_offsets(NOISE_REACH)
    idx = bins[:, None] + off[None, :]
    inside = (idx >= 0) & (idx < nb)
    ok = inside & probe[np.clip(idx, 0, nb - 1)]
    rank = np.cumsum(ok, axis=1)
    take = ok & (rank <= NOISE_BINS)
    enough = rank[:, -1] >= NOISE_BINS
    power = np.zeros(kk)
    dof = np.zeros(kk)
    weight = np.zeros(nb)
    if enough.any():
        vals = np.where(take, u[np.clip(idx, 0, nb - 1)], 0.0)
        power[enough] = vals[enough].sum(axis=1) / NOISE_BINS
        dof[enough] = 2.0 * NOISE_BINS
        np.add.at(weight, np.clip(idx, 0, nb - 1)[enough][take[enough]], 1.0 / NOISE_BINS)
    var_sum = float(np.sum(weight**2 * u**2 / 2.0))
    lpm = ~enough
    deviation = np.zeros(kk, dtype=complex)
    if lpm.any():
        size = LPM_LINES + 1  # the line itself and LPM_LINES neighbours
        if kk < size:
            raise LinesError(
                f"too few lines ({kk}) and unexcited bins to estimate the noise at the lines"
            )
        pos = np.flatnonzero(lpm)
        start = np.clip(pos - size // 2, 0, kk - size)
        win = start[:, None] + np.arange(size)[None, :]
        use = (win != pos[:, None]).astype(float)  # leave the line out: its noise estimate is
        d = freq[win] - freq[pos][:, None]  # then independent of its own noise (Student t)
        d = d / np.maximum(np.abs(d).max(axis=1, keepdims=True), 1e-300)
        phi = cx[win][:, :, None] * d[:, :, None] ** np.arange(LPM_DEGREE + 1)[None, None, :]
        phi = phi * use[:, :, None]
        rhs = e[win] * use
        gram = np.einsum("kjp,kjq->kpq", phi.conj(), phi)
        proj = np.einsum("kjp,kj->kp", phi.conj(), rhs)
        theta = np.linalg.solve(gram, proj[:, :, None])[:, :, 0]
        res = rhs - np.einsum("kjp,kp->kj", phi, theta)
        deviation[pos] = e[pos] - cx[pos] * theta[:, 0]  # P(f_k) at the line itself: θ₀
        free = LPM_LINES - (LPM_DEGREE + 1)
        power[pos] = np.sum(np.abs(res) ** 2, axis=1) / (2.0 * free)
        dof[pos] = 2.0 * free
        w = np.zeros(kk)
        np.add.at(w, win.ravel(), use.ravel() / free)
        var_sum += float(np.sum(w**2 * power**2))
    return LineNoise(power, dof, lpm, var_sum, deviation)
