"""The run's record: ``record.json`` in the recording folder at the end of every run.

One JSON object per run — passed, failed, inconclusive or aborted — shaped like the line-data
conventions (IPC-CFX ``UnitsTested``, HardPy's run record): the unit under test (serial typed,
serial reported, part number), operator and station, the stand with its identity and
calibration due date, the instruments with their identities, the profile (name, kind, seed,
SHA-256), the config's SHA-256, every measurement with its limits and outcome, the decision
rule, deviations, warnings, an abort's kind and reason, and the files with their SHA-256.

Its JSON Schema is versioned in the package: ``benchctl/schemas/record-1.schema.json``
(``benchctl schema record`` prints it). ``schema`` in a record names the version it follows.

- :func:`build_record` builds one from the recording's metadata and the results;
- :func:`write_record` writes ``<dir>/record.json`` (strict JSON, atomically) after
  validating it; :func:`load_record` reads and validates one; :func:`validate_record` raises
  ``DataError`` naming the key and the expectation.

An abort's ``kind`` (:func:`abort_kind`): ``operator`` — a signal (Ctrl-C, SIGTERM, SIGHUP,
SIGQUIT: someone stopped it); ``equipment`` — a device fault or error, a failed precheck, a
safety stop (tracking, silent instrument, limit, excitation), a recording that cannot be
written; ``software`` — an unexpected exception or a failed internal cross-check of the
analysis (a bug).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator

from benchctl import __version__
from benchctl.clock import REAL, Clock
from benchctl.config import axis_map
from benchctl.errors import AnalysisError, BenchError, DataError
from benchctl.fileout import atomic_write_text
from benchctl.jsonout import dumps, load_object, plain
from benchctl.outcomes import ExitCode, Outcome
from benchctl.results.measurements import RULE_TEXT, Measurement, reported_serial, serial_match

SCHEMA_ID = "benchctl-record/1"
SCHEMA_FILE = "record-1.schema.json"
RECORD_JSON = "record.json"
ABORT_KINDS = ("operator", "equipment", "software")


@cache
def record_schema() -> dict[str, Any]:
    """The record's JSON Schema (draft 2020-12), from the package."""
    text = resources.files("benchctl.schemas").joinpath(SCHEMA_FILE).read_text("utf-8")
    schema: dict[str, Any] = json.loads(text)
    return schema


def schema_text() -> str:
    """The schema as it is shipped (``benchctl schema record``)."""
    return resources.files("benchctl.schemas").joinpath(SCHEMA_FILE).read_text("utf-8")


def validate_record(record: Mapping[str, Any]) -> None:
    """Raise ``DataError`` unless ``record`` is valid against the schema (every problem
    listed: where in the record, what was found, what was expected)."""
    v = Draft202012Validator(record_schema())
    errors = sorted(v.iter_errors(plain(record)), key=lambda e: list(e.absolute_path))
    if errors:
        parts = []
        for e in errors[:10]:
            where = "/".join(str(p) for p in e.absolute_path) or "(top)"
            parts.append(f"{where}: {e.message}")
        more = f" (and {len(errors) - 10} more)" if len(errors) > 10 else ""
        raise DataError(f"record not valid against {SCHEMA_ID}: " + "; ".join(parts) + more)


def sha256_file(path: Path | str | None) -> str | None:
    """SHA-256 of a file's bytes, or None when there is no such readable file."""
    if path is None:
        return None
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    except OSError:
        return None
    return h.hexdigest()


# the recording's data files: what the run measured and recorded, each final once the
# recording is closed (logs and the reports beside them are not data; the CAN log, when the
# instrument is on CAN, under the name instrument.can_log gives it)
DATA_FILES = ("meta.json", "stand.csv", "instrument.csv", "setpoints.csv", "events.jsonl",
              "end.json")
RECORDING_HASH_DEFINITION = (
    "SHA-256 of the lines '<sha256>  <name>' (64 lowercase hex digits, two spaces, the file's "
    "name, a newline), one per data file, sorted by name: the output of sha256sum run on the "
    "files in that order"
)


