"""The test session: state machine, prechecks, stand loop and recorder, supervision, report.

Entry point: ``run_test(cfg, profile_path, RunOptions(serial=…, operator=…)) -> RunResult``.
"""

from benchctl.run.session import EXIT_ABORT, EXIT_FAIL, EXIT_PASS, RunOptions, RunResult, run_test
from benchctl.run.state import RunState

__all__ = [
    "EXIT_ABORT",
    "EXIT_FAIL",
    "EXIT_PASS",
    "RunOptions",
    "RunResult",
    "RunState",
    "run_test",
]
