"""σ's uncertainty budget, GUM style: what each source contributes to the uncertainty of the
headline σ, combined, and expanded with k = 2.

Pure computation (no I/O). **The measurand** is the error process's σ (ε = instrument − stand
angle, about its mean); **its estimate is the headline** ``sigma`` of the analysis (eqs. 1–2 of
the method; the budget, the JSON, the report and the record all name this one,
``SIGMA_OF``). The 95 % interval ``sigma_ci95`` is that measurand's interval: it is formed about
``sigma_corrected`` = √(σ² + mean removal), because σ is about the record's own mean, which
takes ``var(ε̄)`` out of σ²; the budget lists that as a *bias* of the headline σ, beside the
timing's.

Every source adds to σ² (or moves it), so most contributions are stated for σ² and carried to σ
by first-order propagation, ``u(σ) = u(σ²)/(2σ)`` (capped at ``√u(σ²)``, the σ that variance
alone would make, which matters only when ``u(σ²) > 4σ²``). The contributions (all in degrees
of σ):

- **finite record and noise** (type A): the statistical interval's half-width ÷ 1.959964 (for
  a scaled χ² of ν degrees of freedom that is ``σ/√(2ν)``), with the interval's ν;
- **timing** (type B): an offset between the streams common to the record and random instant
  errors move σ² by a term of standard deviation ``cross`` (``timing.timing_budget``:
  ``2|cov(ε, ẋ)|·u₀`` and ``2·rms(ε·ẋ)·δ/√N`` in quadrature): ``u = cross/(2σ)``. The
  *variance* random instant errors add (``σ_ẋ²·δ²``) is a bias — σ reads high by about
  ``b/(2σ)`` — listed as such, not combined (the interval's lower end is moved down by it);
- **reference resolution** q (type B, rectangular): the reference's rounding error, uniform on
  ±q/2 and uncorrelated with ε when the motion crosses many steps between samples, adds
  ``q²/12`` to σ². It is not corrected (when the stand moves slowly or holds still the rounding
  is neither uniform nor white), so the whole of it is taken as ``u(σ²)``: ``u = q²/(24σ)``;
- **reference uncertainty** u_enc (type B): an error e of the reference angle enters ε
  directly, ``ε_meas = ε − e``. Uncorrelated with ε it would add ``u_enc²`` to σ² (``u_enc²/(2σ)``,
  negligible); but an encoder's error is mostly systematic — a scale error, an eccentricity —
  and so follows the motion, and with it a lagging instrument's error. Whatever the
  correlation, ``|σ(ε − e) − σ(ε)| ≤ σ(e)`` (Minkowski), so ``u = u_enc`` (the reference's
  error taken as of rms ``u_enc`` over the motion): conservative, first order in ``u_enc``,
  not absurd (a 0.002° reference against a 0.28° σ: 0.7 %);
- **interpolation** of the reference onto the instrument's instants (type B): across the
  reference's bridged gaps the spline misses the motion by an estimated mean square
  ``bridge_variance`` (averaged over all samples; ``align``), which adds to σ²:
  ``u = bridge_variance/(2σ)``; 0 without bridging (between the reference's samples the
  spline of a smooth, oversampled motion errs by far less);
- **non-stationarity** (type A): over one, or six or more, whole periods the error's power
  is tested segment against segment (``stationarity.assess``). Stationary: a contribution of
  0, with the test's figures. Not stationary: the variance the changing power adds to σ̂²,
  ``u = √V/(2σ)`` with the estimate's few degrees of freedom (σ's interval is widened by the
  same term, so the record's term is stated without it). Two to five periods, or no
  line-wise estimate: *not assessed* — a flag, no number, never a zero.

A contribution whose input is not known (the bench config states no encoder resolution or
uncertainty, a CSV carries none) is **not stated**: no number, and the combined uncertainty
says it leaves it out (``complete`` false). The combined standard uncertainty is the root sum
of squares of the evaluated ones, its effective degrees of freedom Welch–Satterthwaite's
``u_c⁴ / Σ u_i⁴/ν_i`` (a type B taken as exact has ν = ∞ and adds nothing to the sum; all
exact: ν_eff = ∞), the coverage factor k = 2 and the expanded uncertainty ``U = k·u_c``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

from benchctl.errors import AnalysisError

SIGMA_OF = "sigma"  # the σ the budget (and sigma_ci95) belongs to: the headline
COVERAGE_FACTOR = 2.0
Z95 = 1.959963984540054

Status = Literal["evaluated", "bias", "not stated", "not assessed"]
EVALUATED: Status = "evaluated"
BIAS: Status = "bias"
NOT_STATED: Status = "not stated"
NOT_ASSESSED: Status = "not assessed"


@dataclass(frozen=True)
class Reference:
    """What the bench config states about the reference angle (deg; None: not stated)."""

    resolution_deg: float | None = None
    uncertainty_deg: float | None = None

    @classmethod
    def of(cls, info: dict[str, Any] | None) -> Reference:
        """From labelled instants' ``info`` (``encoder_resolution_deg``,
        ``encoder_uncertainty_deg``, as a recording's reference carries them)."""
        info = info or {}
        return cls(_stated(info.get("encoder_resolution_deg"), "encoder_resolution_deg"),
                   _stated(info.get("encoder_uncertainty_deg"), "encoder_uncertainty_deg"))


