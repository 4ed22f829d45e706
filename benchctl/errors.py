"""One exception tree for everything benchctl raises.

::

    BenchError                      root; the CLI maps every BenchError to exit code 2
    ├── InputError                  bad user input: a file, a column, a value
    │   ├── ConfigError             bench config or profile YAML fails validation
    │   ├── DataError               a recording/CSV is unusable (NaN, non-monotonic time, gaps…)
    │   └── LimitError              a motion exceeds the stand limits (needed vs allowed)
    ├── AnalysisError               an internal cross-check failed (Parseval): a bug, never silent
    ├── DeviceError                 a device answered with an error or could not be used
    │   ├── DeviceTimeout           no answer in time (also a TimeoutError)
    │   ├── ConnectionLost          a link dropped mid-run
    │   ├── ProtocolError           a malformed frame, bad CRC/checksum, Modbus exception
    │   │   └── ModbusException     the device returned a Modbus exception code
    │   └── StandFault              the stand reports a fault or an E-stop
    └── SafetyAbort                 the run was stopped for safety (signal, tracking error, silent
                                    instrument…); carries the reason

Example scenarios: a profile asking 30°/s from a stand allowing 20°/s raises ``LimitError``
before anything moves; a stand that stops answering raises ``DeviceTimeout``; Ctrl-C during a
run becomes ``SafetyAbort("interrupted by SIGINT")`` and goes through the one cleanup path.
"""

from __future__ import annotations


class BenchError(Exception):
    """Root of all benchctl errors."""


class InputError(BenchError):
    """Bad input from the user: a file, a field, a value. Messages name all three."""


class ConfigError(InputError):
    """A bench config or a profile failed validation."""


class DataError(InputError):
    """A recording or CSV cannot be analysed as it is."""


class LimitError(InputError):
    """A motion exceeds the stand's limits; the message gives needed vs allowed."""


class AnalysisError(BenchError):
    """An internal consistency check of the analysis failed: a bug, raised, never hidden."""


class DeviceError(BenchError):
    """A device answered with an error or could not be used."""


class DeviceTimeout(DeviceError, TimeoutError):
    """A device did not answer in time."""


class ConnectionLost(DeviceError):
    """The link to a device dropped."""


class ProtocolError(DeviceError):
    """A malformed frame, a bad CRC or checksum, an unexpected reply."""


class ModbusException(ProtocolError):
    """The device returned a Modbus exception response."""

    def __init__(self, function_code: int, exception_code: int, message: str = "") -> None:
        self.function_code = function_code
        self.exception_code = exception_code
        super().__init__(
            message
            or f"Modbus exception {exception_code} in reply to function code {function_code}"
        )


class StandFault(DeviceError):
    """The stand reports a fault (with its code) or an E-stop."""

    def __init__(self, message: str, code: int | None = None) -> None:
        self.code = code
        super().__init__(message)


class SafetyAbort(BenchError):
    """The run was stopped for safety; ``reason`` says why."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)
