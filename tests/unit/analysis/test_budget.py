"""σ's uncertainty budget (``benchctl.analysis.budget``): the GUM combination on constructed
inputs, the reference's quantisation on an exact synthetic record, what is "not stated" and
"not assessed", and the budget reaching the analysis's JSON from a recording's bench config.

Tolerances:
- closed forms (root sum of squares, k = 2, U, Welch–Satterthwaite, each contribution's
  formula): 1e-12 relative;
- the quantised reference: σ² read high by q²/12 within 4 standard deviations of the
  difference's estimate from the record's statistics — the rounding error e's sample variance
  (sd ``√((q⁴/80 − q⁴/144)/N)``, e uniform on ±q/2) and its cross term with the noise
  (sd ``2·σ_n·(q/√12)/√N``) in quadrature: 17 % of q²/12 for the record below;
- property (50 examples): u_c ≥ every evaluated contribution and U = 2·u_c to 1e-12.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchctl.analysis import AnalysisResult, analyze
from benchctl.analysis.budget import (
    EVALUATED,
    NOT_ASSESSED,
    NOT_STATED,
    SIGMA_OF,
    Budget,
    Contribution,
    Reference,
    combined,
    effective_dof,
    sigma_u,
    uncertainty_budget,
)
from benchctl.cli import main
from benchctl.errors import AnalysisError
from benchctl.outcomes import Outcome
from benchctl.recording import load_recording
from benchctl.recording.format import FORMAT_NAME
from benchctl.results.measurements import Limits, axis_measurements
from benchctl.results.record import build_record, validate_record
from benchctl.run.report import Report, axis_verdict, format_report

Z95 = 1.959963984540054


def _budget(**kw: object) -> Budget:
    args: dict[str, object] = {
        "sigma": 0.25, "sigma_corrected": 0.2501, "ci_statistical": (0.24, 0.26), "dof": 800.0,
        "timing_cross_variance": 4e-5, "timing_bias_variance": 3e-5, "bridge_variance": 1e-5,
        "reference": Reference(0.001, 0.002)}
    args.update(kw)
    return uncertainty_budget(**args)  # type: ignore[arg-type]


def _by_key(b: Budget) -> dict[str, Contribution]:
    return {c.key: c for c in b.contributions}


def test_combination_coverage_and_effective_dof_closed_forms() -> None:
    us, nus = [0.003, 0.004, 0.012], [10.0, math.inf, 40.0]
    uc = 0.013  # 3-4-12-13
    assert combined(us) == pytest.approx(uc, rel=1e-12)
    assert effective_dof(us, nus) == pytest.approx(uc**4 / (0.003**4 / 10 + 0.012**4 / 40),
                                                   rel=1e-12)
    assert effective_dof([0.1, 0.2], [math.inf, math.inf]) == math.inf
    assert effective_dof([0.0, 0.0], [5.0, 5.0]) == math.inf
    with pytest.raises(AnalysisError, match="2 uncertainties but 1 dofs"):
        effective_dof([0.1, 0.2], [3.0])


def test_each_contribution_is_its_closed_form() -> None:
    s, lo, hi = 0.25, 0.24, 0.26
    b = _budget()
    c = _by_key(b)
    assert [x.key for x in b.contributions] == [
        "record", "timing", "timing_bias", "mean_removal", "resolution", "reference",
        "interpolation", "nonstationarity"]
    assert c["record"].u_deg == pytest.approx((hi - lo) / (2 * Z95), rel=1e-12)
    assert c["record"].gum_type == "A" and c["record"].dof == 800.0
    assert c["timing"].u_deg == pytest.approx(4e-5 / (2 * s), rel=1e-12)
    assert c["timing_bias"].u_deg is None  # a bias, as it is: not combined
    assert c["timing_bias"].bias_deg == pytest.approx((3e-5 - 1e-5) / (2 * s), rel=1e-12)
    assert c["mean_removal"].bias_deg == pytest.approx(-(0.2501 - s), rel=1e-12)
    assert c["resolution"].u_deg == pytest.approx(0.001**2 / (24 * s), rel=1e-12)
    assert c["resolution"].u_variance_deg2 == pytest.approx(0.001**2 / 12, rel=1e-12)
    assert c["reference"].u_deg == 0.002  # enters ε directly: u(σ) ≤ u_enc, any correlation
    assert c["interpolation"].u_deg == pytest.approx(1e-5 / (2 * s), rel=1e-12)
    ev = [c[k].u_deg or 0.0 for k in ("record", "timing", "resolution", "reference",
                                      "interpolation")]
    uc = math.sqrt(sum(u * u for u in ev))
    assert b.combined_deg == pytest.approx(uc, rel=1e-12)
    assert b.coverage_factor == 2.0
    assert b.expanded_deg == pytest.approx(2.0 * uc, rel=1e-12)
    assert b.dof_effective == pytest.approx(uc**4 / (ev[0] ** 4 / 800.0), rel=1e-12)
    assert b.bias_deg == pytest.approx(2e-5 / (2 * s) - (0.2501 - s), rel=1e-12)
    d = json.loads(json.dumps(b.to_dict()))
    assert d["sigma_of"] == SIGMA_OF == "sigma" and d["interval"] == "sigma_ci95"
    assert d["expanded"] == pytest.approx(2.0 * uc, rel=1e-12)


def test_first_order_propagation_is_capped_at_what_the_variance_alone_makes() -> None:
    assert sigma_u(1e-4, 0.5) == pytest.approx(1e-4, rel=1e-12)
    assert sigma_u(1e-4, 0.001) == pytest.approx(0.01, rel=1e-12)  # √u(σ²): 4σ² < u(σ²)
    assert sigma_u(1e-4, 0.0) == pytest.approx(0.01, rel=1e-12)
    assert sigma_u(0.0, 0.3) == 0.0


def test_non_stationarity_is_flagged_not_assessed_never_zero() -> None:
    b = _budget()
    ns = _by_key(b)["nonstationarity"]
    assert ns.status == NOT_ASSESSED and ns.u_deg is None
    d = b.to_dict()
    entry = next(e for e in d["contributions"] if e["key"] == "nonstationarity")
    assert entry["status"] == "not assessed" and entry["u"] is None
    assert d["complete"] is False and "non-stationarity: not assessed" in d["left_out"]


def test_an_encoder_not_stated_is_said_so_not_taken_as_zero() -> None:
    b = _budget(reference=Reference())
    c = _by_key(b)
    for key in ("resolution", "reference"):
        assert c[key].status == NOT_STATED and c[key].u_deg is None
        assert "states no stand.encoder_" in c[key].basis
    assert {"reference resolution: not stated", "reference uncertainty: not stated"} <= set(
        b.to_dict()["left_out"])
    assert Reference.of({}) == Reference() == Reference.of(None)
    assert Reference.of({"encoder_resolution_deg": 0.0, "encoder_uncertainty_deg": None}) == (
        Reference(0.0, None))
    with pytest.raises(AnalysisError, match="encoder_resolution_deg: expected a finite number"):
        Reference.of({"encoder_resolution_deg": -1.0})


def test_bad_inputs_are_refused_naming_them() -> None:
    with pytest.raises(AnalysisError, match="bridge_variance expected a finite number ≥ 0, got -1"):
        _budget(bridge_variance=-1.0)
    with pytest.raises(AnalysisError, match="ci_statistical"):
        _budget(ci_statistical=(0.3, 0.2))
    with pytest.raises(AnalysisError, match="dof expected > 0"):
        _budget(dof=0.0)


u_in = st.floats(min_value=0.0, max_value=1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=50, deadline=None)
@given(sigma=st.floats(min_value=0.0, max_value=100.0), half=u_in, dof=st.floats(0.5, 1e9),
       cross=u_in, bias=u_in, bridge=u_in, q=st.none() | u_in, ue=st.none() | u_in)
def test_combined_covers_every_contribution_and_expanded_is_twice_it(
        sigma: float, half: float, dof: float, cross: float, bias: float, bridge: float,
        q: float | None, ue: float | None) -> None:
    b = uncertainty_budget(
        sigma=sigma, sigma_corrected=sigma, ci_statistical=(sigma, sigma + 2 * half), dof=dof,
        timing_cross_variance=cross, timing_bias_variance=bias + bridge,
        bridge_variance=bridge, reference=Reference(q, ue))
    uc = b.combined_deg
    for c in b.evaluated:
        assert c.u_deg is not None and c.u_deg >= 0.0
        assert uc >= c.u_deg * (1 - 1e-12)
    assert b.expanded_deg == pytest.approx(2.0 * uc, rel=1e-12, abs=0.0)
    assert b.dof_effective >= min(c.dof for c in b.evaluated) * (1 - 1e-9)


def test_a_quantised_reference_reads_sigma_high_by_q2_over_12() -> None:
    """Stand angle x, instrument y = x + white noise; the reference quantised to q. σ² of the
    quantised record exceeds that of the exact one by q²/12 (the tolerance in the module
    notes), and the budget's resolution contribution is q²/(24σ)."""
    rng = np.random.default_rng(20261127)
    n, dt, sn, q = 30_000, 0.01, 0.01, 0.01
    t = np.arange(n) * dt
    x = 5 * np.sin(2 * np.pi * 0.1 * t) + 3 * np.sin(2 * np.pi * 0.23 * t + 1.0)
    y = x + rng.normal(0.0, sn, n)
    xq = np.round(x / q) * q
    exact = analyze(t, x, t, y, lines="off", reference=Reference(0.0, 0.0))
    quant = analyze(t, xq, t, y, lines="off", reference=Reference(q, 0.0))
    excess = quant.variance - exact.variance
    sd = math.hypot(math.sqrt((q**4 / 80 - q**4 / 144) / n), 2 * sn * q / math.sqrt(12 * n))
    assert abs(excess - q * q / 12) <= 4 * sd, (excess, q * q / 12, sd)
    c = _by_key(quant.budget) if quant.budget is not None else {}
    assert c["resolution"].u_deg == pytest.approx(q * q / (24 * quant.sigma), rel=1e-12)
    assert c["resolution"].status == EVALUATED
    d = quant.to_dict()["budget"]
    assert d["sigma_of"] == "sigma" and d["sigma"] == quant.sigma
    assert d["contributions"][0]["dof"] == pytest.approx(quant.dof, rel=1e-12)
    # the record term is the statistical interval's, with its ν
    lo, hi = quant.timing["sigma_ci95_statistical"]
    assert c["record"].u_deg == pytest.approx((hi - lo) / (2 * Z95), rel=1e-12)
    # unlabelled arrays and no Reference given: the encoder is not stated
    plain = analyze(t, xq, t, y, lines="off")
    assert plain.budget is not None
    assert _by_key(plain.budget)["resolution"].status == NOT_STATED