def _stated(v: Any, name: str) -> float | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise AnalysisError(f"{name}: expected a finite number ≥ 0 (deg) or none, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class Contribution:
    """One line of the budget. ``u_deg``: the standard uncertainty it gives the headline σ
    (deg; None unless ``status`` is ``evaluated``); ``u_variance_deg2``: the u(σ²) it was
    propagated from, where it was; ``bias_deg``: for a ``bias`` line, how much σ reads high
    (negative: low); ``dof``: its degrees of freedom (∞: taken as exact)."""

    key: str
    name: str
    gum_type: Literal["A", "B"] | None
    status: Status
    u_deg: float | None
    basis: str
    distribution: str | None = None
    dof: float = math.inf
    u_variance_deg2: float | None = None
    bias_deg: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "name": self.name,
            "type": self.gum_type,
            "status": self.status,
            "u": self.u_deg,
            "u_variance": self.u_variance_deg2,
            "bias": self.bias_deg,
            "distribution": self.distribution,
            "dof": self.dof if math.isfinite(self.dof) else None,
            "dof_infinite": self.status == EVALUATED and not math.isfinite(self.dof),
            "basis": self.basis,
        }


def combined(us: Sequence[float]) -> float:
    """Root sum of squares of standard uncertainties (deg; no underflow or overflow)."""
    return math.hypot(*us)


def effective_dof(us: Sequence[float], dofs: Sequence[float]) -> float:
    """Welch–Satterthwaite: ``u_c⁴ / Σ u_i⁴/ν_i`` (ν = ∞ adds nothing; ∞ when every term is
    exact or u_c is 0). Computed on the u's scaled by the largest, so that no fourth power
    underflows or overflows."""
    if len(us) != len(dofs):
        raise AnalysisError(f"effective_dof: {len(us)} uncertainties but {len(dofs)} dofs")
    top = max(us, default=0.0)
    if not top > 0.0:
        return math.inf
    r = [u / top for u in us]
    den = math.fsum(x**4 / v for x, v in zip(r, dofs, strict=True)
                    if math.isfinite(v) and x > 0.0)
    if den <= 0.0:
        return math.inf
    return combined(r) ** 4 / den


def sigma_u(u_variance: float, sigma: float) -> float:
    """u(σ) from u(σ²), first order: ``u(σ²)/(2σ)``, capped at ``√u(σ²)`` (what that
    variance alone would make of σ; the cap holds only when ``u(σ²) > 4σ²``)."""
    if u_variance <= 0.0:
        return 0.0
    cap = math.sqrt(u_variance)
    return cap if sigma <= 0.0 else min(u_variance / (2.0 * sigma), cap)


@dataclass(frozen=True)
class Budget:
    """The budget of one axis's headline σ (module notes)."""

    sigma_deg: float
    contributions: tuple[Contribution, ...]
    coverage_factor: float = COVERAGE_FACTOR
    sigma_of: str = SIGMA_OF

    @property
    def evaluated(self) -> tuple[Contribution, ...]:
        return tuple(c for c in self.contributions if c.status == EVALUATED)

    @property
    def combined_deg(self) -> float:
        return combined([c.u_deg or 0.0 for c in self.evaluated])

    @property
    def dof_effective(self) -> float:
        ev = self.evaluated
        return effective_dof([c.u_deg or 0.0 for c in ev], [c.dof for c in ev])

    @property
    def expanded_deg(self) -> float:
        return self.coverage_factor * self.combined_deg

    @property
    def bias_deg(self) -> float:
        """The net known bias of the headline σ (deg; positive: σ reads high), not in u_c."""
        return math.fsum(c.bias_deg or 0.0 for c in self.contributions if c.status == BIAS)

    @property
    def left_out(self) -> tuple[Contribution, ...]:
        return tuple(c for c in self.contributions if c.status in (NOT_STATED, NOT_ASSESSED))

    def to_dict(self) -> dict[str, Any]:
        nu = self.dof_effective
        return {
            "sigma_of": self.sigma_of,
            "sigma": self.sigma_deg,
            "interval": "sigma_ci95",
            "contributions": [c.to_dict() for c in self.contributions],
            "combined": self.combined_deg,
            "dof_effective": nu if math.isfinite(nu) else None,
            "coverage_factor": self.coverage_factor,
            "expanded": self.expanded_deg,
            "bias": self.bias_deg,
            "complete": not self.left_out,
            "left_out": [f"{c.name}: {c.status}" for c in self.left_out],
        }


