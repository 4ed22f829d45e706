"""The acceptance plan file (YAML), validated strictly: an unknown field, a wrong type or a
value out of range is a ``ConfigError`` naming the file, the field, the value and what was
expected — before anything opens or moves.

::

    name: paper_procedure                 # required
    description: …                        # optional
    config: ../config/sim.yaml            # the bench config (relative to this file); --config
    operator: QA line 2                   # optional (the CLI's --operator overrides it)
    timeout_s: 3600                       # the whole plan (optional)
    prompt_timeout_s: 600                 # each operator prompt at most (default 600 s)
    setup:                                # actions before the first step, in order
      - prompt: Mount the instrument on the stand   # asked y/N (or --yes)
      - prompt: Area clear of people?
        check: stand_at_rest              # a prompt and a check in one action: prompt first
    steps:                                # run in order, each a real run (benchctl run)
      - name: linearity
        profile: ../profiles/linearity_sine_steps.yaml
        duration_s: null                  # optional: --duration of the run
        decision_rule: simple             # optional: simple | guarded (default: the config's)
        on_fail: continue                 # stop (default) | continue
        timeout_s: 900                    # optional: this step at most
        limits: {gain_min: 0.990, gain_max: 1.000, linearity_spread: 0.01, sigma_deg: 2.0}
    cleanup:                              # always, whatever happened before (see runner)
      - check: ramp_to_zero
      - prompt: Remove the instrument

A step's ``limits`` (each optional; unset: the bench config's): ``sigma_deg``,
``gain_min``/``gain_max`` (the gain at 3/5/7/10 s where the profile excites them),
``linearity_spread`` (sine steps: max − min of the gains), ``phase_deg``, ``delay_s``,
``mean_error_deg``, ``excitation_db`` (informative). They become the run's limits
(``benchctl.results.measurements.Limits`` through the run's config), so the step's
``record.json`` and report judge by them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from benchctl.config import MAX_WAIT_S
from benchctl.errors import ConfigError
from benchctl.options import MAX_RUN_DURATION_S
from benchctl.text import OPERATOR_MAX
from benchctl.text import problem as text_problem
from benchctl.validation import invalid
from benchctl.yamlfile import read_yaml

MAX_PLAN_S = 7 * 86400.0  # a plan's or a step's timeout: at most a week
MAX_STEPS = 100
MAX_ACTIONS = 50
DEFAULT_PROMPT_TIMEOUT_S = 600.0  # an operator prompt unanswered this long ends the plan

Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
Timeout = Annotated[float, Field(gt=0, le=MAX_PLAN_S, allow_inf_nan=False)]
Name = Annotated[str, Field(min_length=1, max_length=100, pattern=r"^[^\x00-\x1f\x7f]+$")]
Text = Annotated[str, Field(min_length=1, max_length=500, pattern=r"^[^\x00-\x08\x0b-\x1f\x7f]+$")]
CHECKS = ("stand_at_rest", "ramp_to_zero")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Action(_Strict):
    """A setup or cleanup action: a ``prompt`` (asked y/N), a ``check`` on the stand, or both
    (the prompt first)."""

    prompt: Text | None = None
    check: Literal["stand_at_rest", "ramp_to_zero"] | None = None

    @model_validator(mode="after")
    def _one(self) -> Action:
        if self.prompt is None and self.check is None:
            raise ValueError(f"an action needs prompt and/or check (one of {', '.join(CHECKS)})")
        return self


class StepLimits(_Strict):
    """Limits of one step's measurements (unset: the bench config's)."""

    sigma_deg: Positive | None = None
    gain_min: Positive | None = None
    gain_max: Positive | None = None
    linearity_spread: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] | None = None
    phase_deg: Annotated[float, Field(gt=0, le=180, allow_inf_nan=False)] | None = None
    delay_s: Annotated[float, Field(gt=0, le=MAX_WAIT_S, allow_inf_nan=False)] | None = None
    mean_error_deg: Positive | None = None
    excitation_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _gain(self) -> StepLimits:
        if self.gain_min is not None and self.gain_max is not None and (
            self.gain_min >= self.gain_max
        ):
            raise ValueError(
                f"gain_min = {self.gain_min:g}: expected below gain_max ({self.gain_max:g})"
            )
        return self


class Step(_Strict):
    name: Name
    profile: Path
    duration_s: Annotated[float, Field(gt=0, le=MAX_RUN_DURATION_S, allow_inf_nan=False)] | None = (
        None
    )
    limits: StepLimits = StepLimits()
    decision_rule: Literal["simple", "guarded"] | None = None
    on_fail: Literal["stop", "continue"] = "stop"
    timeout_s: Timeout | None = None


class Plan(_Strict):
    name: Name
    description: str | None = None
    config: Path | None = None
    operator: str | None = None  # the rules of --operator (benchctl.text)
    timeout_s: Timeout | None = None
    prompt_timeout_s: Timeout = DEFAULT_PROMPT_TIMEOUT_S
    setup: tuple[Action, ...] = Field(default=(), max_length=MAX_ACTIONS)
    steps: tuple[Step, ...] = Field(min_length=1, max_length=MAX_STEPS)
    cleanup: tuple[Action, ...] = Field(default=(), max_length=MAX_ACTIONS)
    source: Path | None = Field(default=None, exclude=True)  # the file it was read from

    @field_validator("operator")
    @classmethod
    def _operator(cls, v: str | None) -> str | None:
        if v is None:
            return None
        bad = text_problem(v.strip(), OPERATOR_MAX, "operator's name")
        if bad is not None:
            raise ValueError(bad)
        return v.strip()

    @model_validator(mode="after")
    def _unique(self) -> Plan:
        seen: set[str] = set()
        for i, s in enumerate(self.steps):
            if s.name in seen:
                raise ValueError(f"steps[{i}].name = {s.name!r}: expected a name no other step has")
            seen.add(s.name)
        return self

    @property
    def prompts(self) -> list[str]:
        return [a.prompt for a in (*self.setup, *self.cleanup) if a.prompt is not None]


def parse_plan(data: Any, source: Path | None = None) -> Plan:
    """Validate a plan mapping; ``config`` and each step's ``profile``, when relative, resolve
    against ``source``'s folder (else the working directory)."""
    label = str(source) if source is not None else "<plan>"
    if not isinstance(data, dict):
        raise ConfigError(
            f"{label}: expected a YAML mapping at the top level, got {type(data).__name__}"
        )
    if "source" in data:
        raise ConfigError(f"{label}: invalid plan: field source: not a plan field")
    try:
        plan = Plan.model_validate({**data, "source": source})
    except ValidationError as err:
        raise ConfigError(invalid(label, "plan", err)) from None
    base = source.parent if source is not None else Path.cwd()

    def resolve(p: Path) -> Path:
        return p if p.is_absolute() else (base / p).resolve()

    steps = tuple(s.model_copy(update={"profile": resolve(s.profile)}) for s in plan.steps)
    update: dict[str, Any] = {"steps": steps}
    if plan.config is not None:
        update["config"] = resolve(plan.config)
    return plan.model_copy(update=update)


def load_plan(path: str | Path) -> Plan:
    """Read and validate a plan YAML file (``ConfigError`` naming file, field, value and
    expectation on any problem)."""
    p = Path(path)
    return parse_plan(read_yaml(p, "plan"), p)


__all__ = [
    "CHECKS",
    "DEFAULT_PROMPT_TIMEOUT_S",
    "Action",
    "Plan",
    "Step",
    "StepLimits",
    "load_plan",
    "parse_plan",
]
