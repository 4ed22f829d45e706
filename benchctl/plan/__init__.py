"""Acceptance plans: an ordered list of test steps with setup, cleanup, prompts, a failure
policy and timeouts, run unattended (``benchctl plan``) or from Python::

    from benchctl.plan import run_plan

    result = run_plan("plans/ci_short.yaml", serial="SN-0042", yes=True,
                      junit="results.xml")
    result.exit_code          # 0 all PASS, 1 a measured FAIL, 2 an abort/error, 3 INCONCLUSIVE
    result.outcome            # PASS | FAIL | INCONCLUSIVE | ABORTED
    for step in result.steps:  # StepResult: name, status, reason, recording, record (record.json)
        print(step.name, step.status, [m["outcome"] for m in step.measurements])
    result.to_dict()          # the plan record (plan.json, schema benchctl-plan/1)

The plan file: ``benchctl.plan.schema``; the order of things, timeouts and exit codes:
``benchctl.plan.runner`` (the timeouts' timers: ``benchctl.plan.timeouts``; the terminal's
prompts: ``benchctl.plan.prompts``); the results: ``benchctl.plan.result``; JUnit XML:
``benchctl.plan.junit``; the plan record's schema: ``benchctl.plan.record``.
"""

from benchctl.plan.result import ActionResult, PlanResult, StepResult
from benchctl.plan.runner import run_plan
from benchctl.plan.schema import Action, Plan, Step, StepLimits, load_plan, parse_plan
from benchctl.plan.timeouts import PlanTimeout

__all__ = [
    "Action",
    "ActionResult",
    "Plan",
    "PlanResult",
    "PlanTimeout",
    "Step",
    "StepLimits",
    "StepResult",
    "load_plan",
    "parse_plan",
    "run_plan",
]
