"""The command line's numeric options: their stated ranges and the one check every option takes
before anything opens (the option tables of ``docs/reference/``: run, plans, analyze, predict).
Light on purpose — no model, no YAML — so a command such as ``benchctl analyze`` checks its
options without building the bench config's models; :mod:`benchctl.config` names them too."""

from __future__ import annotations

import math

from benchctl.errors import InputError

MAX_BAND_HZ = 1e6  # analyze --band, the config's band edges

MAX_RUN_DURATION_S = 86400.0  # run/profile --duration: a day of profile
MAX_PROFILE_SAMPLES = 20_000_000  # --duration × rate, per axis (a day at 231 Hz)
MAX_PROFILE_RATE_HZ = 100_000.0  # profile --rate
MAX_LAG_S = 86400.0  # analyze --max-lag
MAX_DELAY_S = 3600.0  # analyze --compensate-delay, either sign
MAX_SEED = 2**63 - 1  # --seed: 0 … 2⁶³−1


def check_option(
    option: str,
    value: float | None,
    lo: float,
    hi: float,
    *,
    lo_open: bool = False,
    unit: str = "",
    what: str = "",
) -> None:
    """``InputError`` unless ``value`` (None: not given) is finite and within ``lo``…``hi``;
    the message names the option, the value and the range (after ``what`` it expects)."""
    if value is None:
        return
    v = float(value)
    inside = math.isfinite(v) and (v > lo if lo_open else v >= lo) and v <= hi
    if not inside:
        u = f" {unit}" if unit else ""
        rel = "<" if lo_open else "≤"
        lead = f"{what}, " if what else ""
        raise InputError(f"{option} {value!r}: expected {lead}{lo:g} {rel} value ≤ {hi:g}{u}")


__all__ = [
    "MAX_BAND_HZ",
    "MAX_DELAY_S",
    "MAX_LAG_S",
    "MAX_PROFILE_RATE_HZ",
    "MAX_PROFILE_SAMPLES",
    "MAX_RUN_DURATION_S",
    "MAX_SEED",
    "check_option",
]
