"""A whole bench config: ``BenchConfig``, read from a YAML file and checked across its
sections (``load_config``, ``parse_config``), and its JSON Schema (``config_schema``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import (
    Field,
    ValidationError,
    field_validator,
)
from pydantic.json_schema import SkipJsonSchema

from benchctl.config.instrument import InstrumentConfig
from benchctl.config.run import RunConfig
from benchctl.config.sim import SimConfig
from benchctl.config.stand import StandConfig, exchange_bound_s
from benchctl.config.station import ArchiveConfig, PanelConfig, UnitConfig, plain_text
from benchctl.config.timing import TimingConfig
from benchctl.config.types import (
    Strict,
)
from benchctl.errors import ConfigError
from benchctl.faultspec import (
    FaultSpecError,
    check_params,
)
from benchctl.text import STATION_MAX
from benchctl.validation import invalid, shown_value
from benchctl.yamlfile import read_yaml


class BenchConfig(Strict):
    """A bench: the stand, the instrument under test, the run's rules, and optionally the
    simulators, the archive and the web panel."""

    station: str = "bench"
    """The bench's name, into every record and on the panel."""
    unit: UnitConfig = UnitConfig()
    """The unit under test: its part number and the form of its serials."""
    stand: StandConfig
    """The motion stand: its link, register map, limits and how the motion reaches it."""
    instrument: InstrumentConfig
    """The instrument under test: its protocol, link and expected rate."""
    run: RunConfig
    """The run: its verdict limit, decision rule, checks and outputs."""
    timing: TimingConfig = TimingConfig()
    """The bench's own stream-to-stream delay, as its timing calibration measured it (applied
    to every run's analysis)."""
    sim: SimConfig | None = None
    """Present: a simulated bench (`benchctl run` starts the simulators itself)."""
    archive: ArchiveConfig = ArchiveConfig()
    """The results archive: every run stored in a database."""
    panel: PanelConfig | None = None
    """The station's web panel (`benchctl serve`)."""

    source: SkipJsonSchema[Path | None] = Field(default=None, exclude=True)
    """The file the config came from (set when it is loaded; not a field of the file)."""

    @field_validator("station")
    @classmethod
    def _station(cls, v: str) -> str:
        return plain_text(v, STATION_MAX, "station name") or ""


_PATH_FIELDS = {
    ("stand", "register_map"),
    ("instrument", "eds"),
    ("instrument", "dbc"),
    ("run", "output_dir"),
    ("run", "lock_dir"),
    ("archive", "queue_dir"),
}


def _check_fault_transports(cfg: BenchConfig, source: Path) -> None:
    """A scheduled ``garbled`` fault's ``how`` must suit the instrument's driver."""
    if cfg.sim is None:
        return
    for i, fault in enumerate(cfg.sim.faults):
        if fault.target != "instrument":
            continue
        try:
            check_params("instrument", fault.kind, fault.params, driver=cfg.instrument.driver)
        except FaultSpecError as e:
            raise ConfigError(
                f"{source}: invalid bench config: field sim.faults[{i}].{e.field} = "
                f"{shown_value(e.value)}: expected {e.expected} (instrument.driver)"
            ) from None


