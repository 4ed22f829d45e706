"""The stand's reference angle in the bench config: ``stand.encoder_resolution_deg`` (its
quantisation step) and ``stand.encoder_uncertainty_deg`` (its standard uncertainty), both
optional (unset: σ's uncertainty budget says "not stated", never 0). Every shipped simulated
config states the simulated stand's own resolution — the one its simulator rounds the angle to —
and an uncertainty of 0 (its encoder has no other error)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from repo_paths import ROOT

from benchctl.config import ConfigError, load_config, parse_config

SIMS = sorted((ROOT / "config").glob("sim*.yaml"))
SOURCE = ROOT / "config" / "bench.yaml"


@pytest.mark.parametrize("path", SIMS, ids=lambda p: p.name)
def test_a_simulated_config_states_its_simulated_encoder(path: Path) -> None:
    cfg = load_config(path)
    assert cfg.sim is not None
    assert cfg.stand.encoder_resolution_deg == cfg.sim.stand.encoder_resolution_deg == 0.001
    assert cfg.stand.encoder_uncertainty_deg == 0.0


def test_unset_is_not_stated() -> None:
    cfg = load_config(ROOT / "config" / "hardware_example.yaml")
    assert cfg.stand.encoder_resolution_deg is None
    assert cfg.stand.encoder_uncertainty_deg is None


@pytest.mark.parametrize("field", ["encoder_resolution_deg", "encoder_uncertainty_deg"])
@pytest.mark.parametrize("value", [-0.001, ".nan", ".inf"])
def test_a_negative_or_non_finite_value_is_refused_naming_the_field(field: str, value: object
                                                                    ) -> None:
    data = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
    data["stand"][field] = yaml.safe_load(str(value))
    with pytest.raises(ConfigError, match=field):
        parse_config(data, SOURCE)
