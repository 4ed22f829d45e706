"""Profile files: strict validation with clear errors, the library, recorded profiles."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from repo_paths import ROOT
from scipy import integrate

from benchctl.config import StandLimits
from benchctl.errors import ConfigError, DataError
from benchctl.profiles import check_motion, load_profile, parse_profile, roll, synthesize

LIBRARY = sorted((ROOT / "profiles").glob("*.yaml"))
SIM_LIMITS = StandLimits(angle_deg=30, rate_deg_s=30, accel_deg_s2=60)


def write(tmp_path: Path, data: object, name: str = "p.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return p


def sea_state(**over: object) -> dict[str, object]:
    d: dict[str, object] = {
        "name": "s",
        "kind": "sea_state",
        "duration_s": 300,
        "seed": 1,
        "band_hz": [0.05, 0.5],
        "sea": {"spectrum": "bretschneider", "hs_m": 2.0, "tp_s": 8.0},
        "axes": {"roll": {"natural_period_s": 6.0, "damping_ratio": 0.15}},
    }
    d.update(over)
    return d


def test_library_holds_the_profiles_the_project_promises() -> None:
    names = {p.stem for p in LIBRARY}
    for must in (
        "paper_vessel_roll",
        "sea_state_3_small_vessel",
        "sea_state_4_small_vessel",
        "sea_state_5_small_vessel",
        "sea_state_6_small_vessel",
        "fast_craft_roll",
        "linearity_sine_steps",
        "two_axis_roll_pitch",
        "ci_short",
    ):
        assert must in names


@pytest.mark.parametrize("path", LIBRARY, ids=lambda p: p.stem)
def test_every_library_profile_loads_synthesises_fits_a_sim_stand_and_cites_its_source(
    path: Path,
) -> None:
    text = path.read_text(encoding="utf-8")
    assert text.lstrip().startswith("#"), (
        "each profile starts with a comment saying where its numbers come from"
    )
    prof = load_profile(path)
    assert prof.name == path.stem
    motion = synthesize(prof)
    check = check_motion(motion, SIM_LIMITS, rate_hz=50.0)
    assert check.scale == 1.0
    assert prof.to_dict()["spec"]["kind"] == prof.kind


def test_paper_vessel_profile_matches_the_paper_scenario() -> None:
    prof = load_profile(ROOT / "profiles" / "paper_vessel_roll.yaml")
    motion = synthesize(prof)
    tab = motion.tables["roll"]
    assert prof.axes == ("roll",) and prof.duration_s == 900
    assert 1 / tab.freq_hz.max() >= 3.0 - 1e-3 and 1 / tab.freq_hz.min() <= 10.0 + 1e-9
    assert 1.0 < math.sqrt(tab.variance_deg2) < 5.0  # σ of a few degrees


def test_ci_short_profile_is_short_and_gentle() -> None:
    prof = load_profile(ROOT / "profiles" / "ci_short.yaml")
    assert 20 <= prof.duration_s <= 30
    check = check_motion(synthesize(prof), SIM_LIMITS, rate_hz=100.0)
    assert check.peaks["roll"].angle_deg < 10 and check.peaks["roll"].rate_deg_s < 15


@pytest.mark.parametrize(
    ("data", "field"),
    [
        ({**sea_state(), "kind": "wind_state"}, "kind = 'wind_state'"),
        (sea_state(sea={"spectrum": "bretschneider", "hs_m": -2.0, "tp_s": 8.0}), "sea.hs_m"),
        (sea_state(sea={"spectrum": "bretschneider", "hs_ft": 6.0, "tp_s": 8.0}), "sea.hs_ft"),
        (
            sea_state(sea={"spectrum": "bretschneider", "hs_m": 2.0, "wmo_code": 4, "tp_s": 8.0}),
            "sea",
        ),
        (
            sea_state(sea={"spectrum": "bretschneider", "hs_m": 2.0, "tp_s": 8.0, "gamma": 3.3}),
            "sea",
        ),
        (sea_state(duration_min=5), "duration_min"),
        (sea_state(band_hz=[0.5, 0.05]), "band_hz"),
        (sea_state(axes={"yaw": {"natural_period_s": 6.0, "damping_ratio": 0.15}}), "axes.yaw"),
        (
            sea_state(axes={"roll": {"natural_period_s": 6.0, "damping_ratio": 1.5}}),
            "axes.roll.damping_ratio",
        ),
        (sea_state(seed=-1), "seed"),
        ({k: v for k, v in sea_state().items() if k != "seed"}, "seed"),
        (sea_state(duration_s="15 min"), "duration_s"),
    ],
)
def test_bad_profiles_name_the_file_and_field(
    tmp_path: Path, data: dict[str, object], field: str
) -> None:
    p = write(tmp_path, data)
    with pytest.raises(ConfigError) as exc:
        load_profile(p)
    msg = str(exc.value)
    assert str(p) in msg
    assert f"field {field}" in msg or f"field {field}." in msg, msg


def test_unreadable_and_invalid_yaml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read profile"):
        load_profile(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: [unclosed\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_profile(bad)
    lst = tmp_path / "list.yaml"
    lst.write_text("- 1\n- 2\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="mapping"):
        load_profile(lst)


def test_band_the_duration_cannot_resolve_is_refused(tmp_path: Path) -> None:
    p = write(tmp_path, sea_state(duration_s=30, fade_in_s=5, fade_out_s=5, band_hz=[0.02, 0.5]))
    with pytest.raises(ConfigError, match=r"field band_hz .*below the resolution 1/T_p = 0\.05 Hz"):
        synthesize(load_profile(p))


def test_band_with_too_few_lines_and_above_nyquist_are_refused(tmp_path: Path) -> None:
    p = write(tmp_path, sea_state(duration_s=30, fade_in_s=5, fade_out_s=5, band_hz=[0.1, 0.12]))
    with pytest.raises(ConfigError, match="min_lines"):
        synthesize(load_profile(p))
    p = write(tmp_path, sea_state(band_hz=[0.1, 6.0]))
    with pytest.raises(ConfigError, match="half the setpoint rate"):
        synthesize(load_profile(p), setpoint_rate_hz=10.0)


def test_fades_longer_than_the_duration_are_refused(tmp_path: Path) -> None:
    p = write(tmp_path, sea_state(duration_s=20, fade_in_s=10, fade_out_s=10))
    with pytest.raises(ConfigError, match="fade_in_s"):
        synthesize(load_profile(p))
    with pytest.raises(ConfigError, match="fade"):
        synthesize(load_profile(write(tmp_path, sea_state())), duration_s=8.0)


def test_sine_steps_grid_and_fixed_duration() -> None:
    prof = load_profile(ROOT / "profiles" / "linearity_sine_steps.yaml")
    motion = synthesize(prof)
    assert motion.tables is None
    segs = motion.segments  # type: ignore[attr-defined]
    assert [(s.period_s, s.amplitude_deg) for s in segs] == [
        (p, a) for p in (3, 5, 7, 10) for a in (2, 5, 10)
    ]
    expected = 12 * 2 + sum(3 * (5 + 4) * p for p in (3, 5, 7, 10)) + 2
    assert prof.duration_s == pytest.approx(expected) and motion.duration_s == pytest.approx(
        expected
    )
    s = segs[2]  # 3 s, 10 deg
    t = s.start_s + 2 * 3.0 + np.array([0.25, 1.0, 2.2])  # inside the full-amplitude cycles
    np.testing.assert_allclose(
        motion.evaluate(t)["roll"], 10 * np.sin(2 * np.pi * (t - s.start_s) / 3), atol=1e-9
    )
    with pytest.raises(ConfigError, match="sine_steps"):
        synthesize(prof, duration_s=120)


# --- recorded -------------------------------------------------------------------------------

SIGMA, PERIOD, DAMP = 3.0, 6.0, 0.2
A, B = roll.exp_cos_parameters(PERIOD, DAMP)


def known_record(path: Path, duration: float = 1800.0, rate: float = 10.0, seed: int = 99) -> None:
    """A record with a known spectrum: lines j/T at A_j = √(2 G(f_j) Δf), random phases."""
    f = np.arange(1, round(1.2 * duration)) / duration
    amp = np.sqrt(2 * roll.exp_cos_psd(f, SIGMA, A, B) / duration)
    ph = np.random.default_rng(seed).uniform(0, 2 * np.pi, f.size)
    t = np.arange(round(duration * rate)) / rate
    x = np.zeros_like(t)
    for i in range(0, f.size, 200):
        x += np.cos(np.outer(t, 2 * np.pi * f[i : i + 200]) + ph[i : i + 200]) @ amp[i : i + 200]
    np.savetxt(
        path,
        np.column_stack([t, x]),
        fmt="%.6f",
        delimiter=",",
        header="time,roll_deg",
        comments="",
    )


def test_recorded_profile_reproduces_the_known_spectrum(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    known_record(tmp_path / "data" / "trial.csv")
    data = {
        "name": "rec",
        "kind": "recorded",
        "duration_s": 610,
        "fade_in_s": 5,
        "fade_out_s": 5,
        "seed": 4,
        "band_hz": [0.1, 0.3334],
        "axes": {"roll": {"csv": "data/trial.csv", "angle_column": "roll_deg", "segment_s": 100}},
    }
    p = write(tmp_path / "data", data, "../rec.yaml")  # CSV path relative to the profile's folder
    prof = load_profile(tmp_path / "rec.yaml")
    motion = synthesize(prof)
    t = 5.0 + np.arange(600 * 10) / 10.0  # steady part: whole periods
    band_var = float(np.mean(motion.evaluate(t)["roll"] ** 2))
    exact = integrate.quad(
        lambda f: float(roll.exp_cos_psd(np.array([f]), SIGMA, A, B)[0]), 0.1, 0.3334
    )[0]
    assert band_var == pytest.approx(exact, rel=0.02)
    rec = prof.to_dict()["recorded"]["roll"]
    assert rec["sample_rate_hz"] == pytest.approx(10.0) and len(rec["sha256"]) == 64
    assert p.exists()


def test_recorded_profile_missing_csv_is_a_config_error(tmp_path: Path) -> None:
    data = {
        "name": "rec",
        "kind": "recorded",
        "duration_s": 100,
        "seed": 4,
        "band_hz": [0.1, 0.3],
        "axes": {"roll": {"csv": "nowhere.csv", "angle_column": "roll_deg"}},
    }
    p = write(tmp_path, data)
    with pytest.raises(ConfigError, match=r"field axes\.roll\.csv = 'nowhere.csv': file not found"):
        load_profile(p)


@pytest.mark.parametrize(
    ("body", "match"),
    [
        ("time,roll_deg\n0,1\n0.1,nan\n", r"row 3 column roll_deg"),
        ("time,roll_deg\n0,1\n0.1,x\n", r"row 3 column roll_deg: 'x' is not a number"),
        ("time,roll_deg\n0,1\n0.1,2\n0.1,3\n", r"column time must increase; row 4"),
        ("t,roll_deg\n0,1\n", r"no column 'time'"),
    ],
)
def test_recorded_profile_bad_csv_is_a_data_error(tmp_path: Path, body: str, match: str) -> None:
    (tmp_path / "r.csv").write_text(body, encoding="utf-8")
    data = {
        "name": "rec",
        "kind": "recorded",
        "duration_s": 100,
        "seed": 4,
        "band_hz": [0.1, 0.3],
        "axes": {"roll": {"csv": "r.csv", "angle_column": "roll_deg"}},
    }
    with pytest.raises(DataError, match=match):
        load_profile(write(tmp_path, data))


def test_parse_profile_without_a_file() -> None:
    prof = parse_profile(sea_state())
    assert prof.source is None and prof.kind == "sea_state" and prof.axes == ("roll",)
    assert prof.to_dict()["spec"]["sea"]["hs_m"] == 2.0