def _recording(tmp_path: Path, stand: dict[str, object]) -> Path:
    """A small recording folder (stand at 100 Hz, instrument receipts), its config's
    ``stand:`` section as given."""
    rec = tmp_path / f"rec{len(stand)}"
    rec.mkdir()
    t = 1000.0 + np.arange(0, 30, 0.01)
    x = 2 * np.sin(2 * np.pi * 0.2 * t)
    y = x + np.random.default_rng(3).normal(0, 0.01, t.size)
    cfg = {"stand": {"driver": "modbus-tcp", **stand}, "instrument": {"driver": "j1939"}}
    meta = {"format": FORMAT_NAME, "version": 1, "axes": ["roll"], "config": cfg}
    (rec / "meta.json").write_text(json.dumps(meta))
    rows = "\n".join(f"{a:.9f},0.001,{b:.9f},0,0,1,0" for a, b in zip(t, x, strict=True))
    (rec / "stand.csv").write_text("t_host,rtt_s,roll_deg,roll_rate_deg_s,roll_setpoint_deg,"
                                   "status,fault_code\n" + rows + "\n")
    rows = "\n".join(f"{a:.9f},,,,{b:.9f}" for a, b in zip(t + 0.002, y, strict=True))
    (rec / "instrument.csv").write_text("t_host,device_time_s,counter,adapter_time_s,roll_deg\n"
                                        + rows + "\n")
    return rec


