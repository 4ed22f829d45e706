"""The station panel's settings: the bench config's ``panel:`` section, or a file of the same
fields (``benchctl serve --panel FILE``, e.g. one per operator station sharing a bench
config), the command line's options over either::

    panel:
      lang: ru                      # the operator's language: en or ru
      profiles:                     # what the operator may choose: files, or folders of *.yaml
        - ../profiles/paper_vessel_roll.yaml
      plans:                        # acceptance plans the operator may start (optional)
        - ../plans/ci_short.yaml
      duration_s: 120               # each run's duration (default: the profile's own)
      host: 127.0.0.1               # where the panel listens (loopback by default)
      port: 8350
      token_scrypt: "scrypt$16384$8$1$…"   # benchctl serve --hash-token; required off loopback
      require_token: false          # ask for the token on loopback too (behind a reverse proxy)
      origins: [https://bench3.example.org]  # the address(es) browsers use, behind a proxy
      out_dir: ../runs              # the runs' output folder (default: the config's run.output_dir)

Relative paths are taken from the folder of the file they are in; an unknown field is an
error.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from pydantic import ValidationError

from benchctl.config import PanelConfig
from benchctl.errors import ConfigError
from benchctl.validation import invalid
from benchctl.yamlfile import read_yaml

LANGUAGES = ("en", "ru")
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8350


@dataclass(frozen=True)
class PanelSettings:
    """Everything ``benchctl serve`` needs besides the bench config."""

    config: Path
    profiles: tuple[Path, ...]
    plans: tuple[Path, ...] = ()
    lang: str = "en"
    duration_s: float | None = None
    host: str = DEFAULT_HOST
    port: int = DEFAULT_PORT
    token_scrypt: str | None = None
    require_token: bool = False
    origins: tuple[str, ...] = ()
    out_dir: Path | None = None

    def with_(self, **changes: object) -> PanelSettings:
        return replace(self, **changes)  # type: ignore[arg-type]


def read_panel_file(path: Path) -> PanelConfig:
    """The panel settings file, validated as the bench config's ``panel:`` section
    (``ConfigError`` naming the file and the field); relative paths from its folder."""
    data = read_yaml(path, "panel settings") or {}
    try:
        model = PanelConfig.model_validate(data)
    except ValidationError as e:
        raise ConfigError(invalid(path, "panel settings", e)) from None
    return model.resolved(path.parent)


def plan_files(entries: list[Path] | tuple[Path, ...]) -> tuple[Path, ...]:
    """Each entry a plan file (``ConfigError`` for one that is not there)."""
    for entry in entries:
        if not entry.is_file():
            raise ConfigError(f"{entry}: no such plan file (serve --plan)")
    return tuple(entries)


def profile_files(entries: list[Path] | tuple[Path, ...]) -> tuple[Path, ...]:
    """Each entry a profile file, or a folder whose ``*.yaml`` files are profiles (sorted);
    ``ConfigError`` for one that is neither, or for no profile at all."""
    out: list[Path] = []
    for entry in entries:
        if entry.is_dir():
            out.extend(sorted(entry.glob("*.yaml")))
        elif entry.is_file():
            out.append(entry)
        else:
            raise ConfigError(f"{entry}: no such profile file or folder (serve --profile)")
    if not out:
        raise ConfigError("no motion profile for the operator to choose: give --profile FILE "
                          "or --profile FOLDER, or profiles: in the panel settings file")
    seen: dict[str, Path] = {}
    for p in out:
        seen.setdefault(str(p.resolve()), p)
    return tuple(seen.values())
