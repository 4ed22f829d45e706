"""The plan record (``plan.json``, ``benchctl plan --json``) and its JSON Schema,
``benchctl/schemas/plan-1.schema.json`` (``benchctl schema plan`` prints it). Each step's
``record`` is that step's ``record.json`` and is validated against the run record's schema
(``benchctl-record/1``) on its own."""

from __future__ import annotations

import json
from collections.abc import Mapping
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator

from benchctl.errors import DataError
from benchctl.jsonout import load_object, plain
from benchctl.results.record import validate_record

PLAN_SCHEMA_FILE = "plan-1.schema.json"


def plan_schema_text() -> str:
    return resources.files("benchctl.schemas").joinpath(PLAN_SCHEMA_FILE).read_text("utf-8")


@cache
def plan_schema() -> dict[str, Any]:
    schema: dict[str, Any] = json.loads(plan_schema_text())
    return schema


def validate_plan_record(record: Mapping[str, Any]) -> None:
    """Raise ``DataError`` unless ``record`` is a valid plan record (every problem named:
    where, what was found, what was expected), each step's record valid too."""
    data = plain(record)
    v = Draft202012Validator(plan_schema())
    errors = sorted(v.iter_errors(data), key=lambda e: list(e.absolute_path))
    if errors:
        parts = [f"{'/'.join(str(p) for p in e.absolute_path) or '(top)'}: {e.message}"
                 for e in errors[:10]]
        raise DataError("plan record not valid against benchctl-plan/1: " + "; ".join(parts))
    for i, step in enumerate(data.get("steps") or []):
        if step.get("record") is not None:
            try:
                validate_record(step["record"])
            except DataError as e:
                raise DataError(f"steps/{i}/record: {e}") from None


def load_plan_record(path: Path | str) -> dict[str, Any]:
    """A plan record from ``plan.json`` (or a plan folder holding one), validated."""
    return load_object(path, "plan.json", "plan record", validate_plan_record)


__all__ = ["load_plan_record", "plan_schema", "plan_schema_text", "validate_plan_record"]
