"""A run's metadata: what its recording starts with (``base_meta``), what its report keeps of
it (``REPORT_META``), and what departs from the test as specified (``deviations``)."""

from __future__ import annotations

from typing import Any

from benchctl import __version__
from benchctl.config import BenchConfig
from benchctl.redact import redact
from benchctl.results.record import sha256_file
from benchctl.run.prepare import RunOptions

REPORT_META = (
    "serial",
    "operator",
    "station",
    "profile_name",
    "profile_path",
    "seed",
    "duration_s",
    "mode",
    "start_utc",
    "software_version",
    "limit_sigma_deg",
    "scale",
    "equalisation",
)


def base_meta(cfg: BenchConfig, opts: RunOptions, rule: str,
              prepared: dict[str, Any]) -> dict[str, Any]:
    """The recording's metadata at its start: the unit, the operator, the station, the software,
    the config (no password) and the profile (``prepared``: the prepared motion's metadata)."""
    return {
        "serial": opts.serial,
        "operator": opts.operator,
        "station": cfg.station,
        "software_version": __version__,
        "config_path": str(cfg.source) if cfg.source else None,
        "config": redact(cfg.model_dump(mode="json")),  # no password (archive.url)
        "mode": cfg.stand.mode,
        "limit_sigma_deg": cfg.run.limit_sigma_deg,
        "decision_rule": rule,
        "part_number": opts.part_number or cfg.unit.part_number,
        "config_sha256": sha256_file(cfg.source),
        "profile_sha256": sha256_file(prepared.get("profile_path")),
        **prepared,
    }


def deviations(prepared: dict[str, Any]) -> list[str]:
    """What departs from the test as specified (``prepared``: the prepared motion's metadata):
    a profile scaled to fit the stand."""
    out = []
    scale = prepared.get("scale")
    if scale is not None and scale != 1.0:
        out.append(f"profile scaled by {scale:g} to fit the stand limits (--scale-to-fit): "
                   "the motion is not the profile's as specified")
    return out
