"""The bench configuration: one YAML file, validated strictly (unknown fields are errors).

Units are in field names. Relative paths in a config (register maps, EDS/DBC files, output
folders) are resolved against the config file's own folder, so a config works from any cwd.
A validation failure raises ``ConfigError`` naming the file, the field, the value and what
was expected; it is always fatal.

One module per section of the file: ``stand`` (``stand:``), ``instrument``
(``instrument:``), ``sim`` (``sim:``), ``run`` (``run:``), ``station`` (``unit:``,
``archive:``, ``panel:``), ``timing`` (``timing:``); ``bench`` holds the whole
(``BenchConfig``), the checks that span sections, the loader and the JSON Schema; ``types``
the strict base model and the bounded number types. Every field's meaning is on the field (an
attribute docstring), and so in the schema (``benchctl schema config``).
"""

from benchctl.config.bench import (
    CONFIG_SCHEMA_FILE,
    CONFIG_SCHEMA_ID,
    BenchConfig,
    config_schema,
    config_schema_text,
    load_config,
    parse_config,
)
from benchctl.config.instrument import AxisName, InstrumentAxis, InstrumentConfig, axis_map
from benchctl.config.run import (
    AnalysisConfig,
    EqualiseConfig,
    ExcitationConfig,
    HostCheckConfig,
    MountingCheckConfig,
    RunConfig,
    RunLimits,
)
from benchctl.config.sim import (
    CrossAxisConfig,
    SimConfig,
    SimDisturbConfig,
    SimFault,
    SimInstrumentConfig,
    SimMountingConfig,
    SimStandConfig,
    SimStandFault,
)
from benchctl.config.stand import StandConfig, StandLimits, exchange_bound_s
from benchctl.config.station import ArchiveConfig, PanelConfig, UnitConfig
from benchctl.config.timing import TimingConfig
from benchctl.config.types import (
    MAX_DEVICE_RATE_HZ,
    MAX_HOST_RATE_HZ,
    MAX_WAIT_S,
    Strict,
)
from benchctl.errors import ConfigError

__all__ = [
    "CONFIG_SCHEMA_FILE",
    "CONFIG_SCHEMA_ID",
    "MAX_DEVICE_RATE_HZ",
    "MAX_HOST_RATE_HZ",
    "MAX_WAIT_S",
    "AnalysisConfig",
    "ArchiveConfig",
    "AxisName",
    "BenchConfig",
    "ConfigError",
    "CrossAxisConfig",
    "EqualiseConfig",
    "ExcitationConfig",
    "HostCheckConfig",
    "InstrumentAxis",
    "InstrumentConfig",
    "MountingCheckConfig",
    "PanelConfig",
    "RunConfig",
    "RunLimits",
    "SimConfig",
    "SimDisturbConfig",
    "SimFault",
    "SimInstrumentConfig",
    "SimMountingConfig",
    "SimStandConfig",
    "SimStandFault",
    "StandConfig",
    "StandLimits",
    "Strict",
    "TimingConfig",
    "UnitConfig",
    "axis_map",
    "config_schema",
    "config_schema_text",
    "exchange_bound_s",
    "load_config",
    "parse_config",
]
