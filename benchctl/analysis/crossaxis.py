"""Cross-axis response from one two-axis run: one axis's output to the other axis's motion.

Pure computation. When the profile moves roll and pitch on **disjoint** lines (a profile's
``multisine: {interleave_axes: true}``), the instrument's output ``y_a`` of axis a is fitted
(least squares, :func:`benchctl.analysis.linefit.fit_lines`) at every excited line of both
axes together with both references ``x_a`` and ``x_b`` on the instrument's own grid. At a
line k of axis b:

    Y_a,k = H_aa(f_k)·X_a,k + C_ab(f_k)·X_b,k + N_k

(``X_a,k`` is the stand's own small motion of axis a there, usually ≈ 0). ``H_aa`` at b's
lines is interpolated (complex, linear in f) from a's own lines, ``H_aa = Y_a/X_a``. The
cross-axis response is reported relative to the axis's own response, ``C_ab = K_ab·H_aa``:
for a misaligned sensing axis ``K_ab`` is the coupling coefficient itself (the fraction of
b's angle a reads), whatever the dynamics. It is fitted by least squares over b's
lines, ``r_k = K·z_k + N_k`` with ``z_k = Ĥ_aa X_b,k``, ``r_k = Y_a,k − Ĥ_aa X_a,k``:
``K̂ = Σ z̄ r / Σ |z|²``, ``var Re K̂ = var Im K̂ = Σ |z|² s / (Σ |z|²)²`` with ``s_k`` the
noise power at the line (``E|N_k|²/2``, from the unexcited bins nearby or the local polynomial
method, as for the line-wise estimate; not used as weights, whose own estimation error would
narrow the interval). The 95 % intervals
use Student's t with Satterthwaite's degrees of freedom of that variance. ``coefficient`` is
``Re K̂`` (signed: the in-phase coupling), ``quadrature`` ``Im K̂`` (≈ 0 for a coupling that
shares the axis's dynamics). Per line, the cross gain ``|C_ab| = |r_k / X_b,k|`` and its
phase are given too.

With shared lines the two inputs cannot be told apart at a line: no estimate (a reason).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import stdtrit

from benchctl.analysis.align import align
from benchctl.analysis.linefit import fit_lines, grid_offsets, refine_period
from benchctl.analysis.linenoise import line_noise
from benchctl.analysis.lines import (
    LinesError,
    LineSet,
    whole_periods,
)
from benchctl.analysis.timebase import label_of
from benchctl.errors import DataError

FloatArray = NDArray[np.float64]


def cross_axis_response(
    t_dev: FloatArray,
    y_dev: FloatArray,
    own_ref: tuple[FloatArray, FloatArray],
    other_ref: tuple[FloatArray, FloatArray],
    own_lines: LineSet,
    other_lines: LineSet,
    *,
    axis: str,
    other_axis: str,
) -> tuple[dict[str, Any] | None, str | None]:
    """The response of ``axis``'s output to ``other_axis``'s motion (module notes).

    Parameters
    ----------
    t_dev, y_dev : ndarray
        The instrument's instants (s) and output of ``axis`` (deg).
    own_ref, other_ref : (ndarray, ndarray)
        The stand's instants and measured angle of ``axis`` and of ``other_axis``.
    own_lines, other_lines : LineSet
        The lines each axis's motion excites (one period, e.g. from the profile).

    Returns
    -------
    (dict, None) or (None, reason)
        ``input_axis``, ``output_axis``, ``coefficient`` and ``coefficient_ci95``,
        ``quadrature`` and ``quadrature_ci95``, ``magnitude`` (``|K̂|``), ``dof``, ``n_lines``,
        per line ``freq``, ``gain``, ``phase_deg``; ``definition``.
    """
    own_k, oth_k = own_lines.harmonics, other_lines.harmonics
    if abs(own_lines.period_s - other_lines.period_s) > 1e-9 * own_lines.period_s:
        return None, "the axes' motions have different periods"
    if np.intersect1d(own_k, oth_k).size:
        return None, (f"{axis} and {other_axis} share lines: the two inputs cannot be told "
                      "apart at a line (give the profile multisine: {interleave_axes: true})")
    try:
        td, yd = np.asarray(t_dev, dtype=float), np.asarray(y_dev, dtype=float)
        a1 = align(own_ref[0], own_ref[1], td, yd,
                   labels=(label_of(own_ref[0]), label_of(t_dev)))
        a2 = align(other_ref[0], other_ref[1], td, yd,
                   labels=(label_of(other_ref[0]), label_of(t_dev)))
        if len(a1.mask) != len(a2.mask) or a1.dt != a2.dt:
            return None, "the two references do not give one grid"
        mask = a1.mask & a2.mask
        union = np.union1d(own_k, oth_k).astype(np.int64)
        n = len(mask)
        whole_periods(n, a1.dt, LineSet(own_lines.period_s, union, own_lines.source))
        offsets = None if a1.t is None else grid_offsets(a1.t, mask, a1.dt)
        # the period as the stand played it (its own clock is some ppm off the nominal)
        refined, _ = refine_period(a1.x, mask, a1.dt,
                                   LineSet(own_lines.period_s, own_k, "profile"), offsets)
        lines = LineSet(refined.period_s, union, own_lines.source)
        whole_periods(n, a1.dt, lines)
        fit = fit_lines(np.vstack((a1.x, a2.x, a1.y)), mask, a1.dt, lines.period_s, union,
                        offsets)
    except (DataError, LinesError) as e:
        return None, f"no cross-axis estimate: {e}"
    idx_own = np.searchsorted(union, own_k)
    idx_oth = np.searchsorted(union, oth_k)
    f = union / lines.period_s
    cxa, cxb, cy = fit.coef[0], fit.coef[1], fit.coef[2]
    h_own = cy[idx_own] / cxa[idx_own]
    fo = f[idx_oth]
    h_at = (np.interp(fo, f[idx_own], h_own.real) + 1j * np.interp(fo, f[idx_own], h_own.imag))
    z = h_at * cxb[idx_oth]
    r = cy[idx_oth] - h_at * cxa[idx_oth]
    n_valid = int(mask.sum())
    spec = fit.spectrum[2]
    u = 2.0 * (spec.real**2 + spec.imag**2) / float(n_valid) ** 2
    nb = len(u)
    bins = np.rint(union * (n * a1.dt / lines.period_s)).astype(np.int64)
    probe = np.ones(nb, dtype=bool)
    probe[0] = False
    if n % 2 == 0:
        probe[-1] = False
    probe[bins] = False
    try:
        noise = line_noise(r, z, fo, bins[idx_oth], u, probe)
    except LinesError as e:
        return None, f"no cross-axis estimate: {e}"
    s = noise.power
    c = np.abs(z) ** 2
    info = float(np.sum(c))
    k_hat = complex(np.sum(np.conj(z) * r) / info)
    cs = c * s
    sd = math.sqrt(float(np.sum(cs))) / info
    dof = float(np.sum(cs)) ** 2 / max(float(np.sum(cs**2 / noise.dof)), 1e-300)
    t = float(stdtrit(dof, 0.975))
    gain = np.abs(r / cxb[idx_oth])
    phase = np.degrees(np.angle(r / cxb[idx_oth]))
    return {
        "input_axis": other_axis,
        "output_axis": axis,
        "coefficient": k_hat.real,
        "coefficient_ci95": [k_hat.real - t * sd, k_hat.real + t * sd],
        "quadrature": k_hat.imag,
        "quadrature_ci95": [k_hat.imag - t * sd, k_hat.imag + t * sd],
        "magnitude": abs(k_hat),
        "dof": dof,
        "n_lines": int(oth_k.size),
        "freq": fo.tolist(),
        "gain": gain.tolist(),
        "phase_deg": phase.tolist(),
        "definition": (
            f"{axis} output per {other_axis} angle, relative to the {axis} axis's own response "
            f"(C = K·H_{axis}); coefficient = Re K, quadrature = Im K"
        ),
    }, None


def cross_axis_for(
    pairs: dict[str, tuple[FloatArray, FloatArray, FloatArray, FloatArray]],
    lines: dict[str, LineSet],
    axis: str,
) -> tuple[dict[str, Any] | None, str | None]:
    """The cross-axis response into ``axis`` from the one other axis of a two-axis record:
    ``pairs[a] = (t_ref, x_ref, t_dev, y_dev)`` per axis (as ``Recording.pair`` gives),
    ``lines[a]`` each axis's lines. ``(None, None)`` for a one-axis record."""
    others = [a for a in pairs if a != axis]
    if not others or axis not in pairs:
        return None, None
    other = others[0]
    if axis not in lines or other not in lines:
        return None, "no cross-axis estimate: the axes' lines are not known"
    tr, xr, td, yd = pairs[axis]
    to, xo = pairs[other][0], pairs[other][1]
    return cross_axis_response(td, yd, (tr, xr), (to, xo), lines[axis], lines[other],
                               axis=axis, other_axis=other)

