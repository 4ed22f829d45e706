"""``benchctl schema record``: print the JSON Schema of ``record.json`` (as shipped)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from benchctl.outcomes import ExitCode

SCHEMAS = ("record", "plan")


def register(sub: Any) -> None:
    p = sub.add_parser(
        "schema",
        help="print the JSON Schema of a benchctl output (record: record.json, plan: plan.json)",
        description=(
            "Print a versioned JSON Schema (draft 2020-12) of a benchctl output: 'record' is "
            "record.json, the run's record written into every recording (benchctl-record/1); "
            "'plan' is plan.json, an acceptance plan's record (benchctl-plan/1)."
        ),
    )
    p.add_argument("name", choices=SCHEMAS, help="which schema")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from benchctl.plan.record import plan_schema_text
    from benchctl.results.record import schema_text

    text = plan_schema_text() if args.name == "plan" else schema_text()
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return ExitCode.OK
