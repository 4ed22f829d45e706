"""Reading profile files: YAML → validated spec → :class:`Profile` (recorded spectra estimated).

This is the I/O edge of the profiles package. Every problem raises ``ConfigError`` naming the
profile file and the field (a measured record that is unusable raises ``DataError`` naming the
CSV file, column and row).
"""

from __future__ import annotations

import csv
import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import TypeAdapter, ValidationError

from benchctl.errors import ConfigError, DataError
from benchctl.profiles.records import RecordedSpectrum, estimate_psd
from benchctl.profiles.schema import (
    KINDS,
    ProfileSpec,
    RecordedAxisSpec,
    RecordedProfile,
    SineStepsProfile,
)
from benchctl.textfile import MAX_CSV_BYTES, decode_utf8, read_input
from benchctl.validation import invalid
from benchctl.yamlfile import read_yaml

_ADAPTER: TypeAdapter[Any] = TypeAdapter(ProfileSpec)


@dataclass(frozen=True)
class Profile:
    """A validated profile.

    Contract (relied on by the run layer): ``name``, ``kind``, ``axes`` (tuple of "roll" /
    "pitch"), ``duration_s``, ``seed``, ``to_dict()`` (JSON-able, stored in the recording's
    metadata), ``source`` (the file, or None).
    """

    spec: Any  # one of the models in benchctl.profiles.schema
    source: Path | None = None
    recorded: dict[str, RecordedSpectrum] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return str(self.spec.name)

    @property
    def kind(self) -> str:
        return str(self.spec.kind)

    @property
    def axes(self) -> tuple[str, ...]:
        return tuple(self.spec.axes)

    @property
    def seed(self) -> int:
        return int(self.spec.seed)

    @property
    def duration_s(self) -> float:
        """The profile's own duration; for sine_steps, the length of the whole sequence."""
        if isinstance(self.spec, SineStepsProfile):
            return sine_steps_duration(self.spec)
        return float(self.spec.duration_s)

    def to_dict(self) -> dict[str, Any]:
        """The profile as JSON-able data: its fields, its file, and for recorded kinds the
        SHA-256 and sample count of each CSV."""
        d: dict[str, Any] = {
            "source": str(self.source) if self.source else None,
            "spec": self.spec.model_dump(mode="json"),
            "duration_s": self.duration_s,
        }
        if self.recorded:
            d["recorded"] = {a: r.to_dict() for a, r in self.recorded.items()}
        return d

    def label(self, field_path: str) -> str:
        return f"{self.source or '<profile>'}: field {field_path}"


def sine_steps_duration(spec: SineStepsProfile) -> float:
    """Total length of a sine_steps sequence: per axis, per period, per amplitude,
    ``rest_s + (cycles + 2·fade_cycles)·period``, then a final ``rest_s``."""
    one_axis = sum(
        len(spec.amplitudes_deg) * (spec.rest_s + (spec.cycles + 2 * spec.fade_cycles) * p)
        for p in spec.periods_s
    )
    return len(spec.axes) * one_axis + spec.rest_s


def _kinds() -> tuple[str, ...]:

    return KINDS


def parse_profile(data: Any, source: Path | str | None = None) -> Profile:
    """Validate a profile mapping. Relative CSV paths resolve against ``source``'s folder."""
    label = str(source) if source is not None else "<profile>"
    if not isinstance(data, dict):
        raise ConfigError(
            f"{label}: expected a YAML mapping at the top level, got {type(data).__name__}"
        )
    if "kind" not in data:
        raise ConfigError(f"{label}: field kind missing; expected one of {', '.join(_kinds())}")
    try:
        spec = _ADAPTER.validate_python(data)
    except ValidationError as err:
        msg = invalid(label, "profile", err, tag=data.get("kind"), tags=_kinds)
        raise ConfigError(msg) from None
    src = Path(source) if source is not None else None
    recorded: dict[str, RecordedSpectrum] = {}
    if isinstance(spec, RecordedProfile):
        base = src.parent if src is not None else Path.cwd()
        for axis, ax in spec.axes.items():
            recorded[axis] = _load_record(label, axis, ax, base)
    return Profile(spec, src, recorded)