def uncertainty_budget(
    *,
    sigma: float,
    sigma_corrected: float,
    ci_statistical: tuple[float, float],
    dof: float,
    timing_cross_variance: float,
    timing_bias_variance: float,
    bridge_variance: float,
    reference: Reference,
    stationarity: dict[str, Any] | None = None,
    drift: dict[str, Any] | None = None,
) -> Budget:
    """The budget of the headline ``sigma`` (deg; module notes).

    ``sigma_corrected``: σ with the mean removal's loss added back (the interval's centre);
    ``ci_statistical``: σ's 95 % interval from the record's statistics alone (deg), ``dof``
    its ν; ``timing_cross_variance``: the standard deviation of σ² from timing (``cross``, deg²);
    ``timing_bias_variance``: the variance timing adds to σ², the bridged gaps' included
    (deg²); ``bridge_variance``: the bridged gaps' share of it (deg²); ``reference``: the
    reference angle's stated resolution and uncertainty; ``stationarity``: the
    period-to-period test (``Stationarity.to_dict``), None when not made; ``drift``: the
    residual's lowest cosine coefficients (``Drift.to_dict``), None when not fitted — a flagged
    drift is named in the non-stationarity line (its part of σ² is in the record's term).
    """
    for name, v in (("sigma", sigma), ("sigma_corrected", sigma_corrected),
                    ("timing_cross_variance", timing_cross_variance),
                    ("timing_bias_variance", timing_bias_variance),
                    ("bridge_variance", bridge_variance)):
        if not (math.isfinite(v) and v >= 0.0):
            raise AnalysisError(f"uncertainty budget: {name} expected a finite number ≥ 0, "
                                f"got {v!r}")
    lo, hi = float(ci_statistical[0]), float(ci_statistical[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi):
        raise AnalysisError(f"uncertainty budget: ci_statistical expected finite 0 ≤ lo ≤ hi, "
                            f"got {ci_statistical!r}")
    if not dof > 0.0:
        raise AnalysisError(f"uncertainty budget: dof expected > 0, got {dof!r}")
    s = sigma
    out: list[Contribution] = []
    nu = float(dof)
    u_ns = (0.0 if stationarity is None else
            sigma_u(math.sqrt(max(stationarity["added_variance"], 0.0)), s))
    u_rec = math.sqrt(max(((hi - lo) / (2.0 * Z95)) ** 2 - u_ns**2, 0.0))
    out.append(Contribution(
        "record", "finite record and noise", "A", EVALUATED, u_rec,
        f"half the statistical 95 % interval [{lo:.6g}, {hi:.6g}]° ÷ 1.96, ν = {nu:.4g}",
        "scaled χ² (σ² of the record)", nu))
    out.append(Contribution(
        "timing", "timing: offset and random instants", "B", EVALUATED,
        sigma_u(timing_cross_variance, s),
        f"u(σ²) = {timing_cross_variance:.3g} deg² (2|cov(ε, ẋ)|·u₀ ⊕ 2·rms(ε·ẋ)·δ/√N) "
        "÷ 2σ", "normal", math.inf, timing_cross_variance))
    tb = max(timing_bias_variance - bridge_variance, 0.0)
    out.append(Contribution(
        "timing_bias", "timing: random instants' variance", "B", BIAS, None,
        f"σ_ẋ²·δ² = {tb:.3g} deg² adds to σ²: σ reads high by about it ÷ 2σ (the interval's "
        "lower end moved down by it)", None, math.inf, None, sigma_u(tb, s)))
    mr = max(sigma_corrected * sigma_corrected - s * s, 0.0)
    out.append(Contribution(
        "mean_removal", "mean removal", "A", BIAS, None,
        f"var(ε̄) ≈ G(0)/(2T) = {mr:.3g} deg² taken out of σ²: σ reads low by "
        f"{sigma_corrected - s:.3g}° (the interval is about sigma_corrected "
        f"{sigma_corrected:.6g}°)", None, math.inf, None, -(sigma_corrected - s)))
    q = reference.resolution_deg
    if q is None:
        out.append(Contribution(
            "resolution", "reference resolution", "B", NOT_STATED, None,
            "the bench config states no stand.encoder_resolution_deg"))
    else:
        uv = q * q / 12.0
        out.append(Contribution(
            "resolution", "reference resolution", "B", EVALUATED, sigma_u(uv, s),
            f"q = {q:.3g}°: rounding adds q²/12 = {uv:.3g} deg² to σ², taken whole as u(σ²); "
            "÷ 2σ", "rectangular", math.inf, uv))
    ue = reference.uncertainty_deg
    if ue is None:
        out.append(Contribution(
            "reference", "reference uncertainty", "B", NOT_STATED, None,
            "the bench config states no stand.encoder_uncertainty_deg"))
    else:
        out.append(Contribution(
            "reference", "reference uncertainty", "B", EVALUATED, ue,
            f"u_enc = {ue:.3g}°: enters ε directly; |σ(ε − e) − σ(ε)| ≤ σ(e), any correlation",
            "as stated", math.inf))
    out.append(Contribution(
        "interpolation", "reference interpolation", "B",
        EVALUATED, sigma_u(bridge_variance, s),
        ("no bridged reference gap" if bridge_variance == 0.0 else
         f"the spline's estimated mean square miss across bridged gaps {bridge_variance:.3g} "
         "deg² ÷ 2σ"), "normal", math.inf, bridge_variance))
    out.append(_nonstationarity(stationarity, u_ns, drift))
    return Budget(s, tuple(out))


def _nonstationarity(test: dict[str, Any] | None, u: float,
                     drift: dict[str, Any] | None = None) -> Contribution:
    drifts = ""
    if drift is not None and drift["flagged"]:
        drifts = (f"; a DRIFT: the residual's lowest {drift['coefficients']} cosine "
                  f"coefficients fall as k^−{drift['exponent']:g}, its part of σ² (with its own "
                  "few degrees of freedom) in the record's term")
    if test is None:
        return Contribution(
            "nonstationarity", "non-stationarity", None, NOT_ASSESSED, None,
            "power period to period not assessed (a record of two to five whole periods, or "
            "without a line-wise estimate): σ is taken as that of a stationary error over the "
            f"record{drifts}")
    figures = (f"power period to period: χ² {test['statistic']:.4g} on {test['dof']} degrees "
               f"of freedom, p = {test['p_value']:.2g}")
    if test["stationary"]:
        return Contribution(
            "nonstationarity", "non-stationarity", "A", EVALUATED, 0.0,
            f"tested, the power stationary period to period ({figures}){drifts}", "none",
            math.inf)
    nu = float(test["added_dof"])
    return Contribution(
        "nonstationarity", "non-stationarity", "A", EVALUATED, u,
        f"NOT stationary ({figures}): the changing power adds {test['added_variance']:.3g} "
        f"deg⁴ to var(σ̂²) ÷ 2σ; in σ's interval, the record's term stated without it{drifts}",
        "Student's t", nu)


def budget_lines(budget: dict[str, Any] | None, indent: str = "        ") -> list[str]:
    """σ's uncertainty budget as a compact table: each contribution's GUM type, its standard
    uncertainty of σ (°) and ν, or what it is instead (a bias, not stated, not assessed); then
    u_c, ν_eff, k and U, and which σ they belong to."""
    if not budget:
        return []

    def g(v: Any) -> str:
        return "—" if v is None else f"{v:.2g}"

    out = [f"{indent}uncertainty budget of σ ({budget['sigma_of']}, the σ above; GUM, "
           "standard uncertainties of σ in °):"]
    for c in budget["contributions"]:
        name = f"{c['name'][:34]:<34} {c['type'] or '–'}"
        if c["status"] == "evaluated":
            nu = "∞" if c["dof"] is None else f"{c['dof']:.3g}"
            what = f"u {g(c['u']):>8}  ν {nu}"
        elif c["status"] == "bias":
            what = f"bias {c['bias']:+.2g}° (not in u_c)"
        else:
            what = str(c["status"])
        out.append(f"{indent}  {name}  {what}")
    nu = budget["dof_effective"]
    missing = "" if budget["complete"] else "; left out: " + ", ".join(budget["left_out"])
    out.append(f"{indent}  combined u_c {g(budget['combined'])}° (ν_eff "
               f"{'∞' if nu is None else f'{nu:.3g}'}), expanded U = {g(budget['expanded'])}° "
               f"(k = {budget['coverage_factor']:g}){missing}")
    return out


__all__ = ["BIAS", "COVERAGE_FACTOR", "EVALUATED", "NOT_ASSESSED", "NOT_STATED", "SIGMA_OF",
           "Budget", "Contribution", "Reference", "budget_lines", "combined", "effective_dof",
           "sigma_u", "uncertainty_budget"]