def _can_log_name(meta: Mapping[str, Any] | None) -> str | None:
    cfg = (meta or {}).get("config") or {}
    inst = cfg.get("instrument") if isinstance(cfg, Mapping) else None
    if not isinstance(inst, Mapping) or inst.get("driver") == "nmea0183":
        return None
    name = inst.get("can_log")
    return str(name) if isinstance(name, str) and name else None


def data_hashes(folder: Path, meta: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """SHA-256 of each data file of the recording in ``folder`` as it is on the disk, and of
    the recording as a whole (``RECORDING_HASH_DEFINITION``): ``{algorithm, files: [{name,
    bytes, sha256}] sorted by name, recording_sha256, definition}``. ``meta`` (``meta.json``'s
    content) names the CAN log; a data file that is not there is left out."""
    folder = Path(folder)
    names = set(DATA_FILES)
    can = _can_log_name(meta)
    if can is not None:
        names.add(can)
    files = []
    for name in sorted(names):
        path = folder / name
        if not path.is_file() or path.resolve().parent != folder.resolve():
            continue
        digest = sha256_file(path)
        if digest is None:
            continue
        files.append({"name": name, "bytes": path.stat().st_size, "sha256": digest})
    manifest = "".join(f"{f['sha256']}  {f['name']}\n" for f in files)
    return {
        "algorithm": "sha256",
        "files": files,
        "recording_sha256": hashlib.sha256(manifest.encode("utf-8")).hexdigest(),
        "definition": RECORDING_HASH_DEFINITION,
    }


def with_data(record: Mapping[str, Any], folder: Path,
              meta: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """A copy of ``record`` with ``data``: the recording's data files and their hashes as
    they are now (:func:`data_hashes`) — made once the recording is closed."""
    out = dict(record)
    out["data"] = data_hashes(folder, meta)
    return out


def abort_kind(error: BaseException | None, source: str | None = None) -> str:
    """``operator``, ``equipment`` or ``software`` for the first fault of an aborted run (see
    the module notes)."""
    if source == "signal" or isinstance(error, KeyboardInterrupt):
        return "operator"
    if isinstance(error, AnalysisError):
        return "software"
    if isinstance(error, BenchError):
        return "equipment"
    return "software"


def _file(path: Path | None) -> dict[str, str] | None:
    if path is None:
        return None
    digest = sha256_file(path)
    return None if digest is None else {"path": str(path), "sha256": digest}


def _profile_kind(profile: Any) -> str | None:
    if not isinstance(profile, Mapping):
        return None
    spec = profile.get("spec")
    kind = spec.get("kind") if isinstance(spec, Mapping) else None
    kind = kind or profile.get("kind")
    return None if kind is None else str(kind)


def build_record(
    meta: Mapping[str, Any],
    *,
    recording: Path,
    outcome: Outcome,
    measurements: Iterable[Measurement | Mapping[str, Any]] = (),
    decision_rule: str = "simple",
    abort: Mapping[str, Any] | None = None,
    deviations: Iterable[str] = (),
    warnings: Iterable[str] = (),
    report_json: Path | None = None,
    report_txt: Path | None = None,
    log: Path | None = None,
    exit_code: ExitCode | None = None,
    end_utc: str | None = None,
    clock: Clock = REAL,
) -> dict[str, Any]:
    """The record of one run from the recording's metadata (``meta.json``: serial, operator,
    station, devices, profile, seed, config, start time, software version, hashes) and its
    results. ``abort``: {kind, reason, …} for an aborted run (``outcome`` ABORTED).
    ``end_utc``: else now on ``clock`` (the run's)."""

    devices = meta.get("devices") or {}
    dut = devices.get("instrument")
    typed = str(meta.get("serial") or "")
    reported = reported_serial(dut)
    config = meta.get("config") or {}
    stand_cfg = config.get("stand") or {}
    unit_cfg = config.get("unit") or {}
    profile = meta.get("profile") or {}
    part = meta.get("part_number") or unit_cfg.get("part_number")
    due = stand_cfg.get("calibration_due")
    ms = [m.to_dict() if isinstance(m, Measurement) else dict(m) for m in measurements]
    record = {
        "schema": SCHEMA_ID,
        "run_id": recording.name,
        "software": {"name": "benchctl",
                     "version": str(meta.get("software_version") or __version__)},
        "outcome": outcome,
        "exit_code": exit_code,
        "abort": None if abort is None else dict(abort),
        "decision_rule": {"name": decision_rule, "text": RULE_TEXT.get(decision_rule, "")},
        "deviations": list(deviations),
        "warnings": list(warnings),
        "start_utc": meta.get("start_utc"),
        "end_utc": end_utc or clock.now_utc().isoformat(timespec="milliseconds"),
        "unit": {
            "serial": typed,
            "part_number": None if part is None else str(part),
            "reported_serial": reported,
            "serial_match": serial_match(typed, reported),
        },
        "operator": str(meta.get("operator") or ""),
        "station": str(meta.get("station") or ""),
        "stand": {"identity": devices.get("stand"),
                  "calibration_due": None if due is None else str(due)[:10]},
        "timing": _timing(config.get("timing")),
        "instruments": [{"role": "dut", "identity": dut,
                         "axes": _instrument_axes(config.get("instrument") or {})}],
        "profile": {
            "name": meta.get("profile_name"),
            "kind": _profile_kind(profile),
            "seed": meta.get("seed"),
            "sha256": meta.get("profile_sha256"),
            "path": meta.get("profile_path"),
            "scale": meta.get("scale"),
        },
        "config_sha256": meta.get("config_sha256"),
        "measurements": ms,
        "files": {
            "recording": str(recording.resolve()),
            "report_json": _file(report_json),
            "report_txt": _file(report_txt),
            "log": None if log is None else str(log),
        },
    }
    if exit_code is None:
        del record["exit_code"]
    out: dict[str, Any] = plain(record)
    return out


def _timing(timing: Any) -> dict[str, Any] | None:
    """The config's ``timing:`` section as the record states it (None: a config without one,
    from a benchctl before the bench's timing calibration)."""
    if not isinstance(timing, Mapping):
        return None
    cal = timing.get("calibrated")
    return {"offset_s": float(timing.get("offset_s") or 0.0),
            "uncertainty_s": float(timing.get("uncertainty_s") or 0.0),
            "calibrated": None if cal is None else str(cal)[:10],
            "reference": timing.get("reference")}


def _instrument_axes(instrument: Mapping[str, Any]) -> dict[str, Any] | None:
    """``instrument.axes`` of the run's config as {stand axis: {output, sign}} (the axis
    mapping every sample was read with); an older config's list of names is the identity."""

    axes = instrument.get("axes")
    if not axes:
        return None
    return {a: {"output": o, "sign": s} for a, (o, s) in axis_map(axes).items()}


def with_file(record: Mapping[str, Any], key: str, path: Path | None) -> dict[str, Any]:
    """A copy of ``record`` whose ``files[key]`` is ``{path, sha256}`` of ``path`` (None when
    there is no such readable file): e.g. ``report_html``, written after the record was built
    (the report shows the record's content, the record names the report's hash)."""
    out = dict(record)
    out["files"] = {**dict(record.get("files") or {}), key: _file(path)}
    return out


def write_record(folder: Path, record: Mapping[str, Any]) -> Path:
    """Validate ``record`` and write it as ``<folder>/record.json`` (strict JSON; a temporary
    file renamed over it, so a reader never sees half a record)."""
    validate_record(record)
    dest = folder / RECORD_JSON
    atomic_write_text(dest, dumps(record, indent=2) + "\n")  # no .tmp left when it fails
    return dest


def load_record(path: Path | str) -> dict[str, Any]:
    """A record from ``record.json`` (or a recording folder holding one), validated."""
    return load_object(path, RECORD_JSON, "record", validate_record)


__all__ = [
    "ABORT_KINDS",
    "DATA_FILES",
    "RECORDING_HASH_DEFINITION",
    "RECORD_JSON",
    "SCHEMA_ID",
    "abort_kind",
    "build_record",
    "data_hashes",
    "load_record",
    "record_schema",
    "schema_text",
    "sha256_file",
    "validate_record",
    "with_data",
    "with_file",
    "write_record",
]
