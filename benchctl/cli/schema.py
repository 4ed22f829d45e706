"""``benchctl schema record|plan|config``: print a JSON Schema (``record.json``, ``plan.json``, the
bench config)."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from benchctl.outcomes import ExitCode

SCHEMAS = ("record", "plan", "config")


def register(sub: Any) -> None:
    p = sub.add_parser(
        "schema",
        help=(
            "print a JSON Schema: of a benchctl output (record: record.json, plan: plan.json) "
            "or of the bench config (config)"
        ),
        description=(
            "Print a versioned JSON Schema (draft 2020-12) of a benchctl output: 'record' is "
            "record.json, the run's record written into every recording (benchctl-record/1); "
            "'plan' is plan.json, an acceptance plan's record (benchctl-plan/1); 'config' is the "
            "bench config (YAML), every field with its type, default, bounds and meaning — the "
            "file benchctl/schemas/bench-config.schema.json that the shipped configs name for "
            "editors."
        ),
    )
    p.add_argument("name", choices=SCHEMAS, help="which schema")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from benchctl.config import config_schema_text
    from benchctl.plan.record import plan_schema_text
    from benchctl.results.record import schema_text

    makers = {"record": schema_text, "plan": plan_schema_text, "config": config_schema_text}
    text = makers[args.name]()
    sys.stdout.write(text if text.endswith("\n") else text + "\n")
    return ExitCode.OK
