"""The bench config's building blocks: the strict base model and the bounded number types.

Every number in a config is finite (``.inf``, ``.nan``, "inf" are refused); times and rates
that size a buffer or a wait are bounded above (docs/reference/config.md).
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field

Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
MAX_WAIT_S = 3600.0  # timeouts, periods, windows
MAX_HOST_RATE_HZ = 1000.0  # the host's setpoint / stand polling rate
MAX_DEVICE_RATE_HZ = 100_000.0  # an instrument's (or a simulator's) own rate
Seconds = Annotated[float, Field(gt=0, le=MAX_WAIT_S, allow_inf_nan=False)]
HostRate = Annotated[float, Field(gt=0, le=MAX_HOST_RATE_HZ, allow_inf_nan=False)]
DeviceRate = Annotated[float, Field(gt=0, le=MAX_DEVICE_RATE_HZ, allow_inf_nan=False)]
Baud = Annotated[int, Field(gt=0, le=100_000_000)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)
