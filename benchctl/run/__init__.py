"""The test session: state machine, prechecks, stand loop and recorder, supervision, report.

Entry point: ``run_test(cfg, profile_path, RunOptions(serial=…, operator=…)) -> RunResult``.
"""

from benchctl.outcomes import ExitCode, Outcome
from benchctl.run.prepare import RunOptions
from benchctl.run.result import RunResult
from benchctl.run.session import run_test
from benchctl.run.state import RunState

# the exit codes by the names this package has given them (``ExitCode``)
EXIT_PASS, EXIT_FAIL, EXIT_ABORT = ExitCode.OK, ExitCode.FAIL, ExitCode.ERROR

__all__ = [
    "EXIT_ABORT",
    "EXIT_FAIL",
    "EXIT_PASS",
    "ExitCode",
    "Outcome",
    "RunOptions",
    "RunResult",
    "RunState",
    "run_test",
]
