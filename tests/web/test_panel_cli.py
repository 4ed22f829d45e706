"""``benchctl serve``'s command line: its settings from the panel file and the options, the
messages for what is missing, the token's hash."""

from __future__ import annotations

import io
import sys
from pathlib import Path

import pytest
from repo_paths import ROOT

from benchctl.cli import build_parser, main
from benchctl.cli.serve import settings_from
from benchctl.errors import ConfigError
from benchctl.web.security import verify_token


def args(*words: str) -> object:
    return build_parser().parse_args(["serve", *words])


def test_the_panel_file_and_the_options_over_it(tmp_path: Path) -> None:
    panel = tmp_path / "panel.yaml"
    panel.write_text(f"lang: ru\nport: 9000\nduration_s: 45\nprofiles: [{ROOT / 'profiles'}]\n"
                     f"plans: [{ROOT / 'plans/ci_short.yaml'}]\norigins: [https://b.example]\n")
    s = settings_from(args("--config", str(ROOT / "config/sim.yaml"), "--panel", str(panel),
                           "--port", "9001"))
    assert s.lang == "ru" and s.port == 9001 and s.duration_s == 45  # the option wins
    assert s.config.is_absolute() and all(p.is_absolute() for p in s.profiles)
    assert ROOT / "profiles/paper_vessel_roll.yaml" in s.profiles  # a folder: its *.yaml
    assert [p.name for p in s.plans] == ["ci_short.yaml"]
    assert s.origins == ("https://b.example",) and s.host == "127.0.0.1"


def test_the_bench_configs_panel_section_chooses_the_stations_language(tmp_path: Path) -> None:
    """The station's language (and the rest) in its bench config, relative paths from the
    config's folder; the options still win, and a panel file replaces the section."""
    text = (ROOT / "config/sim.yaml").read_text()
    text = text.replace("../drivers/", f"{ROOT}/drivers/").replace("../runs", str(tmp_path))
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles/roll.yaml").write_text(
        (ROOT / "profiles/ci_short.yaml").read_text())
    cfg = tmp_path / "bench.yaml"
    cfg.write_text(text + "panel:\n  lang: ru\n  profiles: [profiles]\n  port: 8400\n"
                   "  out_dir: station-runs\n")
    s = settings_from(args("--config", str(cfg)))
    assert s.lang == "ru" and s.port == 8400
    assert s.profiles == ((tmp_path / "profiles/roll.yaml").resolve(),)
    assert s.out_dir == (tmp_path / "station-runs").resolve()
    assert settings_from(args("--config", str(cfg), "--lang", "en")).lang == "en"
    panel = tmp_path / "panel.yaml"
    panel.write_text(f"profiles: [{ROOT / 'profiles/ci_short.yaml'}]\n")
    s = settings_from(args("--config", str(cfg), "--panel", str(panel)))
    assert s.lang == "en" and s.port == 8350  # the file's fields, not the section's
    cfg.write_text(text + "panel:\n  lang: fr\n")
    with pytest.raises(ConfigError, match=r"bench\.yaml: invalid bench config: field panel\.lang"):
        settings_from(args("--config", str(cfg)))


def test_what_is_wrong_is_named(tmp_path: Path) -> None:
    panel = tmp_path / "panel.yaml"
    panel.write_text("lang: fr\ncolour: blue\n")
    with pytest.raises(ConfigError, match=r"panel\.yaml: invalid panel settings: field lang"):
        settings_from(args("--config", str(ROOT / "config/sim.yaml"), "--panel", str(panel)))
    with pytest.raises(ConfigError, match="no motion profile for the operator"):
        settings_from(args("--config", str(ROOT / "config/sim.yaml")))
    with pytest.raises(ConfigError, match=r"nowhere\.yaml: no such profile"):
        settings_from(args("--config", str(ROOT / "config/sim.yaml"), "--profile",
                           str(tmp_path / "nowhere.yaml")))


def test_without_the_web_extra_it_says_which_to_install(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setitem(sys.modules, "uvicorn", None)  # import uvicorn: ImportError
    code = main(["serve", "--config", str(ROOT / "config/sim.yaml"), "--profile",
                 str(ROOT / "profiles")])
    assert code == 2
    err = capsys.readouterr().err
    assert 'the "web" extra' in err and '.[web]' in err and "uvicorn" in err


def test_hash_token_prints_a_hash_never_the_token(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO("a token long enough\n"))
    assert main(["serve", "--hash-token"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith('token_scrypt: "scrypt$') and "a token long enough" not in out
    assert verify_token("a token long enough", out.split('"')[1])
    monkeypatch.setattr(sys, "stdin", io.StringIO("short\n"))
    assert main(["serve", "--hash-token"]) == 2
