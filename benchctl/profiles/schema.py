"""Profile file schema (pydantic, strict): one model per ``kind``, unknown fields are errors.

Units are in field names (``hs_m``, ``tp_s``, ``sigma_deg``, ``band_hz``). The field reference
is ``docs/reference/profiles.md``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator

from benchctl.options import MAX_RUN_DURATION_S

Axis = Literal["roll", "pitch"]
# every number finite (.inf, .nan refused); durations and periods at most a day
Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
MAX_DURATION_S = MAX_RUN_DURATION_S  # a profile's duration, fades, periods: at most a day
Duration = Annotated[float, Field(gt=0, le=MAX_DURATION_S, allow_inf_nan=False)]
Fade = Annotated[float, Field(ge=0, le=MAX_DURATION_S, allow_inf_nan=False)]


def _check_band(band: tuple[float, float]) -> tuple[float, float]:
    if not band[0] < band[1]:
        raise ValueError(f"expected [low, high] in Hz with low < high, got {list(band)}")
    return band


Band = Annotated[tuple[Positive, Positive], AfterValidator(_check_band)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


# --- common ---------------------------------------------------------------------------


class CrestSpec(Strict):
    """Crest-factor reduction by phase choice (the amplitudes, hence the spectrum, never change)."""

    method: Literal["none", "clip", "schroeder"] = "none"
    iterations: int = Field(default=100, ge=1, le=10000)


class MultisineSpec(Strict):
    """Which lines of the band a spectral profile excites (default: every harmonic k/T_p).

    ``odd``: odd harmonics only (an odd random-phase multisine: even-order distortion then
    falls on unexcited even lines); ``detection_group``: 0, or g ≥ 2 — one line of every group
    of g consecutive candidates is left out at random (seeded), a detection line for odd
    distortion; ``interleave_axes``: roll and pitch on disjoint lines (roll k ≡ 1, pitch
    k ≡ 3 mod 4 when odd; else roll odd, pitch even), so that one run separates each axis's
    response to roll from its response to pitch (cross-axis).
    """

    odd: bool = False
    detection_group: int = Field(default=0, ge=0, le=1000)
    interleave_axes: bool = False

    @model_validator(mode="after")
    def _group(self) -> MultisineSpec:
        if self.detection_group == 1:
            raise ValueError("detection_group 1 would leave every line out; expected 0 or >= 2")
        return self


class ProfileBase(Strict):
    name: str = Field(min_length=1)
    description: str = ""
    reference: str = ""  # where the numbers come from
    seed: int = Field(ge=0, lt=2**63)


class TimedBase(ProfileBase):
    duration_s: Duration
    fade_in_s: Fade = 5.0
    fade_out_s: Fade = 5.0


class SpectralBase(TimedBase):
    """Kinds synthesised from a target spectrum: lines on k/T_p in a band."""

    band_hz: Band | None = None  # default band for every axis
    repeat_period_s: Duration | None = None  # T_p wanted; the rule in design.choose_period
    amplitudes: Literal["cell", "point"] = "cell"
    crest: CrestSpec = CrestSpec()
    min_lines: int = Field(default=3, ge=1, le=100_000)
    multisine: MultisineSpec | None = None  # odd lines, detection lines, disjoint axes


class AxisBand(Strict):
    band_hz: Band | None = None  # overrides the profile's band_hz for this axis


# --- sea_state ----------------------------------------------------------------------------


class SeaSpec(Strict):
    spectrum: Literal["pierson_moskowitz", "bretschneider", "jonswap"]
    hs_m: Positive | None = None
    wmo_code: int | None = Field(default=None, ge=1, le=9)
    tp_s: Positive
    gamma: Annotated[float, Field(ge=1, le=20, allow_inf_nan=False)] | None = None  # default 3.3
    sigma_a: Positive | None = None  # JONSWAP only; default 0.07
    sigma_b: Positive | None = None  # JONSWAP only; default 0.09

    @model_validator(mode="after")
    def _one_height(self) -> SeaSpec:
        if (self.hs_m is None) == (self.wmo_code is None):
            raise ValueError("give exactly one of hs_m or wmo_code")
        if self.spectrum != "jonswap":
            for name in ("gamma", "sigma_a", "sigma_b"):
                if getattr(self, name) is not None:
                    raise ValueError(f"{name} applies to spectrum jonswap only")
        return self


class ShipAxisSpec(AxisBand):
    natural_period_s: Positive
    damping_ratio: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)]
    slope_coefficient: Positive = 1.0


class SeaStateProfile(SpectralBase):
    kind: Literal["sea_state"]
    sea: SeaSpec
    axes: dict[Axis, ShipAxisSpec] = Field(min_length=1)


# --- roll_spectrum ------------------------------------------------------------------------


class ExpCosSpec(AxisBand):
    model: Literal["exp_cos"]
    sigma_deg: Positive
    period_s: Positive  # apparent period 2π/β
    damping: Positive  # α/β


class TableSpec(AxisBand):
    model: Literal["table"]
    freq_hz: list[NonNegative] = Field(min_length=2)
    density_deg2_hz: list[NonNegative] = Field(min_length=2)

    @model_validator(mode="after")
    def _table(self) -> TableSpec:
        if len(self.freq_hz) != len(self.density_deg2_hz):
            raise ValueError(
                f"freq_hz ({len(self.freq_hz)} values) and density_deg2_hz "
                f"({len(self.density_deg2_hz)} values) must have one length"
            )
        if any(b <= a for a, b in zip(self.freq_hz, self.freq_hz[1:], strict=False)):
            raise ValueError("freq_hz must be strictly increasing")
        return self


RollModel = Annotated[ExpCosSpec | TableSpec, Field(discriminator="model")]


class RollSpectrumProfile(SpectralBase):
    kind: Literal["roll_spectrum"]
    axes: dict[Axis, RollModel] = Field(min_length=1)


# --- recorded -----------------------------------------------------------------------------


class RecordedAxisSpec(AxisBand):
    csv: Path  # relative paths resolve against the profile file's folder
    time_column: str = "time"
    angle_column: str
    angle_unit: Literal["deg", "rad"] = "deg"
    segment_s: Duration = 100.0  # Welch segment length: resolution 1/segment_s Hz


class RecordedProfile(SpectralBase):
    kind: Literal["recorded"]
    axes: dict[Axis, RecordedAxisSpec] = Field(min_length=1)


# --- harmonics, sine, sine_steps ----------------------------------------------------------


class LineSpec(Strict):
    amplitude_deg: Positive
    period_s: Positive | None = None
    freq_hz: Positive | None = None
    phase_deg: Finite | None = None  # omitted: drawn from the seed

    @model_validator(mode="after")
    def _one_freq(self) -> LineSpec:
        if (self.period_s is None) == (self.freq_hz is None):
            raise ValueError("give exactly one of period_s or freq_hz")
        return self

    @property
    def frequency_hz(self) -> float:
        return float(self.freq_hz if self.freq_hz is not None else 1.0 / self.period_s)  # type: ignore[operator]


class HarmonicsAxisSpec(Strict):
    lines: list[LineSpec] = Field(min_length=1)


class HarmonicsProfile(TimedBase):
    kind: Literal["harmonics"]
    repeat_period_s: Duration | None = None  # if every line is on k/T_p: whole-period records
    axes: dict[Axis, HarmonicsAxisSpec] = Field(min_length=1)


class SineSpec(Strict):
    amplitude_deg: Positive
    period_s: Duration
    phase_deg: Finite = 0.0


class SineProfile(TimedBase):
    kind: Literal["sine"]
    axes: dict[Axis, SineSpec] = Field(min_length=1)


class SineStepsProfile(ProfileBase):
    """A grid of periods × amplitudes played one after the other on each listed axis."""

    kind: Literal["sine_steps"]
    axes: list[Axis] = Field(min_length=1)
    periods_s: list[Duration] = Field(min_length=1)
    amplitudes_deg: list[Positive] = Field(min_length=1)
    cycles: int = Field(default=5, ge=1, le=100_000)  # full-amplitude cycles per step
    # fade in and out of each step, in periods of that step
    fade_cycles: Annotated[float, Field(ge=0, le=100_000, allow_inf_nan=False)] = 1.0
    rest_s: Fade = 2.0  # at rest between steps (and before the first)

    @model_validator(mode="after")
    def _unique_axes(self) -> SineStepsProfile:
        if len(set(self.axes)) != len(self.axes):
            raise ValueError(f"axes must not repeat, got {self.axes}")
        one_axis = sum(
            len(self.amplitudes_deg) * (self.rest_s + (self.cycles + 2 * self.fade_cycles) * p)
            for p in self.periods_s
        )
        total = len(self.axes) * one_axis + self.rest_s
        if total > MAX_DURATION_S:
            raise ValueError(
                f"the steps last {total:.6g} s in all; expected at most {MAX_DURATION_S:g} s"
            )
        return self


ProfileSpec = Annotated[
    SeaStateProfile
    | RollSpectrumProfile
    | RecordedProfile
    | HarmonicsProfile
    | SineProfile
    | SineStepsProfile,
    Field(discriminator="kind"),
]

KINDS = ("sea_state", "roll_spectrum", "recorded", "harmonics", "sine", "sine_steps")
