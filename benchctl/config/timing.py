"""The bench's own timing (``timing:``): the stream-to-stream offset a timing calibration
measured, applied to every run's analysis (docs/explanation/metrology.md, "The bench's own
timing")."""

from __future__ import annotations

import datetime
from typing import Annotated

from pydantic import Field, model_validator

from benchctl.config.types import Strict

#: an offset beyond this is no transport latency but a wrong clock or a wrong reference (s)
MAX_OFFSET_S = 0.5


class TimingConfig(Strict):
    """The delay the bench itself adds between the stand's samples and the instrument's, as a
    timing calibration measured it (``benchctl timing calibrate``): the instrument's instants
    are moved earlier by ``offset_s`` before every analysis, so that what the acquisition adds
    (serial line, adapter, USB, the host's stamping) is not read as the instrument's delay."""

    offset_s: Annotated[float, Field(ge=-MAX_OFFSET_S, le=MAX_OFFSET_S,
                                     allow_inf_nan=False)] = 0.0
    """How late the bench stamps the instrument's samples relative to the stand's (s): the
    measured delay of a reference of known latency minus that latency. Subtracted from the
    instrument's instants before the analysis; 0: not calibrated (nothing applied)."""
    uncertainty_s: Annotated[float, Field(ge=0, le=MAX_OFFSET_S, allow_inf_nan=False)] = 0.0
    """The calibration's standard uncertainty of ``offset_s`` (s), as it stated it."""
    calibrated: datetime.date | None = None
    """The date of the timing calibration that measured ``offset_s`` (YYYY-MM-DD)."""
    reference: str | None = Field(default=None, max_length=200)
    """What the calibration measured against: the reference instrument and its certified
    latency, the profile."""

    @model_validator(mode="after")
    def _dated(self) -> TimingConfig:
        if self.offset_s != 0.0 and self.calibrated is None:
            raise ValueError("offset_s needs the date of the calibration that measured it "
                             "(calibrated: YYYY-MM-DD)")
        return self

    @property
    def applied(self) -> bool:
        """True when an offset is applied to the analysis."""
        return self.offset_s != 0.0

    def to_dict(self) -> dict[str, object]:
        """As stated in a run's report and record."""
        return {
            "offset_s": self.offset_s,
            "uncertainty_s": self.uncertainty_s,
            "calibrated": None if self.calibrated is None else self.calibrated.isoformat(),
            "reference": self.reference,
        }