def test_the_bench_configs_encoder_reaches_the_budget(tmp_path: Path) -> None:
    stated = load_recording(_recording(
        tmp_path, {"encoder_resolution_deg": 0.001, "encoder_uncertainty_deg": 0.0005}))
    assert stated.encoder == {"encoder_resolution_deg": 0.001, "encoder_uncertainty_deg": 0.0005}
    tr, xr, td, yd = stated.pair("roll")
    r = analyze(tr, xr, td, yd, lines="off")
    assert r.budget is not None
    c = _by_key(r.budget)
    assert c["resolution"].u_deg == pytest.approx(0.001**2 / (24 * r.sigma), rel=1e-12)
    assert c["reference"].u_deg == 0.0005
    old = load_recording(_recording(tmp_path, {}))  # a config without them: not stated
    assert old.encoder == {"encoder_resolution_deg": None, "encoder_uncertainty_deg": None}
    tr, xr, td, yd = old.pair("roll")
    r = analyze(tr, xr, td, yd, lines="off")
    assert r.budget is not None
    assert [c.status for c in r.budget.contributions if c.key in ("resolution", "reference")] == [
        NOT_STATED, NOT_STATED]


def _small_result(q: float | None = 0.001) -> AnalysisResult:
    rng = np.random.default_rng(5)
    t = np.arange(6000) * 0.05
    x = 5 * np.sin(2 * np.pi * 0.1 * t)
    return analyze(t, x, t, x + rng.normal(0, 0.03, t.size), lines="off", axis="roll",
                   reference=Reference(q, None))