def load_profile(path: str | Path) -> Profile:
    """Read and validate a profile YAML file.

    Raises ``ConfigError`` naming the file and field on any problem (unreadable file, bad
    YAML, unknown kind or field, a value out of range, a missing CSV); ``DataError`` when a
    recorded CSV is unusable. Relative CSV paths resolve against the profile file's folder.
    """
    p = Path(path)
    return parse_profile(read_yaml(p, "profile"), p)


def read_angle_csv(
    path: Path, time_column: str, angle_column: str
) -> tuple[np.ndarray, np.ndarray]:
    """Two numeric columns of a CSV (header row; ``#`` lines skipped). ``DataError`` names the
    file, column and row of any missing column, non-number, NaN or non-increasing time; and
    a file that is not a regular file of at most ``MAX_CSV_BYTES`` (``benchctl.textfile``)."""
    raw = read_input(path, "CSV", DataError, MAX_CSV_BYTES)  # a regular file, bounded
    return _angle_csv(raw, path, time_column, angle_column)


def _angle_csv(
    raw: bytes, path: Path, time_column: str, angle_column: str
) -> tuple[np.ndarray, np.ndarray]:
    text = decode_utf8(raw, path, "CSV", DataError)
    numbered = (
        (n, line.removesuffix("\r"))
        for n, line in enumerate(text.split("\n"), start=1)
        if not line.lstrip().startswith("#")
    )
    header: list[str] | None = None
    t_list: list[float] = []
    x_list: list[float] = []
    rows_at: list[int] = []  # the file line of each sample
    it = ia = 0
    for n, line in numbered:
        if "\0" in line:
            raise DataError(f"{path}: line {n}: a NUL character; expected a text CSV")
        try:
            row = next(csv.reader([line]), [])
        except csv.Error as e:
            raise DataError(f"{path}: line {n}: not CSV ({e})") from None
        if header is None:
            header = [h.strip() for h in row]
            for col in (time_column, angle_column):
                if col not in header:
                    raise DataError(f"{path}: no column {col!r}; columns are {header}")
            it, ia = header.index(time_column), header.index(angle_column)
            continue
        if not row:
            continue
        for col, i, out in ((time_column, it, t_list), (angle_column, ia, x_list)):
            try:
                v = float(row[i])
            except (IndexError, ValueError):
                cell = row[i] if i < len(row) else ""
                msg = f"{path}: row {n} column {col}: {cell!r} is not a number"
                raise DataError(msg) from None
            if not math.isfinite(v):
                raise DataError(f"{path}: row {n} column {col}: {v!r} is not finite")
            out.append(v)
        rows_at.append(n)
    if header is None:
        raise DataError(
            f"{path}: empty file, expected a header with {time_column},{angle_column}"
        )
    t = np.asarray(t_list)
    x = np.asarray(x_list)
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        raise DataError(
            f"{path}: column {time_column} must increase; row {rows_at[bad[0] + 1]} has "
            f"{t[bad[0] + 1]!r} after {t[bad[0]]!r}"
        )
    return t, x


def _load_record(label: str, axis: str, ax: RecordedAxisSpec, base: Path) -> RecordedSpectrum:
    path = ax.csv if ax.csv.is_absolute() else (base / ax.csv)
    if not path.exists():
        raise ConfigError(
            f"{label}: field axes.{axis}.csv = {str(ax.csv)!r}: file not found ({path})"
        )
    raw = read_input(path, "CSV", DataError, MAX_CSV_BYTES)  # read once: parsed and hashed
    t, x = _angle_csv(raw, path, ax.time_column, ax.angle_column)
    if ax.angle_unit == "rad":
        x = np.degrees(x)
    digest = hashlib.sha256(raw).hexdigest()
    try:
        return estimate_psd(t, x, ax.segment_s, source=str(path), sha256=digest)
    except ValueError as e:
        raise DataError(f"{path}: {e} (profile {label}, axes.{axis})") from None
