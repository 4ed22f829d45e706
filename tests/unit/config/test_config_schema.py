"""The bench config's JSON Schema: every field explained, the shipped file current, the shipped
configs naming it and valid against it, and ``benchctl schema config`` printing it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from jsonschema import Draft202012Validator
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.config import CONFIG_SCHEMA_FILE, config_schema, config_schema_text, load_config

SHIPPED = ROOT / "benchctl" / "schemas" / CONFIG_SCHEMA_FILE
CONFIGS = sorted((ROOT / "config").glob("*.yaml"))
MODELINE = f"# yaml-language-server: $schema=../benchctl/schemas/{CONFIG_SCHEMA_FILE}"


class _EditorLoader(yaml.SafeLoader):
    """YAML as an editor's schema check sees it: a date is the string it is written as."""


_EditorLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag != "tag:yaml.org,2002:timestamp"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}


def _models(schema: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {"BenchConfig": schema, **schema.get("$defs", {})}


def test_every_section_and_field_is_explained() -> None:
    schema = config_schema()
    missing = []
    fields = 0
    for name, model in _models(schema).items():
        if not model.get("description"):
            missing.append(name)
        for field, spec in model.get("properties", {}).items():
            fields += 1
            if not spec.get("description"):
                missing.append(f"{name}.{field}")
    assert fields > 150  # the whole config, fault parameters included
    assert missing == []


def _same_meaning(node: Any) -> Any:
    """A schema as it means, not as a pydantic version spells it: 2.7 wraps a ``$ref`` that
    has a description beside it in a one-element ``allOf``, later ones do not (and numbers
    compare as numbers: 0 and 0.0)."""
    if isinstance(node, dict):
        out = {k: _same_meaning(v) for k, v in node.items()}
        one = out.get("allOf")
        if isinstance(one, list) and len(one) == 1 and set(one[0]) == {"$ref"}:
            del out["allOf"]
            out["$ref"] = one[0]["$ref"]
        return out
    if isinstance(node, list):
        return [_same_meaning(v) for v in node]
    return node


def test_the_shipped_schema_is_the_models() -> None:
    shipped = json.loads(SHIPPED.read_text("utf-8"))
    assert _same_meaning(shipped) == _same_meaning(config_schema()), (
        f"{SHIPPED} is out of date: benchctl schema config > {SHIPPED.relative_to(ROOT)}"
    )
    Draft202012Validator.check_schema(shipped)


@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_a_shipped_config_names_the_schema_and_is_valid_against_it(path: Path) -> None:
    text = path.read_text("utf-8")
    assert text.splitlines()[0] == MODELINE
    assert (path.parent / MODELINE.split("$schema=")[1]).resolve() == SHIPPED.resolve()
    load_config(path)  # the models take it …
    errors = list(Draft202012Validator(config_schema()).iter_errors(
        yaml.load(text, Loader=_EditorLoader)  # a SafeLoader
    ))
    assert [(list(e.absolute_path), e.message) for e in errors] == []  # … and so does the schema


@pytest.mark.parametrize(
    ("data", "where"),
    [
        ({"stand": {"driver": "modbus-tcp", "prot": 502}}, ["stand"]),
        ({"stand": {"driver": "modbus-udp"}}, ["stand", "driver"]),
        ({"stand": {"driver": "modbus-tcp", "port": 70000}}, ["stand", "port"]),
        ({"instrument": {"driver": "canopen", "axes": ["roll", "yaw"]}}, ["instrument", "axes"]),
        ({"sim": {"faults": [{"target": "stand", "kind": "stall",
                              "params": {"duraton_s": 1}}]}}, ["sim", "faults", 0, "params"]),
        ({"sim": {"faults": [{"target": "instrument", "kind": "garbled",
                              "params": {"fraction": 2}}]}},
         ["sim", "faults", 0, "params", "fraction"]),
    ],
)
def test_the_schema_refuses_what_the_models_refuse(data: dict[str, Any], where: list[Any]) -> None:
    """An editor flags the same mistakes loading would (each one at its place)."""
    places = []
    todo = list(Draft202012Validator(config_schema()).iter_errors(data))
    while todo:  # an optional section's errors are inside its anyOf's
        e = todo.pop()
        places.append(list(e.absolute_path))
        todo += e.context or []
    assert any(p[: len(where)] == where for p in places), places


def test_schema_config_on_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["schema", "config"]) == 0
    out = capsys.readouterr().out
    assert out == config_schema_text()
    doc = json.loads(out)
    stand = doc["$defs"]["StandConfig"]["properties"]
    assert "watchdog" in stand["timeout_s"]["description"]
    assert stand["port"]["maximum"] == 65535
