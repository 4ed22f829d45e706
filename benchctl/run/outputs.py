"""What a finished run leaves behind, written by sinks: each output a small object handed the
run's end (``FinishedRun``) that writes it and returns the files it wrote.

The sinks, in this order, for every run, done or aborted (``benchctl.run.session`` builds the
list, handing each its writer):

- ``ReportFiles``: ``report.json``, ``report.txt`` and the analysis plots
  (``benchctl.run.report.write_report``);
- ``RecordFiles``: ``record.json`` (``benchctl.results.record``) and ``report.html``
  (``benchctl.report.html``), which name each other;
- ``Console``: the verdict's banner on the run's display;
- ``IndexLine``: the run's line in the bench's ``index.jsonl``;
- ``ResultsArchive``: the run in the results archive (``benchctl.archive``), which never
  fails and never waits long.

When (``emit``): a done run is handed to them at its verdict, before its recording is closed
(``closed`` False), for the outputs that make it done — the report files, the record and
report.html, the index line; there a failure (a full disk) is raised: the run then ends
ABORTED through its one cleanup path, its measured verdict kept — and again once its recording
is closed (``closed`` True), for the record and report.html written again with the data files'
SHA-256, the banner and the archive. An aborted run is handed to them once, its recording
closed: the record and report.html with what is known, the banner, the index line, the
archive. Once the recording is closed every sink is guarded: one that fails is a warning in
the log and the ones after it still run.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from benchctl.clock import Clock
from benchctl.config import BenchConfig
from benchctl.errors import RecordingError
from benchctl.outcomes import ExitCode, Outcome
from benchctl.results.measurements import Measurement
from benchctl.results.record import RECORD_JSON, build_record, with_data, with_file
from benchctl.run.display import Display
from benchctl.run.report import REPORT_JSON, REPORT_TXT, Report
from benchctl.run.supervisor import describe

if TYPE_CHECKING:  # imported where used: the archive pulls in SQLAlchemy
    from benchctl.archive.service import RunArchive

log = logging.getLogger(__name__)

REPORT_HTML = "report.html"  # benchctl.report.html.REPORT_HTML (imported where drawn)


@dataclass(frozen=True)
class FinishedRun:
    """A run at its end, as its outputs see it: a done run at its verdict (``closed`` False)
    or with its recording closed, an aborted one always closed."""

    outcome: Outcome  # PASS | FAIL | INCONCLUSIVE, or ABORTED
    exit_code: ExitCode
    reason: str  # the verdict, or why the run was aborted
    folder: Path  # the recording
    out_dir: Path  # the bench's output folder: index.jsonl, the archive's default place
    meta: dict[str, Any]  # the recording's metadata (meta.json, with the devices)
    decision_rule: str
    clock: Clock  # the run's: the record's end time
    measurements: Sequence[Measurement] = ()
    deviations: Sequence[str] = ()
    warnings: Sequence[str] = ()
    report: Report | None = None  # the verdict measured (an aborted run: when it got so far)
    results: dict[str, Any] = field(default_factory=dict)  # axis → analysis result (plots)
    abort: Mapping[str, Any] | None = None  # record.json's ``abort``
    measured: Mapping[str, Any] | None = None  # an aborted run's verdict measured before
    log: Path | None = None  # the run's log file
    figures: bool = True  # run.figures: the plots and the report's figures
    closed: bool = False

    def __post_init__(self) -> None:
        if self.aborted and not self.closed:
            raise ValueError("an aborted run reaches its outputs with its recording closed")

    @property
    def aborted(self) -> bool:
        return self.outcome == Outcome.ABORTED


class Sink(Protocol):
    """One output of a finished run: ``write`` returns the files it wrote (none: nothing to
    write for this run, or at this moment)."""

    name: str

    def write(self, run: FinishedRun) -> list[Path]: ...


def emit(sinks: Sequence[Sink], run: FinishedRun) -> list[Path]:
    """Hand ``run`` to each sink in order; the files they wrote, in order. Before the recording
    is closed a sink's failure is raised (the run's abort); once it is closed each sink is
    guarded, its failure a warning, and the others still run."""
    written: list[Path] = []
    for sink in sinks:
        if not run.closed:
            written += sink.write(run)
            continue
        try:
            written += sink.write(run)
        except Exception as e:
            log.warning("%s not written: %s", sink.name, describe(e), exc_info=e)
    return written


def record_in(files: Sequence[Path]) -> Path | None:
    """The ``record.json`` among ``files``, if one was written."""
    return next((f for f in files if f.name == RECORD_JSON), None)


# ------------------------------------------------------------------------------- the sinks
@dataclass
class ReportFiles:
    """report.json, report.txt and the plots of a done run, at its verdict; a file that cannot
    be written raises ``RecordingError`` (the run's abort)."""

    write_report: Callable[..., list[Path]]  # benchctl.run.report.write_report
    name = "report"

    def write(self, run: FinishedRun) -> list[Path]:
        if run.closed or run.report is None:
            return []
        return list(self.write_report(run.report, run.results, figures=run.figures))


@dataclass
class RecordFiles:
    """record.json and report.html. At a done run's verdict: written, a full disk raised as
    ``RecordingError`` (the run's abort), any other failure a warning (the recording stays the
    source of truth). Once the recording is closed: a done run's written again with the data
    files' SHA-256, both or neither; an aborted run's written once."""

    write_record: Callable[[Path, Mapping[str, Any]], Path]  # benchctl.results.record
    name = "record"

    def write(self, run: FinishedRun) -> list[Path]:
        if run.closed and not run.aborted:
            again = self._again(run)
            return [] if again is None else [again]
        record = self._once(run, strict=not run.closed)
        html = run.folder / REPORT_HTML
        return [p for p in (record, html if html.exists() else None) if p is not None]

    def _once(self, run: FinishedRun, *, strict: bool) -> Path | None:
        """The record and report.html (``closed``: with the data files' SHA-256); a record that
        cannot be written is a warning — except, with ``strict``, a full disk: raised as
        ``RecordingError``."""
        try:
            rec = record_of(run)
            html = write_html(run, rec, strict=strict)
            if html is not None:
                rec = with_file(rec, "report_html", html)
            return self.write_record(run.folder, rec)
        except Exception as e:
            full = RecordingError.disk_full(e, run.folder / RECORD_JSON)
            if strict and full is not None:
                raise full from None
            log.warning("record.json not written: %s", describe(full or e), exc_info=e)
            return None

    def _again(self, run: FinishedRun) -> Path | None:
        """The record and report.html written again once the recording is closed (with the
        data files' SHA-256), both or neither: the earlier report is kept aside (a rename, no
        room needed) and put back should either write fail, so the record.json and
        report.html that stay always name each other."""
        html, prev = run.folder / REPORT_HTML, run.folder / f"{REPORT_HTML}.prev"
        done: Path | None = None
        try:
            rec = record_of(run)
            if html.exists():
                os.replace(html, prev)
            drawn = write_html(run, rec)
            if drawn is not None:
                done = self.write_record(run.folder, with_file(rec, "report_html", drawn))
        except Exception as e:
            log.warning("record.json and report.html not written again (the earlier ones "
                        "stand, without the data files' SHA-256): %s", describe(e), exc_info=e)
        finally:
            if prev.exists():
                with contextlib.suppress(OSError):
                    if done is None:
                        os.replace(prev, html)
                    else:
                        prev.unlink()
        return done


@dataclass
class Console:
    """The verdict's banner on the run's display, once the recording is closed: a done run's
    σ per axis against its limit; an aborted run's kind and reason, the verdict measured
    before the abort, where the stand is and how to bring it to rest at zero."""

    display: Display
    name = "console"

    def write(self, run: FinishedRun) -> list[Path]:
        if not run.closed:
            return []
        if run.aborted:
            self.display.verdict(Outcome.ABORTED, abort_detail(run))
        else:
            assert run.report is not None
            self.display.message(f"{run.outcome}: recording closed")
            self.display.verdict(run.outcome, banner_detail(run.report, run.folder))
        return []


@dataclass
class IndexLine:
    """The run's line in ``<output_dir>/index.jsonl``: a done run's at its verdict (a line that
    cannot be written raises ``RecordingError``, the run's abort), an aborted run's with its
    reason (a line that cannot be written is a warning)."""

    append: Callable[[Path, Report], Path]  # benchctl.run.report.archive
    append_abort: Callable[[Path, dict[str, Any], Path, str], Path]  # … .archive_abort
    name = "index"

    def write(self, run: FinishedRun) -> list[Path]:
        if not run.closed:
            assert run.report is not None
            return [self.append(run.out_dir, run.report)]
        if not run.aborted:
            return []
        try:
            return [self.append_abort(run.out_dir, run.meta, run.folder, run.reason)]
        except Exception as e:  # a full disk: the recording's end.json still says it all
            log.warning("archive not updated: %s", describe(e))
            return []


@dataclass
class ResultsArchive:
    """The run into the results archive (``benchctl.archive``) once its recording is closed:
    never raises and never waits long (a database out of reach: the record is queued; out of
    reach at the run's start: queued at once)."""

    cfg: BenchConfig
    run_archive: RunArchive | None  # begun with the run (``begin_archive``), else none
    name = "archive"

    def write(self, run: FinishedRun) -> list[Path]:
        if not run.closed:
            return []
        try:
            if self.run_archive is not None:
                self.run_archive.end(run.folder)
                return []
            from benchctl.archive.service import archive_run_within, settings_for

            archive_run_within(settings_for(self.cfg, run.out_dir), run.folder)
        except Exception as e:
            log.warning("archive not updated: %s", describe(e), exc_info=e)
        return []


def begin_archive(cfg: BenchConfig, out_dir: Path) -> RunArchive | None:
    """Before a run: killed runs (no end.json) into the archive as ABORTED, the queue sent —
    in the background (``benchctl.archive.service.RunArchive``): the run does not wait."""
    try:
        from benchctl.archive.service import RunArchive, settings_for

        run_archive = RunArchive(settings_for(cfg, out_dir), out_dir)
        run_archive.begin()
        return run_archive
    except Exception as e:
        log.warning("archive not updated: %s", describe(e), exc_info=e)
        return None


# ------------------------------------------------------------------------------- what they write
def record_of(run: FinishedRun) -> dict[str, Any]:
    """The record of ``run`` (``closed``: with the data files' SHA-256)."""
    rj, rt = run.folder / REPORT_JSON, run.folder / REPORT_TXT
    rec = build_record(
        run.meta, recording=run.folder, outcome=run.outcome, measurements=run.measurements,
        decision_rule=run.decision_rule, abort=run.abort, deviations=run.deviations,
        warnings=run.warnings, report_json=rj if rj.exists() else None,
        report_txt=rt if rt.exists() else None, log=run.log,
        exit_code=run.exit_code, clock=run.clock,
    )
    return with_data(rec, run.folder, run.meta) if run.closed else rec


def write_html(run: FinishedRun, record: dict[str, Any], strict: bool = False) -> Path | None:
    """``report.html`` into the recording (``benchctl.report.html``), from the run's report and
    record (an aborted run: what is known); a report that cannot be drawn is a warning, the
    verdict and the record stand without it — except, with ``strict``, a full disk, raised as
    ``RecordingError`` (the run's abort)."""
    try:
        from benchctl.report.html import write_html as draw

        report = None if run.report is None else run.report.to_dict(full=True)
        return draw(run.folder, report=report, record=record, figures=run.figures)
    except Exception as e:
        full = RecordingError.disk_full(e, run.folder / REPORT_HTML)
        if strict and full is not None:
            raise full from None
        log.warning("report.html not written: %s", describe(full or e), exc_info=e)
        return None


def banner_detail(report: Report, path: Path) -> str:
    """The verdict banner's lines: σ per axis against its limit, where the report is."""
    lines = [f"{v.axis} σ {v.sigma_deg:.4f}° (95 % {v.sigma_ci95_deg[0]:.4f} … "
             f"{v.sigma_ci95_deg[1]:.4f}°)  limit {v.limit_deg:g}°  {v.outcome}"
             + ("" if v.sigma_inconclusive is None else
                f"\n  σ not judged: {v.sigma_inconclusive}")
             for v in report.axes.values()]
    lines.extend(f"DEVIATION: {d}" for d in report.deviations)
    html = path / REPORT_HTML
    lines.append(f"report {html}" if html.exists() else f"recording {path}")
    return "\n".join(lines)


def abort_detail(run: FinishedRun) -> str:
    """An aborted run's banner lines: the kind and reason, the verdict measured before the
    abort, where the stand is, where the report (or the recording) is."""
    assert run.abort is not None
    html = run.folder / REPORT_HTML
    return (f"{run.abort['kind']}: {run.reason}\n"
            + (measured_line(run.measured) + "\n" if run.measured else "")
            + "".join(f"{line}\n" for line in stand_lines(run.abort["stand"]))
            + (f"report {html}" if html.exists() else f"recording {run.folder}"))


def measured_line(m: Mapping[str, Any]) -> str:
    """The verdict an aborted run measured before its outputs failed, in one line."""
    axes = "; ".join(f"{a} σ {v['sigma']:.4f}° (95 % {v['sigma_ci95'][0]:.4f} … "
                     f"{v['sigma_ci95'][1]:.4f}°) limit {v['limit']:g}° {v['verdict']}"
                     for a, v in m["axes"].items())
    return (f"measured before the abort: {m['verdict']} ({axes}); its report, record or "
            "archive could not all be written, so the run is ABORTED")


def stand_lines(where: Mapping[str, Any]) -> list[str]:
    """The stand's place after an abort as the terminal shows it: one line, and the commands
    that bring it to rest at zero when it is not."""
    lines = [f"stand: {where['text']}"]
    if where["known"] and where["commands"]:
        lines.append("to bring it to rest at zero, in this order:")
        lines.extend(f"  {c}" for c in where["commands"])
    return lines


__all__ = [
    "Console",
    "FinishedRun",
    "IndexLine",
    "RecordFiles",
    "ReportFiles",
    "ResultsArchive",
    "Sink",
    "abort_detail",
    "banner_detail",
    "begin_archive",
    "emit",
    "measured_line",
    "record_in",
    "record_of",
    "stand_lines",
    "write_html",
]
