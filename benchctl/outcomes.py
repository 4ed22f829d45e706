"""What a run, a plan or a measurement came to (``Outcome``), what a command exits with
(``ExitCode``), and the one mapping between them (``Outcome.exit_code``).

Both are ``StrEnum``/``IntEnum``: an ``Outcome`` is its name as a string and an ``ExitCode`` its
number wherever they are written or printed (JSON, JUnit XML, the report, the terminal), so
``Outcome.PASS == "PASS"`` and ``ExitCode.FAIL == 1``.

Outcomes, and where each is used:

========================  =====================================================================
``PASS``, ``FAIL``,       a measurement judged by the decision rule, a run's verdict, a plan
``INCONCLUSIVE``          step's status, a plan's outcome
``ABORTED``               a run or a plan step that did not end (a fault, a signal, a timeout),
                          a plan with an abort or an error anywhere in it
``NOT_JUDGED``            a measurement without limits (recorded for information)
``WARNING``               an informative measurement beyond its limit (it decides nothing)
``ERROR``                 a plan step that could not start
``SKIPPED``               a plan step not run
``INCOMPLETE``            a report's verdict for a recording its run never closed (no end.json)
========================  =====================================================================

Exit codes: 0 PASS (or success), 1 a measured FAIL, 2 everything else (bad input, a device
fault, an abort, a signal, an unexpected exception), 3 INCONCLUSIVE.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import IntEnum, StrEnum
from types import MappingProxyType


class ExitCode(IntEnum):
    """The exit code of every ``benchctl`` command (and of a run or a plan, ``exit_code``)."""

    OK = 0  # PASS, or success
    FAIL = 1  # a measured FAIL, only that
    ERROR = 2  # everything else: bad input, a fault, an abort, a signal, a bug
    INCONCLUSIVE = 3  # the guarded rule: an interval straddles its limit, nothing beyond it


class Outcome(StrEnum):
    """What a run, a plan, a plan step or a measurement came to (see the module notes)."""

    PASS = "PASS"
    FAIL = "FAIL"
    INCONCLUSIVE = "INCONCLUSIVE"
    ABORTED = "ABORTED"
    NOT_JUDGED = "NOT_JUDGED"
    WARNING = "WARNING"
    ERROR = "ERROR"
    SKIPPED = "SKIPPED"
    INCOMPLETE = "INCOMPLETE"

    @property
    def exit_code(self) -> ExitCode:
        """The exit code of a run, a plan or a step with this outcome (``EXIT_CODES``);
        ``ValueError`` for one no command ends with (NOT_JUDGED, WARNING, SKIPPED,
        INCOMPLETE)."""
        try:
            return EXIT_CODES[self]
        except KeyError:
            raise ValueError(f"outcome {self}: no command ends with it, so it has no exit "
                             f"code; expected one of {', '.join(EXIT_CODES)}") from None


#: the one mapping from an outcome to its exit code
EXIT_CODES: Mapping[Outcome, ExitCode] = MappingProxyType({
    Outcome.PASS: ExitCode.OK,
    Outcome.FAIL: ExitCode.FAIL,
    Outcome.INCONCLUSIVE: ExitCode.INCONCLUSIVE,
    Outcome.ABORTED: ExitCode.ERROR,
    Outcome.ERROR: ExitCode.ERROR,
})

#: the outcomes a run ends with (``record.json``'s ``outcome``)
RUN_OUTCOMES = (Outcome.PASS, Outcome.FAIL, Outcome.INCONCLUSIVE, Outcome.ABORTED)

__all__ = ["EXIT_CODES", "RUN_OUTCOMES", "ExitCode", "Outcome"]
