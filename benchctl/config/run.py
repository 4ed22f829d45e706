"""The bench config's ``run:`` section: the verdict, the decision rule, the checks before and
during the motion, the analysis and the outputs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    Field,
    field_validator,
    model_validator,
)

from benchctl.config.types import (
    MAX_WAIT_S,
    NonNegative,
    Positive,
    Seconds,
    Strict,
)
from benchctl.options import MAX_BAND_HZ


class EqualiseConfig(Strict):
    """Equalisation (``benchctl.analysis.equalise``): before the motion a short pre-test at
    ``level`` × the profile's amplitudes measures the stand's response on the profile's lines
    over ``periods`` whole periods (a period over ``max_period_s``: a shorter one, the response
    interpolated), and the drive is corrected so the measured motion is the profile's. A line
    where the stand moves less than ``min_gain_db`` or whose response is uncertain beyond
    ``max_uncertainty_db`` is not corrected; no line is driven up by more than
    ``max_boost_db``, nor beyond the stand's limits."""

    enabled: bool = False
    """Equalise before the motion (off by default; `--equalise` turns it on)."""
    level: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.2
    """The pre-test's amplitudes as a fraction of the profile's."""
    periods: Annotated[int, Field(ge=1, le=20)] = 1
    """The pre-test's length in whole periods of the profile's multisine."""
    max_period_s: Annotated[float, Field(ge=1, le=600, allow_inf_nan=False)] = 20.0
    """A profile period longer than this is pre-tested over a shorter one, the response interpolated
    (s)."""
    fade_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    """The pre-test's fade in and out (s)."""
    settle_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 3.0
    """Settling before the pre-test's samples are taken (s)."""
    min_gain_db: Annotated[float, Field(ge=-60, lt=0, allow_inf_nan=False)] = -20.0
    """A line where the stand moves less than this is not corrected (dB)."""
    max_boost_db: Annotated[float, Field(ge=0, le=40, allow_inf_nan=False)] = 10.0
    """No line is driven up by more than this (dB), nor beyond the stand's limits."""
    max_uncertainty_db: Annotated[float, Field(gt=0, le=6, allow_inf_nan=False)] = 0.5
    """A line whose measured response is uncertain beyond this is not corrected (dB)."""


class AnalysisConfig(Strict):
    """How the recording is analysed."""

    max_lag_s: Annotated[float, Field(gt=0, le=86400, allow_inf_nan=False)] | None = None
    """The longest delay between the two streams the analysis searches for (s); none: the documented
    default rule."""
    band_hz: tuple[NonNegative, Positive] | None = None
    """[lo, hi]: σ restricted to this band (Hz); none: the whole band."""
    compensate_delay: (
        Literal["none", "auto"] | Annotated[float, Field(ge=-3600, le=3600, allow_inf_nan=False)]
    ) = "none"
    """`none`; `auto` (the instrument's delay estimated and removed before σ); or a delay in seconds
    to remove."""
    departure_settle_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 3.0
    """After an underrun or a rejoin, the stand is back on the profile: its servo and the instrument
    settle for this long before the analysis takes its samples again (s)."""

    @field_validator("band_hz")
    @classmethod
    def _band(cls, band: tuple[float, float] | None) -> tuple[float, float] | None:
        if band is not None and not (band[0] < band[1] <= MAX_BAND_HZ):
            raise ValueError(f"expected [lo, hi] in Hz with lo < hi ≤ {MAX_BAND_HZ:g}")
        return band