def test_the_budget_in_the_report_and_the_record(tmp_path: Path) -> None:
    """The report's axis, its text and the record's σ measurement carry the same budget, of
    the σ they state (``sigma``)."""
    r = _small_result()
    v = axis_verdict("roll", r, 0.4)
    d = v.to_dict(full=False)
    assert d["budget"]["sigma_of"] == "sigma" and d["budget"]["sigma"] == d["sigma"]
    assert d["budget"] == r.to_dict()["budget"]
    text = format_report(Report({"roll": v}, tmp_path, {"serial": "S"}, {}, (0.0, 300.0)))
    assert "uncertainty budget of σ (sigma, the σ above" in text
    assert "non-stationarity" in text and "not assessed" in text
    assert "reference uncertainty" in text and "not stated" in text
    assert f"expanded U = {r.budget.expanded_deg:.2g}° (k = 2)" in text  # type: ignore[union-attr]
    ms = axis_measurements("roll", v.to_dict(), Limits(sigma_deg=0.4))
    sigma = ms[0]
    assert sigma.name == "sigma" and sigma.value == v.sigma_deg
    assert sigma.uncertainty == d["budget"]
    assert all(m.uncertainty is None for m in ms[1:])
    rec = build_record({"serial": "SN", "operator": "o", "station": "s"}, recording=tmp_path,
                       outcome=Outcome.PASS, measurements=ms)
    validate_record(json.loads(json.dumps(rec)))
    assert rec["measurements"][0]["uncertainty"]["sigma_of"] == "sigma"
    assert "uncertainty" not in rec["measurements"][1]


def test_the_budget_in_analyze_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t = np.arange(6000) * 0.05
    x = 5 * np.sin(2 * np.pi * 0.1 * t)
    y = x + np.random.default_rng(2).normal(0, 0.03, t.size)
    csv = tmp_path / "run.csv"
    np.savetxt(csv, np.column_stack([t, x, y]), delimiter=",", fmt="%.17g",
               header="time,reference,device", comments="")
    assert main(["analyze", str(csv), "--json", "--lines", "off"]) == 0
    d = json.loads(capsys.readouterr().out)
    b = d["budget"]
    assert b["sigma_of"] == "sigma" and b["sigma"] == d["sigma"] and b["coverage_factor"] == 2
    assert b["expanded"] == pytest.approx(2 * b["combined"], rel=1e-12)
    status = {c["key"]: c["status"] for c in b["contributions"]}
    assert status["resolution"] == status["reference"] == "not stated"  # a CSV states none
    assert status["nonstationarity"] == "not assessed"
    assert main(["analyze", str(csv), "--lines", "off"]) == 0
    assert "uncertainty budget of σ (sigma" in capsys.readouterr().out
