"""A bench config whose longest stand exchange and heartbeat do not fit inside the stand's
watchdog is refused: ``stand.timeout_s × (stand.retries + 1) + stand.heartbeat_period_s`` must
be at most the stand's watchdog — ``stand.watchdog_s`` when given (a real stand's setting), the
simulated stand's ``sim.stand.watchdog_s`` with a ``sim:`` section. Otherwise one slow reply
lets the stand stop itself mid-run (config/sim.yaml shipped 2.0 s × 2 + 0.1 s against 1.0 s).
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from repo_paths import ROOT

from benchctl.config import ConfigError, exchange_bound_s, load_config, parse_config

SIM = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
HARDWARE = yaml.safe_load((ROOT / "config" / "hardware_example.yaml").read_text())
SOURCE = ROOT / "config" / "bench.yaml"  # where the data claims to come from (paths resolve)


def _with(base: dict[str, Any], stand: dict[str, Any], sim_stand: dict[str, Any] | None = None
          ) -> dict[str, Any]:
    data = copy.deepcopy(base)
    data["stand"].update(stand)
    if sim_stand is not None:
        data["sim"]["stand"].update(sim_stand)
    return data


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "config").glob("*.yaml")))
def test_every_shipped_config_fits_its_stands_watchdog(name: str) -> None:
    cfg = load_config(ROOT / "config" / name)
    watchdog = cfg.sim.stand.watchdog_s if cfg.sim is not None else cfg.stand.watchdog_s
    assert watchdog is not None, f"{name} states no watchdog of its stand"
    assert exchange_bound_s(cfg.stand) <= watchdog


def test_the_old_default_config_is_refused_naming_file_fields_values_and_expectation() -> None:
    data = _with(SIM, {"timeout_s": 2.0, "retries": 1}, {"watchdog_s": 1.0})
    with pytest.raises(ConfigError) as info:
        parse_config(data, SOURCE)
    msg = str(info.value)
    assert msg.startswith(f"{SOURCE}: invalid bench config: ")
    for part in ("stand.timeout_s = 2 s", "stand.retries = 1", "stand.heartbeat_period_s = 0.1 s",
                 "= 4.1 s", "expected at most the stand's watchdog, sim.stand.watchdog_s = 1 s"):
        assert part in msg, msg
    assert "\n" not in msg


def test_a_real_stands_watchdog_is_checked_when_given_and_only_then() -> None:
    ok = _with(HARDWARE, {"timeout_s": 0.3, "retries": 1, "heartbeat_period_s": 0.1})
    parse_config(ok, SOURCE)  # 0.7 s within 1.0 s
    slow = _with(HARDWARE, {"timeout_s": 0.5})
    with pytest.raises(ConfigError, match=r"= 1\.1 s: expected at most the stand's watchdog, "
                                          r"stand\.watchdog_s = 1 s"):
        parse_config(slow, SOURCE)
    unknown = copy.deepcopy(slow)
    del unknown["stand"]["watchdog_s"]
    parse_config(unknown, SOURCE)  # a stand whose watchdog the config does not state


def test_with_a_sim_section_the_simulators_watchdog_is_the_stands() -> None:
    same = _with(SIM, {"watchdog_s": 2.0})
    parse_config(same, SOURCE)
    other = _with(SIM, {"watchdog_s": 5.0})
    with pytest.raises(ConfigError, match=r"field stand\.watchdog_s = 5 s: expected the simulated "
                                          r"stand's, sim\.stand\.watchdog_s = 2 s"):
        parse_config(other, SOURCE)


def test_the_file_loader_refuses_it_too(tmp_path: Path) -> None:
    data = _with(SIM, {"timeout_s": 1.0, "retries": 1}, {"watchdog_s": 2.0})
    for k in ("register_map",):
        data["stand"][k] = str((ROOT / "config" / data["stand"][k]).resolve())
    f = tmp_path / "bench.yaml"
    f.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=rf"^{f}: invalid bench config: .*= 2\.1 s"):
        load_config(f)


@settings(max_examples=60, deadline=None)
@given(
    timeout=st.floats(0.01, 5.0),
    retries=st.integers(0, 5),
    period=st.floats(0.01, 1.0),
    watchdog=st.floats(0.05, 30.0),
    simulated=st.booleans(),
)
def test_accepted_exactly_when_the_exchange_and_heartbeat_fit(
    timeout: float, retries: int, period: float, watchdog: float, simulated: bool
) -> None:
    stand = {"timeout_s": timeout, "retries": retries, "heartbeat_period_s": period}
    if simulated:
        data = _with(SIM, stand, {"watchdog_s": watchdog})
    else:
        data = _with(HARDWARE, {**stand, "watchdog_s": watchdog})
    need = timeout * (retries + 1) + period
    if need <= watchdog:
        cfg = parse_config(data, SOURCE)
        assert exchange_bound_s(cfg.stand) == pytest.approx(need)
    elif need > watchdog * (1 + 1e-9):
        with pytest.raises(ConfigError, match="expected at most the stand's watchdog"):
            parse_config(data, SOURCE)
