"""Wave and roll spectra against closed forms (pure functions)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, optimize

from benchctl.profiles import roll, spectra


def _m0(fn, tp_s: float) -> float:
    fp = 1.0 / tp_s
    total = 0.0
    for a, b in ((0.0, fp), (fp, 3 * fp), (3 * fp, np.inf)):
        val, _ = integrate.quad(lambda f: float(fn(np.array([f]))[0]), a, b, limit=400)
        total += val
    return total


@pytest.mark.parametrize(("hs", "tp"), [(0.875, 7.5), (3.25, 9.7), (5.0, 12.4)])
def test_pierson_moskowitz_hs_from_m0(hs: float, tp: float) -> None:
    m0 = _m0(lambda f: spectra.pierson_moskowitz(f, hs, tp), tp)
    assert 4 * math.sqrt(m0) == pytest.approx(hs, rel=0.01)


@pytest.mark.parametrize("gamma", [1.0, 2.0, 3.3, 7.0])
@pytest.mark.parametrize(("hs", "tp"), [(1.0, 5.0), (4.0, 11.0)])
def test_jonswap_hs_from_m0(hs: float, tp: float, gamma: float) -> None:
    m0 = _m0(lambda f: spectra.jonswap(f, hs, tp, gamma), tp)
    assert 4 * math.sqrt(m0) == pytest.approx(hs, rel=0.01)


@pytest.mark.parametrize("gamma", [1.0, 2.0, 3.3, 5.0])
def test_jonswap_normalisation_matches_goda(gamma: float) -> None:
    # Goda (1988): C(γ) ≈ 1 − 0.287 ln γ for the standard σa, σb
    assert spectra.jonswap_normalisation(gamma) == pytest.approx(
        1 - 0.287 * math.log(gamma), rel=0.02
    )


def test_jonswap_gamma_one_is_pierson_moskowitz() -> None:
    f = np.linspace(0.01, 1.0, 500)
    np.testing.assert_allclose(
        spectra.jonswap(f, 2.0, 8.0, 1.0), spectra.pierson_moskowitz(f, 2.0, 8.0), rtol=1e-6
    )


@pytest.mark.parametrize("tp", [4.0, 7.5, 12.4])
@pytest.mark.parametrize("gamma", [None, 1.5, 3.3])
def test_spectral_peak_sits_at_tp(tp: float, gamma: float | None) -> None:
    def neg(f: float) -> float:
        arr = np.array([f])
        s = (
            spectra.pierson_moskowitz(arr, 2.0, tp)
            if gamma is None
            else spectra.jonswap(arr, 2.0, tp, gamma)
        )
        return -float(s[0])

    res = optimize.minimize_scalar(
        neg, bounds=(0.5 / tp, 2.0 / tp), method="bounded", options={"xatol": 1e-9}
    )
    assert 1.0 / res.x == pytest.approx(tp, rel=1e-4)


def test_wmo_sea_state_table() -> None:
    assert spectra.wmo_sea_state(4).hs_m == pytest.approx(1.875)
    assert spectra.wmo_sea_state(6).hs_min_m == 4.0 and spectra.wmo_sea_state(6).hs_max_m == 6.0
    with pytest.raises(ValueError, match="0…9"):
        spectra.wmo_sea_state(12)


def test_spectra_reject_bad_parameters() -> None:
    with pytest.raises(ValueError, match="hs_m"):
        spectra.pierson_moskowitz([0.1], -1.0, 8.0)
    with pytest.raises(ValueError, match="gamma"):
        spectra.jonswap([0.1], 1.0, 8.0, gamma=0.5)


@pytest.mark.parametrize("zeta", [0.05, 0.1, 0.3])
def test_roll_response_peaks_at_natural_period_with_height_for_damping(zeta: float) -> None:
    tn, kappa = 6.0, 0.7
    res = optimize.minimize_scalar(
        lambda f: -float(roll.roll_rao(np.array([f]), tn, zeta, kappa)[0]),
        bounds=(0.5 / tn, 1.5 / tn),
        method="bounded",
        options={"xatol": 1e-10},
    )
    assert res.x * tn == pytest.approx(math.sqrt(1 - 2 * zeta**2), rel=1e-5)
    assert -res.fun == pytest.approx(kappa / (2 * zeta * math.sqrt(1 - zeta**2)), rel=1e-8)
    at_fn = float(roll.roll_rao(np.array([1.0 / tn]), tn, zeta, kappa)[0])
    assert at_fn == pytest.approx(kappa / (2 * zeta), rel=1e-12)
    assert float(roll.roll_rao(np.array([1e-5]), tn, zeta, kappa)[0]) == pytest.approx(
        kappa, rel=1e-6
    )


def test_roll_response_is_slope_spectrum_times_rao_squared() -> None:
    f = np.array([0.05, 0.1, 1 / 6, 0.3])
    s = spectra.pierson_moskowitz(f, 2.0, 8.0)
    slope = (2 * np.pi * f) ** 4 / spectra.G_STANDARD**2 * s
    rao = 0.6 / np.sqrt((1 - (6 * f) ** 2) ** 2 + (2 * 0.15 * 6 * f) ** 2)
    expected = (180 / np.pi) ** 2 * rao**2 * slope
    np.testing.assert_allclose(roll.roll_response_psd(f, s, 6.0, 0.15, 0.6), expected, rtol=1e-12)


@pytest.mark.parametrize(
    ("sigma", "period", "damping"), [(3.0, 6.0, 0.2), (1.0, 3.0, 0.05), (5.0, 10.0, 0.5)]
)
def test_exp_cos_integrates_to_sigma_squared(sigma: float, period: float, damping: float) -> None:
    alpha, beta = roll.exp_cos_parameters(period, damping)
    fb = beta / (2 * np.pi)
    g = lambda f: float(roll.exp_cos_psd(np.array([f]), sigma, alpha, beta)[0])  # noqa: E731
    area = sum(
        integrate.quad(g, a, b, limit=400)[0]
        for a, b in ((0, fb), (fb, 10 * fb), (10 * fb, np.inf))
    )
    assert area == pytest.approx(sigma**2, rel=1e-6)


def test_exp_cos_density_is_the_transform_of_its_correlation() -> None:
    sigma, alpha, beta = 2.0, 0.3, 1.1
    for f in (0.0, 0.1, beta / (2 * np.pi), 0.4):
        # G(f) = 4 ∫₀^∞ R(τ) cos(2πfτ) dτ for a one-sided density in Hz
        val, _ = (
            integrate.quad(
                lambda tau: float(roll.exp_cos_correlation(tau, sigma, alpha, beta)),
                0,
                np.inf,
                weight="cos",
                wvar=2 * np.pi * f,
            )
            if f > 0
            else integrate.quad(
                lambda tau: float(roll.exp_cos_correlation(tau, sigma, alpha, beta)), 0, np.inf
            )
        )
        assert float(roll.exp_cos_psd(np.array([f]), sigma, alpha, beta)[0]) == pytest.approx(
            4 * val, rel=1e-6
        )


def test_breakpoint_table_is_linear_and_zero_outside() -> None:
    g = roll.breakpoint_psd([0.05, 0.15, 0.25, 0.5], [0.1, 0.2, 0.3], [1.0, 3.0, 1.0])
    np.testing.assert_allclose(g, [0.0, 2.0, 2.0, 0.0])
