"""The bench config's station-wide sections: ``unit:`` (the unit under test), ``archive:``
(the results archive) and ``panel:`` (the station's web panel)."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal
from urllib.parse import urlsplit

from pydantic import (
    Field,
    field_validator,
)

from benchctl.config.types import (
    Strict,
)
from benchctl.text import PART_NUMBER_MAX
from benchctl.text import problem as text_problem

_ARCHIVE_URL = re.compile(r"(sqlite:///.+|(postgresql|postgres)(\+psycopg)?://.+)\Z", re.S)


class ArchiveConfig(Strict):
    """The results archive (``benchctl.archive``): every run stored in a database.
    ``url``: ``sqlite:///PATH`` (a relative PATH against this config's folder) or
    ``postgresql+psycopg://USER@HOST[:PORT]/DB`` for a line of benches sharing one (its
    password best from libpq's own sources — ``~/.pgpass``, ``PGPASSFILE``, ``PGPASSWORD``, a
    service file — not written here; never written anywhere by benchctl either way);
    None: ``sqlite:///<run.output_dir>/archive.sqlite``. ``queue_dir``: where records wait
    while the database cannot be reached (None: ``<run.output_dir>/archive-queue``).
    ``write_timeout_s``: how long a statement waits for a lock (a busy SQLite file) before
    the record is queued; any one statement is given twice this."""

    enabled: bool = True
    """Store every run in the archive."""
    url: str | None = None
    """`sqlite:///PATH` (a relative PATH against this file's folder) or
    `postgresql+psycopg://USER@HOST[:PORT]/DB` (its password from libpq's own sources, never here);
    none: `sqlite:///<run.output_dir>/archive.sqlite`."""
    queue_dir: Path | None = None
    """Where records wait while the database cannot be reached (none:
    `<run.output_dir>/archive-queue`)."""
    connect_timeout_s: Annotated[float, Field(gt=0, le=30, allow_inf_nan=False)] = 2.0
    """How long a connection to the database may take (s)."""
    write_timeout_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    """How long a statement waits for a lock (a busy SQLite file) before the record is queued (s);
    any one statement is given twice this."""

    @field_validator("url")
    @classmethod
    def _url(cls, v: str | None) -> str | None:
        if v is not None and not _ARCHIVE_URL.match(v):
            raise ValueError(
                "expected sqlite:///PATH or postgresql+psycopg://USER@HOST[:PORT]/DB"
            )
        if v is not None and not v.startswith("sqlite"):
            try:
                urlsplit(v).port  # noqa: B018 (a port that is not a number raises)
            except ValueError:
                raise ValueError(
                    "the port is not a number 0-65535: expected "
                    "postgresql+psycopg://USER@HOST[:PORT]/DB"
                ) from None
        return v


def plain_text(v: str | None, max_chars: int, what: str) -> str | None:
    """A name or number for people to read (``benchctl.text``): printable, at most
    ``max_chars`` characters, the whitespace around it removed; else a ``ValueError`` saying
    what is wrong."""
    if v is None:
        return None
    s = v.strip()
    bad = text_problem(s, max_chars, what)
    if bad is not None:
        raise ValueError(bad)
    return s


MAX_SERIAL_PATTERN = 200  # characters of unit.serial_pattern


class UnitConfig(Strict):
    """The unit under test: its part number (the serial is given per run: --serial) and the
    form every serial typed for it must have, ``serial_pattern``: a Python regular expression
    the whole serial must match (e.g. ``SN-[0-9]{6}``), checked before anything opens.
    ``serial_check``: what a serial typed unlike the one the instrument reports does —
    ``warn`` (the default: a warning, the run goes on) or ``require`` (a precheck: the run is
    refused before the stand moves, as is an instrument that reports no serial)."""

    part_number: str | None = None
    """The unit's part number, into every record."""
    serial_pattern: str | None = Field(default=None, min_length=1, max_length=MAX_SERIAL_PATTERN)
    """A Python regular expression every serial typed for this unit must wholly match (e.g.
    `SN-[0-9]{6}`), checked before anything opens."""
    serial_check: Literal["warn", "require"] = "warn"
    """A serial typed unlike the one the instrument reports: `warn` (a warning, the run goes on) or
    `require` (the run is refused before the stand moves, as is an instrument that reports no
    serial)."""

    @field_validator("part_number")
    @classmethod
    def _part_number(cls, v: str | None) -> str | None:
        return plain_text(v, PART_NUMBER_MAX, "part number")

    @field_validator("serial_pattern")
    @classmethod
    def _serial_pattern(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                re.compile(v)
            except re.error as e:
                raise ValueError(f"expected a regular expression: {e}") from None
        return v


class PanelConfig(Strict):
    """The station's web panel (``benchctl serve``): what its operator sees and may choose.
    ``lang``: the language of every text the operator reads (en, ru). ``profiles``: the motion
    profiles offered (files, or folders whose ``*.yaml`` files are profiles); ``plans``: the
    acceptance plans offered; ``duration_s``: each run's duration (None: the profile's own).
    ``host``/``port``: where it listens (loopback by default; another address needs
    ``token_scrypt``, the hash ``benchctl serve --hash-token`` prints — never the token).
    ``require_token``: ask for the token on loopback too (behind a reverse proxy).
    ``origins``: the addresses browsers reach it by, behind a proxy. ``out_dir``: the runs'
    folder (None: ``run.output_dir``). Relative paths resolve against this config's folder;
    ``benchctl serve``'s options override each field."""

    lang: Literal["en", "ru"] = "en"
    """The language of every text the operator reads (en, ru)."""
    profiles: list[Path] = Field(default_factory=list)
    """The motion profiles offered: files, or folders whose `*.yaml` files are profiles."""
    plans: list[Path] = Field(default_factory=list)
    """The acceptance plans offered."""
    duration_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    """Each run's duration (s); none: the profile's own."""
    host: str = "127.0.0.1"
    """The address the panel listens on (loopback by default; another address needs token_scrypt).
    """
    port: Annotated[int, Field(ge=0, le=65535)] = 8350
    """The port the panel listens on."""
    token_scrypt: str | None = None
    """The hash of the operators' token that `benchctl serve --hash-token` prints (never the token
    itself)."""
    require_token: bool = False
    """Ask for the token on loopback too (behind a reverse proxy)."""
    origins: list[str] = Field(default_factory=list)
    """The addresses browsers reach the panel by, behind a proxy."""
    out_dir: Path | None = None
    """The runs' folder (none: run.output_dir)."""

    def resolved(self, base: Path) -> PanelConfig:
        """The same with its relative paths taken from ``base`` (a folder)."""
        def rel(p: Path) -> Path:
            return p if p.is_absolute() else base / p

        return self.model_copy(update={
            "profiles": [rel(p) for p in self.profiles],
            "plans": [rel(p) for p in self.plans],
            "out_dir": None if self.out_dir is None else rel(self.out_dir),
        })