class ExcitationConfig(Strict):
    """Excitation fidelity (``benchctl.analysis.excitation``): the measured stand angle's
    spectrum against the profile's, judged per band: beyond ±``alarm_db`` an alarm, beyond
    ±``abort_db`` the abort level. Lines below ``weak_line_db`` (amplitude re the strongest)
    and bands below ``weak_band_db`` (power re the strongest band) are not judged, nor a band
    whose 95 % half-width exceeds ``max_ci_db``. ``band_edges_hz``: the bands' edges, ascending
    (default: third-octave bands). ``abort_run``: abort the run when a band's running estimate
    during the motion is confirmed beyond ±``abort_db``."""

    alarm_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 1.5
    """A band's measured excitation beyond ± this of the profile's raises an alarm (dB)."""
    abort_db: Annotated[float, Field(gt=0, le=40, allow_inf_nan=False)] = 3.0
    """Beyond ± this, the abort level (dB); at least alarm_db."""
    weak_line_db: Annotated[float, Field(ge=-120, lt=0, allow_inf_nan=False)] = -30.0
    """Lines weaker than this, re the strongest (amplitude), are not judged (dB)."""
    weak_band_db: Annotated[float, Field(ge=-120, lt=0, allow_inf_nan=False)] = -20.0
    """Bands weaker than this, re the strongest (power), are not judged (dB)."""
    max_ci_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 0.5
    """A band whose 95 % interval's half-width exceeds this is not judged (dB)."""
    band_edges_hz: tuple[Positive, ...] | None = None
    """The bands' edges, strictly ascending (Hz); none: third-octave bands."""
    abort_run: bool = True
    """Abort the run when, during the motion, a band's running estimate is confirmed beyond ±
    abort_db."""

    @field_validator("band_edges_hz")
    @classmethod
    def _edges(cls, e: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if e is not None and (
            len(e) < 2 or any(e[i + 1] <= e[i] for i in range(len(e) - 1))
            or e[-1] > MAX_BAND_HZ
        ):
            raise ValueError(
                f"expected at least two band edges in Hz, strictly ascending, ≤ {MAX_BAND_HZ:g}"
            )
        return e

    @model_validator(mode="after")
    def _levels(self) -> ExcitationConfig:
        if self.abort_db < self.alarm_db:
            raise ValueError(
                f"abort_db = {self.abort_db:g}: expected ≥ alarm_db ({self.alarm_db:g})"
            )
        return self


class MountingCheckConfig(Strict):
    """The mounting check (``benchctl.run.mounting``), a precheck before the motion: each axis
    of the profile in turn is tilted slowly to ``tilt_deg`` and back (``hold_s`` held at each
    end), within the stand's limits (checked with the profile, before anything opens), and the
    instrument's response fitted: the reading of
    that axis must follow it with a gain within 1 ± ``gain_tolerance`` and every other
    reading within ± ``cross_tolerance`` of it. A unit mounted reversed (gain −1) or with roll
    and pitch swapped is refused before the test, with what was seen and how to fix it.
    The tolerances are wide on purpose: they separate the mounting errors (−1, 0, the other
    axis's ±1) from a correct mount; a poor unit's gain and cross-axis sensitivity are the
    test's to measure (and FAIL). Their sum must stay below 1 (the cases stay apart)."""

    enabled: bool = True
    """Run the mounting check before the motion."""
    tilt_deg: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = 2.0
    """How far each axis is tilted (°)."""
    hold_s: Annotated[float, Field(ge=0.2, le=10, allow_inf_nan=False)] = 1.0
    """How long the tilt is held at each end (s)."""
    gain_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.3
    """The tilted axis's reading must follow it with a gain within 1 ± this."""
    cross_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.3
    """Every other reading must stay within ± this of the tilt (as a gain)."""

    @model_validator(mode="after")
    def _apart(self) -> MountingCheckConfig:
        if self.gain_tolerance + self.cross_tolerance >= 1:
            raise ValueError(
                f"gain_tolerance = {self.gain_tolerance:g} + cross_tolerance = "
                f"{self.cross_tolerance:g}: expected a sum below 1 (else a reading that does "
                "not respond could pass as one that does)"
            )
        return self


class RunLimits(Strict):
    """Optional limits of further measurements (benchctl.results.measurements): each one set
    makes that measurement decide the verdict with σ; unset, it is recorded, not judged."""

    gain_min: Positive | None = None
    """The gain at the periods 3, 5, 7 and 10 s (where excited) must be at least this."""
    gain_max: Positive | None = None
    """… and at most this."""
    phase_deg: Annotated[float, Field(gt=0, le=180, allow_inf_nan=False)] | None = None
    """|phase| at those periods at most this (°)."""
    delay_s: Annotated[float, Field(gt=0, le=MAX_WAIT_S, allow_inf_nan=False)] | None = None
    """The instrument's delay at most this (s)."""
    mean_error_deg: Positive | None = None
    """|mean error| at most this (°)."""

    @model_validator(mode="after")
    def _gain(self) -> RunLimits:
        if self.gain_min is not None and self.gain_max is not None and (
            self.gain_min >= self.gain_max
        ):
            raise ValueError(
                f"gain_min = {self.gain_min:g}: expected below gain_max ({self.gain_max:g})"
            )
        return self


class HostCheckConfig(Strict):
    """The host fitness check (``benchctl.run.fitness``): before the motion, threads ask to
    wake every ``period_s`` and every stand-loop period for ``window_s`` and the lateness of
    each wake is measured (as cyclictest or LinuxCNC's latency test do). The worst lateness ×
    ``margin`` must fit inside what the stand tolerates — its buffer (``buffered``), a quarter
    of the setpoint period (``stream``: a later setpoint is a missed slot), and the slack its
    heartbeat watchdog leaves beyond the longest exchange — else ``on_poor``: ``warn`` (the
    run goes on, a warning in the record) or ``refuse`` (a failed precheck: exit 2, nothing
    moves). Not measured on simulated time. ``benchctl host-check`` runs it alone."""

    enabled: bool = True
    """Measure the host before the motion (never on simulated time)."""
    window_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    """How long the wakes are measured (s)."""
    period_s: Annotated[float, Field(ge=1e-4, le=1.0, allow_inf_nan=False)] = 0.001
    """The fixed wake period measured besides the stand loop's own (s; cyclictest's 1 ms)."""
    margin: Annotated[float, Field(ge=1, le=1e6, allow_inf_nan=False)] = 4.0
    """The worst lateness × this must fit inside what the stand tolerates."""
    on_poor: Literal["warn", "refuse"] = "warn"
    """A host that does not fit: `warn` (the run goes on, a warning in the record) or `refuse` (a
    failed precheck: exit 2, nothing moves)."""


class RunConfig(Strict):
    """The run's rules: the verdict, the checks before and during the motion, the analysis and the
    outputs."""

    limit_sigma_deg: Positive
    """The verdict's limit: PASS when σ is at most this, on every axis (°)."""
    decision_rule: Literal["simple", "guarded"] = "simple"
    """How σ (and every measurement with an interval) is judged against its limit: `simple` (the
    value within the limit) or `guarded` (the 95 % interval wholly within: PASS; wholly beyond:
    FAIL; else INCONCLUSIVE, exit 3)."""
    limits: RunLimits = RunLimits()
    """Optional limits of further measurements (gain, phase, delay, mean error)."""
    output_dir: Path = Path("runs")
    """Where the runs' folders are written (relative to this file)."""
    min_free_disk_mb: Positive = 200.0
    """A run is refused when the output folder's disk has less free space than this (MB)."""
    precheck_window_s: Seconds = 1.0
    """The instrument's rate and its agreement with the stand at rest are measured over this (s)."""
    instrument_rate_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.2
    """The instrument's measured rate must be within ± this fraction of instrument.expected_rate_hz.
    """
    profile_tolerance_deg: Positive = 1.0
    """The stand's motion departing from the profile by more than this aborts the run (°)."""
    linearity_spread_limit: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.01
    """sine_steps profiles: PASS when the spread (max − min) of the steps' gains is at most this,
    per axis."""
    analysis: AnalysisConfig = AnalysisConfig()
    """Analysis options."""
    excitation: ExcitationConfig = ExcitationConfig()
    """The excitation fidelity's levels: the measured motion's spectrum against the profile's."""
    lock_dir: Path | None = None
    """One run per stand: where its lock files are kept (none: /run/benchctl-locks)."""
    precision: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] | None = None
    """Stop the motion once σ's 95 % interval is within ± this fraction of σ (after at least one
    whole period of the multisine); none: the whole profile runs."""
    equalise: EqualiseConfig = EqualiseConfig()
    """A low-level pre-test and the drive corrected by the stand's measured response (off by
    default)."""
    mounting_check: MountingCheckConfig = MountingCheckConfig()
    """Before the motion, each axis tilted a few degrees and back: a unit mounted reversed or with
    its axes swapped is refused (on by default)."""
    host_check: HostCheckConfig = HostCheckConfig()
    """The host's scheduling latency, measured before the motion and judged against the stand's
    buffer and watchdog."""
    realtime_priority: Annotated[int, Field(ge=1, le=99)] | None = None
    """The SCHED_FIFO priority (1–99) the stand loop's thread asks for on the real clock (Linux:
    CAP_SYS_NICE or an rtprio limit); whether it was granted is recorded, a refusal never stops the
    run; none: not asked for."""
    figures: bool = True
    """Draw the report's figures at the run's end (about 1–3 s per axis); false on a bench whose
    reports nobody opens at the station: `benchctl report REC` draws them later."""