def _check_watchdog(cfg: BenchConfig, source: Path) -> None:
    """One exchange at its longest plus the heartbeat period must fit inside the stand's
    watchdog (``stand.watchdog_s``, or the simulated stand's ``sim.stand.watchdog_s``): a link
    allowed to wait longer for a reply than the stand waits for a heartbeat lets the stand stop
    itself mid-run on a reply that was merely slow."""
    st = cfg.stand
    where, watchdog = "stand.watchdog_s", st.watchdog_s
    if cfg.sim is not None:
        sim_wd = cfg.sim.stand.watchdog_s
        if watchdog is not None and watchdog != sim_wd:
            raise ConfigError(
                f"{source}: invalid bench config: field stand.watchdog_s = {watchdog:g} s: "
                f"expected the simulated stand's, sim.stand.watchdog_s = {sim_wd:g} s (with a "
                "`sim:` section the simulator is the stand)"
            )
        where, watchdog = "sim.stand.watchdog_s", sim_wd
    if watchdog is None:
        return
    need = exchange_bound_s(st)
    if need > watchdog * (1 + 1e-9):
        raise ConfigError(
            f"{source}: invalid bench config: fields stand.timeout_s = {st.timeout_s:g} s × "
            f"(stand.retries = {st.retries} + 1) + stand.heartbeat_period_s = "
            f"{st.heartbeat_period_s:g} s = {need:g} s: expected at most the stand's watchdog, "
            f"{where} = {watchdog:g} s (one exchange may wait out every try's reply timeout, and "
            "the heartbeat waits behind it: the stand would stop itself mid-run on a slow reply)"
        )


def parse_config(data: Any, source: Path) -> BenchConfig:
    """Validate a config mapping; relative paths resolve against ``source``'s folder."""
    if not isinstance(data, dict):
        raise ConfigError(
            f"{source}: expected a YAML mapping at the top level, got {type(data).__name__}"
        )
    try:
        cfg = BenchConfig.model_validate({**data, "source": source})
    except ValidationError as err:
        raise ConfigError(invalid(source, "bench config", err)) from None
    _check_fault_transports(cfg, source)
    _check_watchdog(cfg, source)
    base = source.parent
    updates: dict[str, Any] = {}
    for section, name in sorted(_PATH_FIELDS):
        sub = getattr(cfg, section)
        value = getattr(sub, name)
        if isinstance(value, Path) and not value.is_absolute():
            try:
                updates.setdefault(section, {})[name] = (base / value).resolve()
            except (OSError, ValueError) as e:
                raise ConfigError(
                    f"{source}: invalid bench config: field {section}.{name} = "
                    f"{shown_value(str(value))}: not a usable path ({e})"
                ) from None
    for section, fields in updates.items():
        cfg = cfg.model_copy(update={section: getattr(cfg, section).model_copy(update=fields)})
    if cfg.panel is not None:
        cfg = cfg.model_copy(update={"panel": cfg.panel.resolved(base)})
    return cfg


CONFIG_SCHEMA_ID = "urn:benchctl:schema:bench-config"
CONFIG_SCHEMA_FILE = "bench-config.schema.json"  # in benchctl/schemas/, for editors


def config_schema() -> dict[str, Any]:
    """The bench config's JSON Schema (draft 2020-12), from the models that validate it: every
    section and field with its type, default, bounds and meaning. ``benchctl schema config``
    prints it; ``benchctl/schemas/bench-config.schema.json`` is the same, shipped for editors
    (a config's first line ``# yaml-language-server: $schema=…`` names it)."""
    schema = _one_line(BenchConfig.model_json_schema(mode="validation"))
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": CONFIG_SCHEMA_ID,
        "title": "benchctl bench config",
        **{k: v for k, v in schema.items() if k != "title"},
    }


def _one_line(node: Any) -> Any:
    """Descriptions as editors show them: a docstring's line breaks become spaces (a blank line
    between paragraphs stays)."""
    if isinstance(node, dict):
        return {
            k: ("\n\n".join(" ".join(p.split()) for p in v.split("\n\n"))
                if k == "description" and isinstance(v, str) else _one_line(v))
            for k, v in node.items()
        }
    if isinstance(node, list):
        return [_one_line(v) for v in node]
    return node


def config_schema_text() -> str:
    """``config_schema()`` as the shipped file has it (indented, UTF-8, one final newline)."""
    return json.dumps(config_schema(), indent=2, ensure_ascii=False, allow_nan=False) + "\n"


def load_config(path: str | Path) -> BenchConfig:
    """Read and validate a bench config YAML file."""
    p = Path(path)
    return parse_config(read_yaml(p, "bench config"), p)
