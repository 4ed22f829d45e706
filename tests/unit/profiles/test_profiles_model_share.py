"""A profile says what it holds: the model's whole σ, the share its band keeps, the motion's σ."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.profiles import load_profile, synthesize
from benchctl.profiles.design import total_variance


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "p.yaml"
    p.write_text(text)
    return p


def test_exp_cos_model_variance_is_its_sigma_squared(tmp_path: Path) -> None:
    """R(τ) = σ² e^(−α|τ|) cos βτ: the whole area under its density is σ² exactly (to 1e-6)."""
    s = synthesize(load_profile(ROOT / "profiles/paper_vessel_roll.yaml"))
    pa = s.summary()["per_axis"]["roll"]  # type: ignore[index]
    assert pa["model_sigma_deg"] == pytest.approx(3.0, rel=1e-6)
    share = pa["band_share"]
    assert share == pytest.approx(pa["target_variance_deg2"] / 9.0, rel=1e-6)
    assert 0.80 < share < 0.82  # the paper's vessel: the 0.1–0.333 Hz band keeps 80.8 %
    assert pa["sigma_deg"] == pytest.approx(math.sqrt(share) * 3.0, rel=1e-4)


def test_table_model_variance_is_the_trapezoid_area() -> None:
    f = np.array([0.05, 0.1, 0.2, 0.4])
    g = np.array([0.0, 4.0, 2.0, 0.0])

    def density(x: np.ndarray) -> np.ndarray:
        return np.interp(x, f, g, left=0.0, right=0.0)

    exact = float(np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(f)))
    assert total_variance(density, f) == pytest.approx(exact, rel=1e-9)


def test_profile_show_says_what_the_band_keeps(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["profile", "show", str(ROOT / "profiles/paper_vessel_roll.yaml")]) == 0
    out = capsys.readouterr().out
    assert "model sigma 3.0000 deg; the band keeps 80.8 % of its variance" in out
    assert main(["profile", "show", str(ROOT / "profiles/paper_vessel_roll.yaml"), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)["per_axis"]["roll"]
    assert d["model_sigma_deg"] == pytest.approx(3.0, rel=1e-6)
    assert d["band_share"] == pytest.approx(d["variance_deg2"] / 9.0, rel=1e-4)
